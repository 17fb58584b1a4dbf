"""How long a frame may stay in the emulator before its reply is worth nothing (sans-I/O).

A real EtherCAT line holds a frame for the time it takes to pass its slaves and come back: well under a
millisecond (a full 1,514-byte frame lasts 123 us on 100 Mbit/s, each ESC adds about 1 us). An emulator
that was not scheduled (a stalled VM, a ``kill -STOP``, a loaded host) finds frames in its socket that
waited far longer; answering them would give the master replies no line ever delivers, which masters
that reuse frame indices (SOEM: 16 of them) match to newer requests. So the wire answers a frame only
while its age -- from the kernel's receive timestamp to the moment the reply would be sent -- is within
the limit, and drops it otherwise: the master sees a lost frame, which every master handles.

This module holds the decision and its bookkeeping as pure functions of nanosecond timestamps; the
wire (``ethercat/wire.py``) reads the clock and the socket. Dropped frames are reported once per burst
(:class:`LateDrops`): a burst ends when a frame is answered in time or the line falls idle, and bursts
that end within ``report_every_ns`` of the last report are merged into the next one.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Final

__all__ = [
    "DEFAULT_MAX_RESIDENCE_MS",
    "SCM_TIMESTAMPNS",
    "SOL_SOCKET",
    "LateBurst",
    "LateDrops",
    "is_late",
    "kernel_timestamp_ns",
    "residence_limit_ns",
]

#: The default limit (the rig's ``[ethercat] max_residence_ms``; docs/decisions.md gives the reasoning).
DEFAULT_MAX_RESIDENCE_MS: Final = 2.0
#: Linux's socket level and the ``SO_TIMESTAMPNS`` / ``SCM_TIMESTAMPNS`` value (asm-generic/socket.h,
#: x86 and arm); Python's socket module names neither before 3.14.
SOL_SOCKET: Final = 1
SCM_TIMESTAMPNS: Final = 35
_TIMESPEC = struct.Struct("@qq")   # struct timespec: tv_sec, tv_nsec (64-bit Linux)
#: At most one report per this many nanoseconds: bursts closer together are reported as one.
REPORT_EVERY_NS: Final = 1_000_000_000


def residence_limit_ns(max_residence_ms: float) -> int:
    """The limit in nanoseconds; 0 (no limit) for ``max_residence_ms <= 0``."""
    return int(max_residence_ms * 1e6) if max_residence_ms > 0 else 0


def is_late(received_ns: int, now_ns: int, limit_ns: int) -> bool:
    """True when a frame received at ``received_ns`` is older than ``limit_ns`` at ``now_ns`` (a limit of 0
    never is). A clock step backwards (``now_ns`` before ``received_ns``) counts as age 0."""
    return limit_ns > 0 and now_ns - received_ns > limit_ns


def kernel_timestamp_ns(ancdata: Iterable[tuple[int, int, bytes]]) -> int | None:
    """The receive time (Unix nanoseconds) in a ``recvmsg`` ancillary data list of a socket with
    ``SO_TIMESTAMPNS`` on, or None when it holds none."""
    for level, kind, data in ancdata:
        if level == SOL_SOCKET and kind == SCM_TIMESTAMPNS and len(data) >= _TIMESPEC.size:
            sec, nsec = _TIMESPEC.unpack_from(data)
            return int(sec) * 1_000_000_000 + int(nsec)
    return None


@dataclass(frozen=True, slots=True)
class LateBurst:
    """What one report says: frames dropped since the last report and the oldest one's age."""

    frames: int
    oldest_ns: int

    def describe(self, limit_ns: int) -> str:
        """The log line's text."""
        return (f"dropped {self.frames} frame(s) older than {limit_ns / 1e6:g} ms instead of answering them "
                f"late (oldest {self.oldest_ns / 1e6:.1f} ms): the emulator was not scheduled in time")


class LateDrops:
    """The count of frames dropped late and the pending report of the current burst."""

    __slots__ = ("_frames", "_last_report_ns", "_oldest_ns", "on_arrival", "report_every_ns", "total")

    def __init__(self, report_every_ns: int = REPORT_EVERY_NS) -> None:
        self.total = 0
        #: Of ``total``: frames that were already too old when the idle wire thread got them (it waited for
        #: frames since before they arrived): the kernel, the machine's scheduler or the interpreter lock held
        #: them, not the emulator's work on other frames or its lock.
        self.on_arrival = 0
        self.report_every_ns = report_every_ns
        self._frames = 0
        self._oldest_ns = 0
        self._last_report_ns: int | None = None

    @property
    def pending(self) -> bool:
        """Drops not reported yet."""
        return self._frames > 0

    def drop(self, age_ns: int, on_arrival: bool = False) -> None:
        """One frame dropped at ``age_ns``; ``on_arrival``: it came to an idle wire thread already that old."""
        self.total += 1
        if on_arrival:
            self.on_arrival += 1
        self._frames += 1
        self._oldest_ns = max(self._oldest_ns, age_ns)

    def report_due_in_ns(self, now_ns: int) -> int | None:
        """Nanoseconds until :meth:`settle` would report the pending drops (0: now), None when none pend."""
        if not self._frames:
            return None
        if self._last_report_ns is None:
            return 0
        return max(0, self._last_report_ns + self.report_every_ns - now_ns)

    def settle(self, now_ns: int) -> LateBurst | None:
        """The burst is over (a frame was answered in time, or the line is idle): the report to log, or None
        when nothing pends or the last report was less than ``report_every_ns`` ago (the drops then join
        the next report)."""
        if self.report_due_in_ns(now_ns) != 0:
            return None
        return self.flush(now_ns)

    def flush(self, now_ns: int) -> LateBurst | None:
        """The pending drops' report whenever the last one was (the wire stops), or None."""
        if not self._frames:
            return None
        burst = LateBurst(self._frames, self._oldest_ns)
        self._frames = 0
        self._oldest_ns = 0
        self._last_report_ns = now_ns
        return burst
