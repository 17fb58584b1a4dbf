"""Distributed clocks of the ESC: local and system time, receive-time latches, SYNC0/SYNC1 settings.

The master measures propagation delays by latching receive times (a write to 0x0900), sets each
slave's system time offset (0x0920) and programs the SYNC unit: start time (0x0990), SYNC0 / SYNC1
cycle (0x09A0 / 0x09A4) and activation (0x0981). Each ESC has its own local clock
(:class:`~gatewaylab.ethercat.esc_dc_clock.LocalClock`: drift, jumps, the time control loop that drift
compensation writes to 0x0910 feed; 0x092C / 0x0932 show it) and its place in the line (when a frame
reaches it, set by the segment from the cable lengths). SYNC0 pulses come from the injected clock; the firmware
gets each as a call (the real ESC raises the SYNC0 line). Devices read the DC settings through
:class:`DistributedClocks` (``Esc.sync0_period`` and friends), never from the registers themselves.
Register meanings: ET1100 data sheet section II, "Distributed Clocks".
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Final

from gatewaylab.common.clock import Clock, TimerHandle
from gatewaylab.ethercat import esc_registers as reg
from gatewaylab.ethercat.esc_dc_clock import DEFAULT_CABLE_M, LOOP_LIMIT_PPM, FrameTime, LocalClock, line_delays
from gatewaylab.ethercat.esc_registers import SYNC0_MIN_CYCLE_NS, U16, U32, U64

__all__ = ["DC_ACT_CYCLIC", "DC_ACT_SYNC0", "DC_ACT_SYNC1", "REG_DC_DIFF_FILTER", "REG_DC_SPEED_DIFF",
           "REG_DC_SPEED_START", "REG_DC_TIME_DIFF", "DistributedClocks", "place_line"]


#: 0x0981 bits: cyclic unit enabled, SYNC0 generated, SYNC1 generated.
DC_ACT_CYCLIC: Final = 0x01
DC_ACT_SYNC0: Final = 0x02
DC_ACT_SYNC1: Final = 0x04
_MASK64: Final = 0xFFFFFFFFFFFFFFFF
_MASK32: Final = 0xFFFFFFFF
#: System time difference, speed counter start / diff, filter depths (ET1100 section II, 0x092C-0x0935).
REG_DC_TIME_DIFF: Final = 0x092C
REG_DC_SPEED_START: Final = 0x0930
REG_DC_SPEED_DIFF: Final = 0x0932
REG_DC_DIFF_FILTER: Final = 0x0934


class DistributedClocks:
    """The DC unit of one ESC over the shared register memory; ``on_sync0`` gets each pulse's time."""

    __slots__ = ("_sync0_cycle", "_sync0_next", "_sync0_timer", "arrival_ns", "cable_m", "clock", "downstream",
                 "frame", "local", "mem", "on_sync0", "return_ns")

    def __init__(self, clock: Clock, mem: bytearray, on_sync0: Callable[[float], None]) -> None:
        self.clock = clock
        self.mem = mem
        self.on_sync0 = on_sync0
        #: Slaves behind this one in the line.
        self.downstream = 0
        #: The local clock: drift, jumps, drift compensation.
        self.local = LocalClock(clock)
        #: Length of the cable into port 0 (from the master or the slave before), in metres.
        self.cable_m = DEFAULT_CABLE_M
        #: When a frame reaches port 0, in ns after the master sent it (set by the segment).
        self.arrival_ns = 0.0
        #: How much later the frame comes back to port 1 from the slaves behind (0: none behind).
        self.return_ns = 0.0
        #: When the frame being processed left the master (shared by a segment's ESCs, see :func:`place_line`).
        self.frame = FrameTime()
        self._sync0_timer: TimerHandle | None = None
        self._sync0_next = 0.0
        self._sync0_cycle = 0.0

    # ------------------------------------------------------------------ time
    def local_time_ns(self) -> int:
        """The ESC's local clock now, in nanoseconds (the injected clock, drifted and corrected)."""
        return round(self.local.at(self.clock.now()))

    def system_time_ns(self) -> int:
        """Local time plus the offset the master wrote to 0x0920: the line's common time base."""
        return self._system_at(self.clock.now())

    def _system_at(self, t: float) -> int:
        offset: int = U64.unpack_from(self.mem, reg.REG_DC_SYSTEM_OFFSET)[0]
        return (round(self.local.at(t)) + offset) & _MASK64

    def _frame_time(self) -> float:
        """Clock time at which the frame being processed reaches this ESC."""
        frame = self.frame
        t = frame.t
        if t < 0:
            t = frame.t = self.clock.now()
        return t + self.arrival_ns * 1e-9

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
            U64.pack_into(self.mem, reg.REG_DC_SYSTEM_TIME, self._system_at(self._frame_time()))

    def write(self, address: int, end: int, old: bytes) -> None:
        """A master wrote [address, end) (``old``: the bytes before): latch receive times, feed drift
        compensation, reset the control loop, (re)start the SYNC0 train on an activation write."""
        mem = self.mem
        if address < reg.REG_DC_RECV_TIME + 4 and end > reg.REG_DC_RECV_TIME:
            # A write to port 0's receive time latches the receive times of all ports.
            t = self._frame_time()
            local = self.local
            t0 = round(local.at(t))
            U32.pack_into(mem, reg.REG_DC_RECV_TIME, t0 & _MASK32)
            t1 = round(local.at(t + self.return_ns * 1e-9)) if self.downstream else 0
            U32.pack_into(mem, reg.REG_DC_RECV_TIME + 4, t1 & _MASK32)
            U32.pack_into(mem, reg.REG_DC_RECV_TIME + 8, 0)
            U32.pack_into(mem, reg.REG_DC_RECV_TIME + 12, 0)
            U64.pack_into(mem, reg.REG_DC_RECV_TIME_PU, t0 & _MASK64)
        if address < reg.REG_DC_SYSTEM_TIME + 8 and end > reg.REG_DC_SYSTEM_TIME:
            # A write to the system time is compared with the local copy: the control loop's input.
            stop = min(end, reg.REG_DC_SYSTEM_TIME + 8)
            lo = max(address, reg.REG_DC_SYSTEM_TIME)
            if lo == reg.REG_DC_SYSTEM_TIME and stop - lo in (4, 8):
                self._compensate(stop - lo == 8)
            mem[lo:stop] = old[lo - address:stop - address]
        if address < reg.REG_DC_SYSTEM_OFFSET + 8 and end > reg.REG_DC_SYSTEM_OFFSET:
            self.local.restart_measurement()
        if address < REG_DC_SPEED_START + 2 and end > REG_DC_SPEED_START:
            self.local.reset_loop()
            U32.pack_into(mem, REG_DC_TIME_DIFF, 0)
            U16.pack_into(mem, REG_DC_SPEED_DIFF, 0)
        if address <= reg.REG_DC_ACTIVATION < end:
            self._configure()

    def _compensate(self, wide: bool) -> None:
        """The value just written to 0x0910 (64 bits, or the low 32) against the local copy of the system
        time when the frame got here: one step of the control loop; 0x092C and 0x0932 show the result."""
        mem = self.mem
        t = self._frame_time()
        delay = U32.unpack_from(mem, reg.REG_DC_SYSTEM_DELAY)[0]
        if wide:
            raw = (self._system_at(t) - U64.unpack_from(mem, reg.REG_DC_SYSTEM_TIME)[0] - delay) & _MASK64
            diff = raw - (1 << 64) if raw >> 63 else raw
        else:
            raw = (self._system_at(t) - U32.unpack_from(mem, reg.REG_DC_SYSTEM_TIME)[0] - delay) & _MASK32
            diff = raw - (1 << 32) if raw >> 31 else raw
        local = self.local
        local.compare(t, float(diff), mem[REG_DC_DIFF_FILTER] & 0x0F)
        mean = round(local.mean_diff)
        U32.pack_into(mem, REG_DC_TIME_DIFF, min(abs(mean), 0x7FFFFFFF) | (0x80000000 if mean < 0 else 0))
        span = (U16.unpack_from(mem, REG_DC_SPEED_START)[0] & 0x7FFF or 0x1000) - 0x7F
        U16.pack_into(mem, REG_DC_SPEED_DIFF, round(local.correction_ppm / LOOP_LIMIT_PPM * span) & 0xFFFF)

    @property
    def time_difference_ns(self) -> int:
        """0x092C decoded: the filtered difference local copy - (received system time + delay), in ns."""
        value: int = U32.unpack_from(self.mem, REG_DC_TIME_DIFF)[0]
        return -(value & 0x7FFFFFFF) if value & 0x80000000 else value

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
        start = self.local.clock_time(float((self.sync0_start_time_ns - offset) & _MASK64))
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


def place_line(clocks: Sequence[DistributedClocks], frame: FrameTime) -> None:
    """Set when a frame reaches each ESC of a line (in order, first next to the master) and returns to its
    port 1, from the cable lengths (``cable_m``) of each (:func:`~gatewaylab.ethercat.esc_dc_clock.line_delays`);
    ``frame``: the line's frame time, which its segment clears around each frame."""
    for dc, (arrival, back) in zip(clocks, line_delays([c.cable_m for c in clocks]), strict=True):
        dc.arrival_ns = arrival
        dc.return_ns = back
        dc.frame = frame
