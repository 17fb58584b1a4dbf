"""Virtual CAN / CAN FD buses and their python-can faces."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from gatewaylab.bus.bus import (
    BusEvent,
    Controller,
    ErrorFrameEvent,
    ErrorKind,
    ErrorState,
    Outcome,
    StateChangeEvent,
    Transmission,
    TxAbortedEvent,
    TxDoneEvent,
    VirtualBus,
)
from gatewaylab.bus.frame import CanFrame, len_to_dlc
from gatewaylab.bus.timing import frame_duration

if TYPE_CHECKING:
    from gatewaylab.bus.transport.inprocess import InProcessBus

__all__ = [
    "BusEvent", "CanFrame", "Controller", "ErrorFrameEvent", "ErrorKind", "ErrorState", "Outcome",
    "StateChangeEvent", "Transmission", "TxAbortedEvent", "TxDoneEvent", "VirtualBus", "frame_duration",
    "len_to_dlc", "python_can_bus",
]


def python_can_bus(vbus: VirtualBus, **kwargs: Any) -> InProcessBus:
    """A python-can ``BusABC`` on ``vbus``; see :mod:`gatewaylab.bus.transport.inprocess`."""
    from gatewaylab.bus.transport.inprocess import InProcessBus

    return InProcessBus(vbus, **kwargs)
