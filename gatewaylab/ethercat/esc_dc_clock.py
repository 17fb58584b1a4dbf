"""The local clock of one ESC: its drift, its jumps, the time control loop of drift compensation, and the
propagation delays of a line of ESCs.

ET1100 data sheet section I, "Distributed Clocks": every DC slave has a local clock; its *local copy of
the system time* is the local time plus the system time offset (0x0920). Drift compensation: the master
distributes the reference clock's system time with ARMW/FRMW (or any write) to 0x0910; each slave
compares the value written, plus the propagation delay the master measured (0x0928), with its own local
copy, and a control loop adjusts the speed of its local clock. 0x092C shows the (filtered) difference:
bit 31 set when the local copy is smaller than the received time, bits 30:0 its magnitude; 0x0932
shows the speed counter's deviation. Writing 0x0930 (speed counter start) resets both.

The model (docs/decisions.md): local time is piecewise linear in the injected clock, with the crystal's
drift (``drift_ppm``: a fault makes a slave's clock run fast or slow) and the loop's correction
(``correction_ppm``) both in ppm. The loop estimates the slave's drift against the reference from
successive differences and sets the correction to cancel it and a quarter of the remaining difference
per write interval, never beyond :data:`LOOP_LIMIT_PPM` (the ET1100's speed counter has a limited range
too): a drift within the limit converges, a larger one makes the difference grow, a jump is slewed out at
the limit rate only (a master re-initialising DC -- a new offset in 0x0920 -- fixes it at once).

Propagation (:func:`place_line`): a frame reaches slave k's port 0 after the cables and the slaves
before it, :data:`CABLE_NS_PER_M` per metre of cable and :data:`FORWARD_NS` per slave passed, the same
both ways, so the receive-time latches (0x0900) give a master's delay measurement (SOEM ec_configdc:
half the difference of round trips) exactly the delays the model has.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

from gatewaylab.common.clock import Clock

__all__ = ["CABLE_NS_PER_M", "DEFAULT_CABLE_M", "FORWARD_NS", "LOOP_LIMIT_PPM", "FrameTime", "LocalClock",
           "line_delays"]


#: Signal speed in an Ethernet cable: about 5 ns per metre (two thirds of the speed of light).
CABLE_NS_PER_M: Final = 5.0
#: Time a frame takes through one ESC with 100BASE-TX ports (receive PHY, ESC, transmit PHY), each way.
FORWARD_NS: Final = 500.0
#: Cable length between two devices (and from the master to the first) unless the rig says otherwise.
DEFAULT_CABLE_M: Final = 1.0
#: The largest speed correction the time control loop applies (either sign).
LOOP_LIMIT_PPM: Final = 500.0
#: Compensation writes closer together than this only update the mean difference.
_MIN_INTERVAL_NS: Final = 1000.0
#: A pause longer than this between compensation writes restarts the loop's measurement.
_MAX_INTERVAL_NS: Final = 1e9
#: Weight of a new drift measurement in the loop's estimate.
_ESTIMATE_GAIN: Final = 0.125
#: Share of the remaining difference the loop removes per write interval.
_PHASE_GAIN: Final = 0.25


class FrameTime:
    """When the frame being processed left the master, shared by the ESCs of a line: a real ESC handles a frame
    on the fly, so every ESC's DC accesses of one frame happen at the same time (plus the frame's travel to it),
    however long the emulator takes over the frame. The segment clears it before and after each frame; the first
    DC access of a frame stamps it."""

    __slots__ = ("t",)

    def __init__(self) -> None:
        #: clock time of the frame (s); < 0: none stamped yet
        self.t = -1.0


def _clamp(value: float) -> float:
    return max(-LOOP_LIMIT_PPM, min(LOOP_LIMIT_PPM, value))


class LocalClock:
    """One ESC's local time (ns, float) as a function of the injected clock's time, and its control loop."""

    __slots__ = ("_estimate_ppm", "_l0", "_last_diff", "_last_t", "_rate", "_t0", "clock", "correction_ppm",
                 "drift_ppm", "mean_diff", "samples")

    def __init__(self, clock: Clock) -> None:
        self.clock = clock
        #: The crystal's deviation (a fault sets it): local time runs fast (> 0) or slow by this many ppm.
        self.drift_ppm = 0.0
        #: The speed correction the control loop applies now, in ppm.
        self.correction_ppm = 0.0
        #: The filtered difference local copy - (received + delay) the loop saw last (0x092C), in ns.
        self.mean_diff = 0.0
        #: Compensation writes compared since the loop was last reset.
        self.samples = 0
        self._estimate_ppm = 0.0
        self._last_t = -1.0
        self._last_diff = 0.0
        self._t0 = 0.0
        self._l0 = 0.0
        self._rate = 1e9

    # ------------------------------------------------------------------ time
    def at(self, t: float) -> float:
        """Local time in ns at clock time ``t`` (s)."""
        return self._l0 + (t - self._t0) * self._rate

    def clock_time(self, local_ns: float) -> float:
        """The clock time (s) at which local time reads ``local_ns`` at the present speed."""
        return self._t0 + (local_ns - self._l0) / self._rate

    @property
    def speed(self) -> float:
        """Local nanoseconds per clock nanosecond now."""
        return self._rate / 1e9

    def _rebase(self, t: float) -> None:
        self._l0 = self.at(t)
        self._t0 = t

    def _set_speed(self, t: float) -> None:
        self._rebase(t)
        self._rate = 1e9 * (1.0 + (self.drift_ppm + self.correction_ppm) * 1e-6)

    # ------------------------------------------------------------------ faults
    def set_drift(self, ppm: float) -> None:
        """From now on the crystal runs ``ppm`` fast (negative: slow); 0 is a good crystal."""
        self.drift_ppm = ppm
        self._set_speed(self.clock.now())

    def jump(self, ns: float) -> None:
        """Local time jumps by ``ns`` now (once)."""
        self._rebase(self.clock.now())
        self._l0 += ns

    # ------------------------------------------------------------------ the control loop
    def reset_loop(self) -> None:
        """Speed counter start written (0x0930) or power-on: no correction, no history."""
        self.correction_ppm = 0.0
        self._estimate_ppm = 0.0
        self.mean_diff = 0.0
        self.samples = 0
        self._last_t = -1.0
        self._set_speed(self.clock.now())

    def restart_measurement(self) -> None:
        """The system time offset changed (0x0920): the differences before it say nothing about after."""
        self._last_t = -1.0
        self.mean_diff = 0.0

    def compare(self, t: float, diff: float, depth: int) -> None:
        """A compensation write reached the ESC at clock time ``t``: ``diff`` = local copy of the system time
        - (received time + delay), in ns; ``depth``: 0x0934's filter depth (the mean weighs a new difference
        by 1 / 2**depth)."""
        self.samples += 1
        self.mean_diff += (diff - self.mean_diff) / (1 << depth)
        last_t = self._last_t
        h = (t - last_t) * 1e9
        if last_t < 0 or h > _MAX_INTERVAL_NS:
            self._last_t = t
            self._last_diff = diff
            return
        if h < _MIN_INTERVAL_NS:
            return
        # the difference moved by (drift + correction - the reference's drift) over h: the slave's own share
        measured = (diff - self._last_diff) / h * 1e6 - self.correction_ppm
        est = _clamp(self._estimate_ppm + (measured - self._estimate_ppm) * _ESTIMATE_GAIN)
        self._estimate_ppm = est
        self.correction_ppm = _clamp(-est - diff * _PHASE_GAIN / h * 1e6)
        self._set_speed(t)
        self._last_t = t
        self._last_diff = diff


def line_delays(cables_m: Sequence[float]) -> list[tuple[float, float]]:
    """For a line whose cable into slave k is ``cables_m[k]`` metres long: per slave, (when a frame reaches
    its port 0, how much later the frame returns to its port 1 -- 0 for the last slave), in ns after the
    master sent it. A frame passes each slave once each way (:data:`FORWARD_NS`), the last one loops it back
    through its processing unit once."""
    n = len(cables_m)
    cable = [m * CABLE_NS_PER_M for m in cables_m]
    arrival: list[float] = []
    t = 0.0
    for k in range(n):
        t += cable[k] + (FORWARD_NS if k else 0.0)
        arrival.append(t)
    out: list[tuple[float, float]] = [(0.0, 0.0)] * n
    through = FORWARD_NS           # time from port 0 in to port 0 out, from the last slave backwards
    for k in range(n - 1, -1, -1):
        if k == n - 1:
            out[k] = (arrival[k], 0.0)
        else:
            back = FORWARD_NS + 2 * cable[k + 1] + through
            out[k] = (arrival[k], back)
            through = back + FORWARD_NS
    return out
