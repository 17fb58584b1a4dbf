"""Who takes part in the bus's frames while nothing changes: the controllers that may send,
hear, acknowledge, or see only garbage (a foreign bit rate), and each kind of frame's receivers
with their callbacks. The bus builds an :class:`Audience` on demand and drops it whenever
something changes (``VirtualBus.audience_changed``, the one invalidation point)."""

from __future__ import annotations

from gatewaylab.bus.controller import Controller, ErrorState, FrameCallback
from gatewaylab.bus.stats import RxCounters

__all__ = ["Audience", "Route", "Routes"]


_BUS_OFF = ErrorState.BUS_OFF


#: the receivers of one kind of frame, each with its callback (None: it only counts REC down)
Route = tuple[tuple[Controller, FrameCallback | None], ...]


class Routes(dict[int, Route]):
    """The receivers of each kind of frame (see :data:`Route`), built when a kind is first
    asked for. Frames of one kind reach the same receivers: classic base frames by identifier,
    FD base frames by identifier + 0x800 (a range of their own), extended frames by format only
    (-1 classic, -2 FD); VirtualBus._deliver computes that key, the one place that does."""

    __slots__ = ("hear",)

    def __init__(self, hear: list[Controller]) -> None:
        super().__init__()
        self.hear = hear

    def __missing__(self, key: int) -> Route:
        """The route of a kind not seen since the audience was built: the receivers in
        attachment order, each with the callback it gets the frame through; receivers with
        REC > 0 are named even without a callback."""
        fd = key == -2 or key >= 0x800
        can_id = key - 0x800 if key >= 0x800 else key
        entries = []
        for c in self.hear:
            if fd and not c.fd:
                continue
            table = c.rx_table
            cb = c.on_frame if table is None else table.get(can_id)   # no extended ids in tables
            if cb is not None or c.rec:
                entries.append((c, cb))
        route = self[key] = tuple(entries)
        return route


class Audience:
    """Who takes part in frames while nothing changes on the bus, their callbacks per kind of
    frame, and what they received. The bus builds it on demand; VirtualBus.audience_changed (the one
    invalidation point) settles its receive counters and drops it."""

    __slots__ = ("acks", "fd_acks", "foreign", "hear", "routes", "rx", "senders")

    def __init__(self, controllers: list[Controller]) -> None:
        #: connected, not bus-off, matching bit timing: the controllers that may win arbitration
        self.senders = [c for c in controllers
                        if c.connected and c.state is not _BUS_OFF and c.timing_matches]
        live = [c for c in controllers if c.connected and c.state is not _BUS_OFF and not c.synthetic]
        #: controllers that hear frames (in attachment order)
        self.hear = [c for c in live if c.timing_matches]
        #: controllers at a foreign bit rate: every frame is a form error to them
        self.foreign = [c for c in live if not c.timing_matches]
        #: hearing controllers that acknowledge (not listen-only)
        self.acks = [c for c in self.hear if not c.listen_only]
        #: those of them that acknowledge FD frames
        self.fd_acks = [c for c in self.acks if c.fd]
        self.routes = Routes(self.hear)
        self.rx = RxCounters()

