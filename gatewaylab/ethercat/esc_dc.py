"""Distributed clocks of the ESC: local and system time, receive-time latches, SYNC0/SYNC1 settings.

The master measures propagation delays by latching receive times (a write to 0x0900), sets each
slave's system time offset (0x0920) and programs the SYNC unit: start time (0x0990), SYNC0 / SYNC1
cycle (0x09A0 / 0x09A4) and activation (0x0981). The emulated local clocks do not drift, so drift
compensation writes to 0x0910 are absorbed. SYNC0 pulses come from the injected clock; the firmware
gets each as a call (the real ESC raises the SYNC0 line). Devices read the DC settings through
:class:`DistributedClocks` (``Esc.sync0_period`` and friends), never from the registers themselves.
Register meanings: ET1100 data sheet section II, "Distributed Clocks".
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Final

from gatewaylab.common.clock import Clock, TimerHandle
from gatewaylab.ethercat import esc_registers as reg
from gatewaylab.ethercat.esc_registers import SYNC0_MIN_CYCLE_NS, U32, U64

__all__ = ["DC_ACT_CYCLIC", "DC_ACT_SYNC0", "DC_ACT_SYNC1", "DistributedClocks"]


#: 0x0981 bits: cyclic unit enabled, SYNC0 generated, SYNC1 generated.
DC_ACT_CYCLIC: Final = 0x01
DC_ACT_SYNC0: Final = 0x02
DC_ACT_SYNC1: Final = 0x04
_MASK64: Final = 0xFFFFFFFFFFFFFFFF


class DistributedClocks:
    """The DC unit of one ESC over the shared register memory; ``on_sync0`` gets each pulse's time."""

    __slots__ = ("_sync0_cycle", "_sync0_next", "_sync0_timer", "clock", "downstream", "mem", "on_sync0")

    def __init__(self, clock: Clock, mem: bytearray, on_sync0: Callable[[float], None]) -> None:
        self.clock = clock
        self.mem = mem
        self.on_sync0 = on_sync0
        #: Slaves behind this one in the line (port 1's receive time lags by 40 ns each).
        self.downstream = 0
        self._sync0_timer: TimerHandle | None = None
        self._sync0_next = 0.0
        self._sync0_cycle = 0.0

    # ------------------------------------------------------------------ time
    def local_time_ns(self) -> int:
        """The ESC's local clock: the injected clock in nanoseconds (it does not drift)."""
        return round(self.clock.now() * 1e9)

    def system_time_ns(self) -> int:
        """Local time plus the offset the master wrote to 0x0920: the line's common time base."""
        offset: int = U64.unpack_from(self.mem, reg.REG_DC_SYSTEM_OFFSET)[0]
        return (self.local_time_ns() + offset) & _MASK64

    # ------------------------------------------------------------------ settings the firmware reads
    @property
    def sync0_active(self) -> bool:
        """The master activated the cyclic unit and SYNC0 generation (0x0981 bits 0 and 1)."""
        return self.mem[reg.REG_DC_ACTIVATION] & (DC_ACT_CYCLIC | DC_ACT_SYNC0) == DC_ACT_CYCLIC | DC_ACT_SYNC0

    @property
    def sync1_active(self) -> bool:
        """The master activated the cyclic unit and SYNC1 generation (0x0981 bits 0 and 2)."""
        return self.mem[reg.REG_DC_ACTIVATION] & (DC_ACT_CYCLIC | DC_ACT_SYNC1) == DC_ACT_CYCLIC | DC_ACT_SYNC1

    @property
    def sync0_cycle_ns(self) -> int:
        """SYNC0 cycle time as the master wrote it (0x09A0), in ns, whether active or not."""
        return int(U32.unpack_from(self.mem, reg.REG_DC_SYNC0_CYCLE)[0])

    @property
    def sync1_cycle_ns(self) -> int:
        """SYNC1 cycle time as the master wrote it (0x09A4), in ns."""
        return int(U32.unpack_from(self.mem, reg.REG_DC_SYNC1_CYCLE)[0])

    @property
    def sync0_start_time_ns(self) -> int:
        """Start time of the SYNC0 train in system time (0x0990), in ns."""
        return int(U64.unpack_from(self.mem, reg.REG_DC_START_TIME)[0])

    @property
    def sync0_period(self) -> float:
        """The period the SYNC0 pulses come at, in seconds (a cycle below
        :data:`SYNC0_MIN_CYCLE_NS` raised to it); 0.0 while SYNC0 is off or its cycle is 0."""
        if not self.sync0_active:
            return 0.0
        ns = self.sync0_cycle_ns
        return max(ns, SYNC0_MIN_CYCLE_NS) / 1e9 if ns else 0.0

    @property
    def sync0_next(self) -> float:
        """Clock time of the next SYNC0 pulse (meaningful while pulses run)."""
        return self._sync0_next

    # ------------------------------------------------------------------ master accesses
    def refresh(self, address: int, end: int) -> None:
        """A master read of [address, end): the system time register shows the time of the read."""
        if end > reg.REG_DC_SYSTEM_TIME and address < reg.REG_DC_SYSTEM_TIME + 8:
            U64.pack_into(self.mem, reg.REG_DC_SYSTEM_TIME, self.system_time_ns())

    def write(self, address: int, end: int, old: bytes) -> None:
        """A master wrote [address, end) (``old``: the bytes before): latch receive times, absorb
        drift compensation, (re)start the SYNC0 train on an activation write."""
        mem = self.mem
        if address < reg.REG_DC_RECV_TIME + 4 and end > reg.REG_DC_RECV_TIME:
            # A write to port 0's receive time latches the receive times of all ports.
            t = self.local_time_ns()
            U32.pack_into(mem, reg.REG_DC_RECV_TIME, t & 0xFFFFFFFF)
            t1 = t + 40 * self.downstream if self.downstream else 0
            U32.pack_into(mem, reg.REG_DC_RECV_TIME + 4, t1 & 0xFFFFFFFF)
            U32.pack_into(mem, reg.REG_DC_RECV_TIME + 8, 0)
            U32.pack_into(mem, reg.REG_DC_RECV_TIME + 12, 0)
            U64.pack_into(mem, reg.REG_DC_RECV_TIME_PU, t)
        if address < reg.REG_DC_SYSTEM_TIME + 8 and end > reg.REG_DC_SYSTEM_TIME:
            # Writes to the system time feed drift compensation; our local clocks do not drift.
            stop = min(end, reg.REG_DC_SYSTEM_TIME + 8)
            lo = max(address, reg.REG_DC_SYSTEM_TIME)
            mem[lo:stop] = old[lo - address:stop - address]
        if address <= reg.REG_DC_ACTIVATION < end:
            self._configure()

    # ------------------------------------------------------------------ SYNC0 pulses
    def stop(self) -> None:
        """No more SYNC0 pulses (power off; a new activation write starts them again)."""
        if self._sync0_timer is not None:
            self._sync0_timer.cancel()
            self._sync0_timer = None

    def _configure(self) -> None:
        self.stop()
        cycle_ns = self.sync0_cycle_ns
        if not self.sync0_active or cycle_ns == 0:
            return
        offset = U64.unpack_from(self.mem, reg.REG_DC_SYSTEM_OFFSET)[0]
        start = ((self.sync0_start_time_ns - offset) & _MASK64) / 1e9
        cycle = max(cycle_ns, SYNC0_MIN_CYCLE_NS) / 1e9
        now = self.clock.now()
        if start < now:
            start += (int((now - start) / cycle) + 1) * cycle
        self._sync0_cycle = cycle
        self._sync0_next = start
        self._sync0_timer = self.clock.call_at(start, self._fire)

    def _fire(self) -> None:
        t = self._sync0_next
        nxt = t + self._sync0_cycle
        now = self.clock.now()
        if nxt <= now:  # pulses the PDI missed while it was busy merge into this one
            nxt += (int((now - nxt) / self._sync0_cycle) + 1) * self._sync0_cycle
        self._sync0_next = nxt
        self._sync0_timer = self.clock.call_at(self._sync0_next, self._fire)
        self.mem[reg.REG_DC_SYNC0_STATUS] |= 0x01
        self.on_sync0(t)
