"""Distributed clocks of the in-process master (SOEM's ethercatdc): SYNC0 programming."""

from __future__ import annotations

from gatewaylab.ethercat.esc import REG_DC_ACTIVATION, REG_DC_START_TIME, REG_DC_SYNC0_CYCLE, REG_DC_SYSTEM_TIME
from gatewaylab.hosts.ethercat.base import U32, U64, Port
from gatewaylab.hosts.ethercat.config import Configuration

__all__ = ["Dc"]


class Dc:
    """Programs the DC registers of configured slaves, for slaves that run synchronous cycles."""

    def __init__(self, port: Port, config: Configuration) -> None:
        self.port = port
        self.config = config

    def configure_sync0(self, position: int, cycle: float, start_delay: float = 0.01) -> None:
        """Program DC SYNC0 (cycle, start = system time + delay, activation) for slaves that run synchronous cycles."""
        station = self.config.slave(position).station
        now = U64.unpack(self.port.fprd(station, REG_DC_SYSTEM_TIME, 8))[0]
        self.port.fpwr(station, REG_DC_SYNC0_CYCLE, U32.pack(round(cycle * 1e9)))
        self.port.fpwr(station, REG_DC_START_TIME, U64.pack(now + round(start_delay * 1e9)))
        self.port.fpwr(station, REG_DC_ACTIVATION, b"\x03")
