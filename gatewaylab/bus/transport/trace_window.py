"""A time window of a trace (``--from`` / ``--to`` of ``plot``, ``play``, ``dump --replay`` and ``monitor
--replay``): trace time, its origin, and which frames fall inside."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass

from gatewaylab.bus.transport.trace import TraceItem
from gatewaylab.common.errors import ConfigError

__all__ = ["UNIX_TIME_FROM", "TimeBound", "TimeWindow", "trace_origin"]

#: A timestamp at or above this is Unix time; below it, time since the rig started (a rig's .asc trace).
UNIX_TIME_FROM = 1e8


def trace_origin(first_stamp: float) -> float:
    """Time 0 of trace time, from the trace's first timestamp: a trace in Unix time (.log, .blf, .pcap,
    ...) counts from its first frame (the rig's start is not in the file); one already relative to the
    rig's start (.asc) counts from there. The times ``monitor --replay`` prints and ``plot`` draws."""
    return first_stamp if first_stamp >= UNIX_TIME_FROM else 0.0


@dataclass(frozen=True, slots=True)
class TimeBound:
    """One end of a :class:`TimeWindow`: ``seconds`` of trace time (a Unix time when at least
    :data:`UNIX_TIME_FROM`), or with ``relative`` (written ``+S``) seconds after a reference: for
    ``--from`` the trace's first frame, for ``--to`` the window's start."""

    seconds: float
    relative: bool = False

    @classmethod
    def parse(cls, text: str, option: str) -> TimeBound:
        """``T`` or ``+S`` (seconds, >= 0); anything else is a :class:`ConfigError` naming ``option``."""
        body = text.strip()
        relative = body.startswith("+")
        try:
            seconds = float(body[1:] if relative else body)
        except ValueError:
            seconds = float("nan")
        if not seconds >= 0 or seconds == float("inf"):
            raise ConfigError(f"{option} wants seconds of trace time (T) or seconds after a reference (+S), "
                              f"0 or more, got {text!r}")
        return cls(seconds, relative)


@dataclass(frozen=True, slots=True)
class TimeWindow:
    """The frames of a trace from ``start`` (included) to ``end`` (excluded), in trace time.

    ``--from T``: T s of trace time (see :func:`trace_origin`; a Unix time if T >= 1e8); ``--from +S``:
    S s after the trace's first frame. ``--to T``: up to trace time T; ``--to +D``: D s after the
    window's start (``--from``, else the first frame). No bound: the trace's start / end."""

    start: TimeBound | None = None
    end: TimeBound | None = None

    @classmethod
    def parse(cls, start: str | None, end: str | None) -> TimeWindow:
        """``--from`` / ``--to`` as given (None: not given); an empty window is refused here when the
        two forms can be compared without the trace (otherwise by :meth:`bounds`)."""
        window = cls(None if start is None else TimeBound.parse(start, "--from"),
                     None if end is None else TimeBound.parse(end, "--to"))
        low, high = window.start, window.end
        if high is not None and (
                (high.relative and high.seconds == 0)
                or (low is not None and not low.relative and not high.relative
                    and (low.seconds >= UNIX_TIME_FROM) == (high.seconds >= UNIX_TIME_FROM)
                    and high.seconds <= low.seconds)):
            raise ConfigError(f"--to {end} is not after --from {start or '(the first frame)'}: the window is empty")
        return window

    def __bool__(self) -> bool:
        return self.start is not None or self.end is not None

    def bounds(self, first_stamp: float) -> tuple[float, float]:
        """``(low, high)`` in the trace's own timestamps, for a trace whose first timestamp is
        ``first_stamp``; a :class:`ConfigError` when ``--to`` is not after ``--from``."""
        origin = trace_origin(first_stamp)

        def at(bound: TimeBound, reference: float) -> float:
            if bound.relative:
                return reference + bound.seconds
            return bound.seconds if bound.seconds >= UNIX_TIME_FROM else origin + bound.seconds
        low = -float("inf") if self.start is None else at(self.start, first_stamp)
        high = float("inf") if self.end is None else at(
            self.end, first_stamp if self.start is None else low)
        if high <= low:
            raise ConfigError(f"--to ({high - origin:.6f} s of trace time) is not after --from "
                              f"({low - origin:.6f} s)")
        return low, high

    def select(self, items: Iterable[TraceItem | None]) -> Iterator[TraceItem]:
        """The items of ``items`` (a whole trace, first item first; None, a live view's idle tick, is
        skipped) inside the window."""
        bounds: tuple[float, float] | None = None
        for item in items:
            if item is None:
                continue
            if bounds is None:
                bounds = self.bounds(item[1])
            if bounds[0] <= item[1] < bounds[1]:
                yield item
