"""``gatewaylab migrate config`` / ``esi``: ENI in, ENI + Markdown report out; ESI from the devices'
own descriptions (the same source as their SII and dictionary, so a master importing both agrees)."""

from __future__ import annotations

from typing import Protocol

from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.ecanlite.device import EcanLiteDevice
from gatewaylab.devices.esd_can_ethercat import objects as esd_obj
from gatewaylab.devices.esd_can_ethercat.device import create_esd_gateway
from gatewaylab.ethercat.esi import export_esi
from gatewaylab.ethercat.slave import Slave
from gatewaylab.migrate.eni import EniError, InitCmd, SlaveConfig, SyncManager, format_writes
from gatewaylab.migrate.translate import Translation

DEVICES = ("ecanlite", "esd_can_ethercat")


def device_slave(device: str) -> Slave:
    """A fresh, unconnected instance of ``device`` (its slave carries description and dictionary)."""
    clock = SimulatedClock()
    if device == "ecanlite":
        return EcanLiteDevice(clock, []).slave
    if device == "esd_can_ethercat":
        return create_esd_gateway(clock, None, start=False).slave
    raise EniError(f"device {device!r} is not one of {', '.join(DEVICES)}")


def esi_text(device: str) -> str:
    """The device's ESI export (``gatewaylab.ethercat.esi``) with its full dictionary."""
    slave = device_slave(device)
    return export_esi(slave.desc, slave.od)


def find_esd(slaves: list[SlaveConfig]) -> SlaveConfig:
    """The esd CAN-EtherCAT among an ENI's slaves (vendor 0x17, product 2)."""
    desc = device_slave("esd_can_ethercat").desc
    for s in slaves:
        if (s.vendor_id, s.product_code) == (desc.vendor_id, desc.product_code):
            return s
    raise EniError(f"no esd CAN-EtherCAT (vendor 0x{desc.vendor_id:X}, product 0x{desc.product_code:X}) in the ENI")


def ecanlite_slave(esd: SlaveConfig, tr: Translation) -> SlaveConfig:
    """The ECAN-Lite ``Config/Slave`` replacing ``esd``: identity, mailbox and SMs from the device's
    description, the translated InitCmds, 128 x N bytes each way, the esd's DC settings."""
    desc = device_slave("ecanlite").desc
    size = 128 * tr.multiplier
    return SlaveConfig(
        name=f"{desc.name} (from {esd.name})", vendor_id=desc.vendor_id, product_code=desc.product_code,
        revision=desc.revision, serial=0, mailbox_out=desc.mailbox_out, mailbox_in=desc.mailbox_in,
        init_cmds=tuple(tr.cmds), output_bits=8 * size, input_bits=8 * size,
        sync_managers=(SyncManager(2, desc.outputs_start, desc.outputs_control, True, size),
                       SyncManager(3, desc.inputs_start, desc.inputs_control, True, size)),
        dc_cycle0=esd.dc_cycle0, dc_cycle1=esd.dc_cycle1, dc_shift=esd.dc_shift)


def report(source: str, esd_cmds: list[InitCmd] | tuple[InitCmd, ...], tr: Translation) -> str:
    """The Markdown translation report: settings, capacity arithmetic, every note, the writes."""
    sp = f", sample point {tr.sample_point / 10:g} %" if tr.sample_point else ""
    rate = (f"- bit rate {tr.bitrate} bit/s{sp}" + (", listen-only" if tr.listen_only else "") + ", classic CAN"
            if tr.bitrate else "- no bit rate (off the bus)")
    lines = [f"# esd CAN-EtherCAT -> ECAN-Lite: {source}", "",
             f"- esd CAN port -> MCAN channel {tr.channel} (0x{0x8001 + tr.channel:04X}, channel mask "
             f"0x{1 << tr.channel:02X} in 0x8010/0x8011)", rate,
             f"- PDO multiplier N = {tr.multiplier}: {128 * tr.multiplier} B outputs, {128 * tr.multiplier} B inputs",
             "", "## Capacity", ""]
    lines += [f"    {a}" for a in tr.arithmetic]
    lines += ["", "## Not translated one-to-one", ""]
    lines += [f"- **{n.topic}**: {n.reason}. Closest: {n.closest}." for n in tr.notes] or ["- nothing"]
    lines += ["", "## esd startup writes read", "", "```text", format_writes(list(esd_cmds)).rstrip(), "```",
              "", "## ECAN-Lite startup writes (PREOP -> SAFEOP)", "", "```text", format_writes(tr.cmds).rstrip(),
              "```", ""]
    return "\n".join(lines)


class SdoReader(Protocol):
    """What reading a running esd's dictionary needs (the in-process Master has it)."""

    def sdo_upload(self, position: int, index: int, subindex: int, complete: bool = False) -> bytes:
        """The raw value of one object of the slave at ``position`` (an SDO upload)."""


def read_live(master: SdoReader, position: int) -> list[InitCmd]:
    """A running esd gateway's settings as the startup writes that would recreate them."""
    cmds: list[InitCmd] = []

    def up(index: int, sub: int) -> None:
        cmds.append(InitCmd(index, sub, master.sdo_upload(position, index, sub)))

    up(0xF800, esd_obj.BAUD_INDEX)
    up(0xF800, esd_obj.API_BAUD)
    for sub in (esd_obj.FLAGS, esd_obj.RX_QUEUE, esd_obj.TX_QUEUE, esd_obj.LOCAL_RX, esd_obj.LOCAL_TX):
        up(0x8000, sub)
    up(0x8001, 0)
    for sub in range(1, cmds[-1].value + 1):
        up(0x8001, sub)
    up(0x1C13, 0)
    for sub in range(1, cmds[-1].value + 1):
        up(0x1C13, sub)
    return cmds


__all__ = ["DEVICES", "device_slave", "ecanlite_slave", "esi_text", "find_esd", "read_live", "report"]
