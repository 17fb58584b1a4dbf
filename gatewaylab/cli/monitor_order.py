"""The decoded monitor's log in time order: the frames of the bus and what the rig's control endpoint
says of its controllers come from two sources with their own delays; :class:`TimeOrder` merges them.

Frames arrive in bus order, stamped with the instant they ended (the rig's clock); a controller
event ("CAN axis3: unplugged") is stamped when the monitor's poll of the rig saw it, and may be
read before frames that ended earlier but were still on their way. So the log holds every event
back for ``hold`` seconds and gives them out sorted by time (sans-I/O: the caller says what time
it is). :func:`sender_node` tells which CANopen node sent a frame, so that a controller coming
back can be stamped before the first frame it sent (a boot-up follows "plugged in again").
"""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Iterable

from gatewaylab.bus.frame import CanFrame
from gatewaylab.canopen.monitor import MonitorEvent

__all__ = ["TimeOrder", "sender_node"]

#: The function codes (COB-ID & 0x780) of what a CANopen node itself sends (CiA 301 7.3.5, the
#: predefined connection set): EMCY, TPDO1-4, SDO response, heartbeat / boot-up.
_NODE_SENDS = frozenset((0x080, 0x180, 0x280, 0x380, 0x480, 0x580, 0x700))


def sender_node(frame: CanFrame) -> int | None:
    """The node-ID whose own object ``frame`` is (predefined connection set), or None."""
    if frame.extended or frame.rtr or frame.fd:
        return None
    node = frame.can_id & 0x7F
    return node if node and frame.can_id & 0x780 in _NODE_SENDS else None


class TimeOrder:
    """A reorder buffer: ``add`` events as they are decoded, take them back sorted by time once they
    are ``hold`` seconds old (``due``), or all at the end (``flush``). Events of equal time keep the
    order they were added in. An event older than one already given out (later than ``hold``) is
    given out at once: the log never waits without end."""

    def __init__(self, hold: float) -> None:
        self.hold = hold
        self._heap: list[tuple[float, int, MonitorEvent]] = []
        self._seq = itertools.count()

    def __len__(self) -> int:
        return len(self._heap)

    def add(self, events: Iterable[MonitorEvent]) -> None:
        """Events just decoded (from frames, the rig's answers or the silence check)."""
        for event in events:
            heapq.heappush(self._heap, (event.t, next(self._seq), event))

    def due(self, now: float) -> list[MonitorEvent]:
        """The events at least ``hold`` seconds older than ``now``, oldest first."""
        limit = now - self.hold
        out = []
        while self._heap and self._heap[0][0] <= limit:
            out.append(heapq.heappop(self._heap)[2])
        return out

    def flush(self) -> list[MonitorEvent]:
        """Every event still held, oldest first (the monitor ends)."""
        out = [entry[2] for entry in sorted(self._heap)]
        self._heap.clear()
        return out
