"""The lines ``gatewaylab migrate compare`` runs on: fresh copies of a rig file with one gateway added,
in process on a simulated clock or (``--wire``) in real time with the EtherCAT segment on an interface.

Imported by ``cli/migrate.py`` only when ``compare`` runs, so other commands do not load the rig runtime.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from gatewaylab.common.clock import RealTimeClock, SimulatedClock
from gatewaylab.common.errors import ConfigError
from gatewaylab.hosts.ethercat.inprocess import InProcessBackend
from gatewaylab.migrate.compare_run import GATEWAYS, Line, LineOpener, Runner, simulated_runner
from gatewaylab.migrate.compare_wire import RealtimeOpener, WireLine, wire_runner, wire_unavailable
from gatewaylab.rig.config import RigConfig, load_rig
from gatewaylab.rig.runtime import Rig

__all__ = ["GATEWAY_KINDS", "compare_config", "line_opener", "open_compare", "realtime_opener", "with_gateway"]


#: device kinds compare adds itself; a rig for compare must not hold them
GATEWAY_KINDS = tuple(g[0] for g in GATEWAYS)


def compare_config(path: str | Path, bus: str) -> RigConfig:
    """The rig file for ``migrate compare``: buses and drives, no gateway, ``bus`` declared."""
    config = load_rig(path)
    if bus not in {b.name for b in config.buses}:
        raise ConfigError(f"{path}: no [[bus]] named {bus!r} (declared: "
                          f"{', '.join(b.name for b in config.buses) or 'none'})")
    for dev in config.devices:
        if dev.get("kind") in GATEWAY_KINDS:
            raise ConfigError(f"{path}: holds a {dev['kind']} gateway ({dev.get('name', '?')}); "
                              f"compare adds each gateway itself, give a rig with buses and drives only")
    return config


def with_gateway(config: RigConfig, kind: str, bus: str) -> RigConfig:
    """``config`` plus one gateway of ``kind`` on ``bus`` (the ECAN-Lite with MCAN channel 0 on it)."""
    device: dict[str, Any] = ({"kind": kind, "name": "compare-esd", "bus": bus} if kind == "esd_can_ethercat"
                              else {"kind": kind, "name": "compare-ecan", "channels": [bus]})
    return dataclasses.replace(config, clock="simulated", devices=(*config.devices, device))


def line_opener(config: RigConfig, bus: str) -> LineOpener:
    """Opens a fresh copy of ``config`` with a gateway, on a simulated clock, in this process."""

    def open_line(kind: str) -> Line:
        rig = Rig(with_gateway(config, kind, bus), clock=SimulatedClock(), endpoints=False)
        try:
            rig.start()
            return Line(InProcessBackend.from_rig(rig), rig.bus(bus), rig.close)
        except BaseException:
            rig.close()
            raise

    return open_line


def realtime_opener(config: RigConfig, bus: str) -> RealtimeOpener:
    """Opens a fresh copy of ``config`` with a gateway, in real time, its EtherCAT segment on an
    interface (``migrate compare --wire``), its loop running in a thread until ``stop()``."""

    def open_rig(kind: str, interface: str) -> WireLine:
        config_k = dataclasses.replace(with_gateway(config, kind, bus), clock="realtime",
                                       ethercat={"interface": interface})
        rig = Rig(config_k, clock=RealTimeClock(), endpoints=False)
        try:
            rig.start()
            thread = rig.run_in_thread()
        except BaseException:
            rig.close()
            raise

        def stop() -> None:
            rig.request_stop()
            thread.join(timeout=5.0)
            rig.close()

        return WireLine(rig.bus(bus), rig.clock.wall_epoch, stop)

    return open_rig


def open_compare(path: str, bus: str, wire: bool = False) -> Runner:
    """What ``migrate compare --rig PATH --bus BUS [--wire]`` runs with (the config is checked now)."""
    config = compare_config(path, bus)
    if not wire:
        return simulated_runner(line_opener(config, bus))
    reason = wire_unavailable()
    if reason is not None:
        raise ConfigError(f"--wire {reason}")
    return wire_runner(realtime_opener(config, bus))

