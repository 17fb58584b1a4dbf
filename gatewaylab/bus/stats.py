"""Frame and error counters of a bus and of its controllers, and the receive tallies that keep
counting off the per-frame path (the bus counts each delivered frame once, per sender; each
receiver's share is settled into its :class:`ControllerStats` when the audience changes or the
counters are read)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from gatewaylab.bus.frame import CanFrame

if TYPE_CHECKING:
    from gatewaylab.bus.controller import Controller

__all__ = ["BusStats", "ControllerStats", "RxCounters"]


@dataclass(slots=True)
class ControllerStats:
    """Frame and error counters of one controller (``controller.stats``)."""
    tx_frames: int = 0
    rx_frames: int = 0
    tx_bytes: int = 0
    rx_bytes: int = 0
    error_frames: int = 0
    tx_retransmissions: int = 0
    #: times the controller went bus-off (a short bus-off with auto-recovery leaves only this trace)
    bus_offs: int = 0


@dataclass(slots=True)
class BusStats:
    """Frame, error and busy-time counters of the whole bus since ``since`` (``bus.stats``)."""
    frames: int = 0
    bytes: int = 0
    error_frames: int = 0
    dropped_frames: int = 0
    busy_time: float = 0.0
    since: float = 0.0


class RxCounters:
    """Receive counters of one audience. Every hearing controller receives every delivered frame
    but its own (and no FD frame when it is not FD capable), so the bus tallies each frame once,
    per sender, and adds each receiver's share to its stats when the audience ends or stats are
    read (settle)."""

    __slots__ = ("sent",)

    def __init__(self) -> None:
        #: per sender: [frames, bytes, FD frames, FD bytes] delivered since the last settle
        self.sent: dict[Controller, list[int]] = {}

    def count(self, sender: Controller, frame: CanFrame) -> None:
        """One delivered frame."""
        try:
            tally = self.sent[sender]
        except KeyError:
            tally = self.sent[sender] = [0, 0, 0, 0]
        n = len(frame.data)
        tally[0] += 1
        tally[1] += n
        if frame.fd:
            tally[2] += 1
            tally[3] += n

    def settle(self, receivers: list[Controller]) -> None:
        """Add what each receiver got since the last settle to its stats; start again from zero."""
        sent = self.sent
        if not sent:
            return
        frames, nbytes, fd_frames, fd_bytes = (sum(column) for column in zip(*sent.values()))
        for c in receivers:
            own = sent.get(c, (0, 0, 0, 0))
            st = c.counters
            if c.fd:
                st.rx_frames += frames - own[0]
                st.rx_bytes += nbytes - own[1]
            else:   # its own frames are classic ones
                st.rx_frames += frames - fd_frames - own[0]
                st.rx_bytes += nbytes - fd_bytes - own[1]
        sent.clear()

