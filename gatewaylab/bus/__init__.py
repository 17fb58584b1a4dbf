"""Virtual CAN / CAN FD buses and their python-can faces."""

from .bus import (
    BusEvent,
    Controller,
    ErrorFrameEvent,
    ErrorKind,
    ErrorState,
    StateChangeEvent,
    TxAbortedEvent,
    TxDoneEvent,
    VirtualBus,
)
from .frame import CanFrame, len_to_dlc
from .timing import frame_duration

__all__ = [
    "BusEvent", "CanFrame", "Controller", "ErrorFrameEvent", "ErrorKind", "ErrorState",
    "StateChangeEvent", "TxAbortedEvent", "TxDoneEvent", "VirtualBus", "frame_duration",
    "len_to_dlc", "python_can_bus",
]


def python_can_bus(vbus: VirtualBus, **kwargs: object) -> "InProcessBus":  # noqa: F821
    """A python-can ``BusABC`` on ``vbus``; see :mod:`gatewaylab.bus.transport.inprocess`."""
    from .transport.inprocess import InProcessBus

    return InProcessBus(vbus, **kwargs)  # type: ignore[arg-type]
