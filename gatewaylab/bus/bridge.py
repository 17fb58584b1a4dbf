"""The decisions of a bridge between a virtual bus and a real python-can bus, sans-I/O.

The transport (``bus/transport/bridge.py``) owns the python-can bus and its threads; this module says
what to do with what it sees: which received messages cross to the virtual bus (not the echoes of
what the bridge itself sent, not error frames), what an error frame means (SocketCAN's
linux/can/error.h classes, which python-can passes on as the arbitration id of an error frame), and
how long to wait before the next attempt to open a vanished adapter.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from enum import Enum

from gatewaylab.bus.frame import CanFrame

__all__ = [
    "CAN_ERR_BUSOFF",
    "CAN_ERR_RESTARTED",
    "Backoff",
    "BridgeStats",
    "EchoFilter",
    "LinkState",
    "Verdict",
    "classify",
]


#: linux/can/error.h: the controller went bus-off / was restarted
CAN_ERR_BUSOFF = 0x040
CAN_ERR_RESTARTED = 0x100


class LinkState(Enum):
    """Where the real side of a bridge is."""

    CONNECTING = "connecting"    # not opened yet, or waiting for the next attempt
    UP = "up"
    BUS_OFF = "bus-off"          # the real controller reported bus-off; reopened after a back-off
    DOWN = "down"                # the adapter failed (vanished, driver error); reopened after a back-off
    CLOSED = "closed"


class Verdict(Enum):
    """What to do with one message received from the real side."""

    FORWARD = "forward"      # a frame of another node: put it on the virtual bus
    ECHO = "echo"            # the bridge's own frame coming back (receive_own_messages): dropped
    ERROR = "error"          # an error frame: counted, not forwarded
    BUS_OFF = "bus-off"      # an error frame saying bus-off: the link is restarted


def classify(is_error_frame: bool, is_rx: bool, arbitration_id: int) -> Verdict:
    """The verdict on a received python-can message (its ``is_error_frame``, ``is_rx`` and id)."""
    if is_error_frame:
        return Verdict.BUS_OFF if arbitration_id & CAN_ERR_BUSOFF else Verdict.ERROR
    if not is_rx:
        return Verdict.ECHO
    return Verdict.FORWARD


class EchoFilter:
    """Recognises the bridge's own frames coming back from interfaces that loop them back without
    marking them (python-can's ``udp_multicast`` receives its own datagrams, ``is_rx`` true).

    A received frame equal to one the bridge sent within ``window`` seconds is that frame's echo (and
    consumed); ``now`` is any monotonic time the caller passes in.
    """

    def __init__(self, window: float = 0.5, limit: int = 4096) -> None:
        self.window = window
        self._sent: deque[tuple[float, CanFrame]] = deque(maxlen=limit)

    def sent(self, frame: CanFrame, now: float) -> None:
        """Remember a frame this side forwarded, so its echo from the other side is recognised."""
        self._sent.append((now + self.window, frame))

    def is_echo(self, frame: CanFrame, now: float) -> bool:
        """True when ``frame`` is the echo of one forwarded within the window (it is then forgotten)."""
        sent = self._sent
        while sent and sent[0][0] < now:
            sent.popleft()
        for i, (_, mine) in enumerate(sent):
            if mine == frame:
                del sent[i]
                return True
        return False


class Backoff:
    """Exponential back-off between attempts to (re)open the real side: initial, x2, ..., maximum."""

    def __init__(self, initial: float = 0.1, maximum: float = 5.0) -> None:
        self.initial = initial
        self.maximum = maximum
        self._next = initial

    def next(self) -> float:
        """The delay before the next attempt (and double it for the one after)."""
        delay = self._next
        self._next = min(self.maximum, self._next * 2)
        return delay

    def reset(self) -> None:
        """The link works again: the next failure starts from ``initial``."""
        self._next = self.initial


@dataclass(slots=True)
class BridgeStats:
    """What crossed a bridge and what did not."""

    to_real: int = 0           # virtual -> real, sent
    from_real: int = 0         # real -> virtual, put on the virtual bus
    echoes: int = 0            # own frames received back from the real side, dropped
    error_frames: int = 0      # error frames of the real side
    lost: int = 0              # virtual -> real frames that met no open adapter or a failed send
    refused: int = 0           # real -> virtual frames the virtual bus could not carry (FD on classic)
    reconnects: int = 0        # the real side was opened again after a failure
