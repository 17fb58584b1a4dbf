"""SOEM's distributed-clock setup for a line, done by the in-process master: ``config_dc`` is SOEM's
``ecx_configdc`` (ethercatdc.c) for slaves in a line, ``compensate`` the FRMW of 0x0910 SOEM adds to every
process data frame once DC is configured (``ecx_main_send_processdata``), ``time_difference`` reads 0x092C.

ecx_configdc: BWR 0x0900 latches every port's receive time; per slave FPRD 0x0900 (port 0), 0x0918
(receive time of the processing unit), FPWR 0x0920 = master time - 0x0918, FPRD 0x0904 (port 1); the
propagation delay of slave i (not the first) is that of its parent plus half of (parent's port 1 - port
0) minus (its own port 1 - port 0), written to 0x0928.
"""

from __future__ import annotations

import struct

from gatewaylab.common.clock import SimulatedClock
from gatewaylab.ethercat.datagram import Command, Datagram
from gatewaylab.ethercat.esc import (
    REG_DC_RECV_TIME,
    REG_DC_RECV_TIME_PU,
    REG_DC_SYSTEM_DELAY,
    REG_DC_SYSTEM_OFFSET,
    REG_DC_SYSTEM_TIME,
)
from gatewaylab.ethercat.esc_dc import REG_DC_SPEED_START, REG_DC_TIME_DIFF
from gatewaylab.hosts.ethercat.master import Master

#: SOEM's master time base: ns since 2000-01-01 (any value will do; a fixed one keeps tests exact).
MASTER_TIME_NS = 7 * 10**17


def reset_dc(m: Master) -> None:
    """SOEM ecx_set_slaves_to_default's DC part: system time 0 (4 bytes), speed counter start 0x1000,
    filter depths 0 / 12 (BWR 0x0910, 0x0930, 0x0934)."""
    m.exchange([Datagram.physical(Command.BWR, 0, 0, REG_DC_SYSTEM_TIME, bytes(4))])
    m.exchange([Datagram.physical(Command.BWR, 0, 0, REG_DC_SPEED_START, struct.pack("<H", 0x1000))])
    m.exchange([Datagram.physical(Command.BWR, 0, 0, 0x0934, struct.pack("<H", 0x0C00))])


def config_dc(m: Master) -> list[int]:
    """ecx_configdc for a line; the propagation delays it wrote to 0x0928 (the first slave: 0)."""
    m.exchange([Datagram.physical(Command.BWR, 0, 0, REG_DC_RECV_TIME, bytes(4))])
    delays: list[int] = []
    prev_span = 0
    n = len(m.slaves)
    for i, s in enumerate(m.slaves):
        st = s.station
        rt_a = struct.unpack("<I", m.fprd(st, REG_DC_RECV_TIME, 4))[0]
        pu = struct.unpack("<Q", m.fprd(st, REG_DC_RECV_TIME_PU, 8))[0]
        m.fpwr(st, REG_DC_SYSTEM_OFFSET, struct.pack("<Q", (MASTER_TIME_NS - pu) & (2**64 - 1)))
        rt_b = struct.unpack("<I", m.fprd(st, REG_DC_RECV_TIME + 4, 4))[0]
        span = (rt_b - rt_a) & 0xFFFFFFFF if i < n - 1 else 0    # dt1: only a slave with one behind it
        if i == 0:
            delays.append(0)
        else:
            delays.append(delays[-1] + (prev_span - span) // 2)
            m.fpwr(st, REG_DC_SYSTEM_DELAY, struct.pack("<I", delays[-1]))
        prev_span = span
    return delays


def compensate(m: Master, clock: SimulatedClock, frames: int, period: float = 0.001,
               command: Command = Command.FRMW) -> None:
    """``frames`` drift compensation frames ``period`` apart: FRMW 0x0910 (8 bytes) from the first slave (the one
    SOEM adds to process data), or ARMW from position 0 (static drift compensation bursts)."""
    adp = m.slaves[0].station if command == Command.FRMW else 0
    for _ in range(frames):
        clock.advance(period)
        d = m.exchange([Datagram.physical(command, 0, adp, REG_DC_SYSTEM_TIME, bytes(8))])[0]
        assert d.wkc == len(m.slaves), f"{command.name} wkc {d.wkc}"


def time_difference(m: Master, position: int) -> int:
    """0x092C of the slave at ``position``, signed: positive when its local copy is ahead (bit 31 clear)."""
    raw: int = struct.unpack("<I", m.fprd(m.slaves[position].station, REG_DC_TIME_DIFF, 4))[0]
    return -(raw & 0x7FFFFFFF) if raw & 0x80000000 else raw
