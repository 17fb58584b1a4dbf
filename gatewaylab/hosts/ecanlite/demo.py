"""Rigs for the package demos (15.6) in process: ECAN-Lites with CiA 402 drives on their channels.

:func:`rig_toml` writes the rig file the tests, the benchmark and the docs use; :func:`rig_axes`
reads a started rig back into the axis table (which drive sits on which slave and channel) so
``gatewaylab ecan cia402 --rig`` needs no ``--axes``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from gatewaylab.devices.ecanlite.rig import EcanLiteParticipant
from gatewaylab.hosts.ecanlite.cia402 import Axis
from gatewaylab.plugin.capabilities import ethercat_devices, node_of

__all__ = ["rig_axes", "rig_channel_bitrates", "rig_toml"]


def rig_toml(drives_per_channel: Sequence[Sequence[int]] = ((1,),), *, bitrate: int = 1_000_000,
             data_bitrate: int | None = None, slaves: int = 1, interface: str | None = None) -> str:
    """A simulated-clock rig: ``slaves`` ECAN-Lites, each with ``len(drives_per_channel)`` buses;
    channel k of slave s carries drives with the node ids ``drives_per_channel[k]``. With
    ``interface`` the rig gets an ``[ethercat]`` section (the segment answers on that interface
    under ``gatewaylab run``); without it, the in-process master takes the EtherCAT devices in
    file order."""
    lines = ['clock = "simulated"', ""]
    for s in range(slaves):
        for k, nodes in enumerate(drives_per_channel):
            name = f"s{s}can{k}"
            lines += ["[[bus]]", f'name = "{name}"', f"bitrate = {bitrate}"]
            if data_bitrate:
                lines.append(f"data_bitrate = {data_bitrate}")
            lines.append("")
            for n in nodes:
                serial = 0x10000 * (s + 1) + 0x100 * k + n
                lines += ["[[drive]]", f'bus = "{name}"', f"node_id = {n}", f"serial = {serial}",
                          f'name = "s{s}c{k}n{n}"', ""]
        chans = ", ".join(f'"s{s}can{k}"' for k in range(len(drives_per_channel)))
        lines += ["[[device]]", 'kind = "ecanlite"', f'name = "ecan{s}"', f"channels = [{chans}]", ""]
    if interface:
        lines += ["[ethercat]", f'interface = "{interface}"', ""]
    return "\n".join(lines)


def _ecanlites(rig: Any) -> list[tuple[int, EcanLiteParticipant]]:
    """(line position, participant) of the rig's ECAN-Lites (EtherCAT devices in file order)."""
    return [(pos, p) for pos, p in enumerate(ethercat_devices(rig.participants))
            if isinstance(p, EcanLiteParticipant)]


def rig_axes(rig: Any, step: int = 0) -> tuple[list[int], list[Axis]]:
    """The ECAN-Lite positions of a rig and an axis for every drive on one of their channels."""
    positions = []
    axes = []
    for k, (pos, ecan) in enumerate(_ecanlites(rig)):
        positions.append(pos)
        for ch, bus_name in enumerate(ecan.channels):
            for p in rig.participants:
                node = node_of(p)
                if node is not None and node.bus.name == bus_name and node.node_id is not None:
                    axes.append(Axis(k, ch, node.node_id, step))
    return positions, axes


def rig_channel_bitrates(rig: Any) -> dict[int, dict[int, tuple[int, int | None]]]:
    """adapter slave -> channel -> (bit rate, data bit rate) of the buses on the rig's ECAN-Lites."""
    out: dict[int, dict[int, tuple[int, int | None]]] = {}
    for k, (_pos, ecan) in enumerate(_ecanlites(rig)):
        out[k] = {}
        for ch, bus_name in enumerate(ecan.channels):
            bus = rig.buses[bus_name]
            out[k][ch] = (int(bus.bitrate), bus.data_bitrate)
    return out
