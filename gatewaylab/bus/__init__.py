"""Virtual CAN / CAN FD buses and their python-can faces.

The public path of the bus API (docs/architecture.md "The bus API"): every name below lives in one
module of this package (its home, named in the import) and is re-exported here on purpose.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from gatewaylab.bus.bus import VirtualBus
from gatewaylab.bus.controller import (
    BusEvent,
    Controller,
    ErrorFrameEvent,
    ErrorKind,
    ErrorState,
    StateChangeEvent,
    TxAbortedEvent,
    TxDoneEvent,
)
from gatewaylab.bus.frame import CanFrame, len_to_dlc
from gatewaylab.bus.timing import frame_duration
from gatewaylab.bus.transmission import Outcome, Transmission

if TYPE_CHECKING:
    from gatewaylab.bus.controller import ControllerBus
    from gatewaylab.bus.faults import FaultedBus
    from gatewaylab.bus.transport.inprocess import InProcessBus

    def _implements(bus: VirtualBus) -> tuple[ControllerBus, FaultedBus]:
        """mypy checks here that the bus is what its controllers and its fault injector ask of it."""
        return bus, bus

__all__ = [
    "BusEvent", "CanFrame", "Controller", "ErrorFrameEvent", "ErrorKind", "ErrorState", "Outcome",
    "StateChangeEvent", "Transmission", "TxAbortedEvent", "TxDoneEvent", "VirtualBus", "frame_duration",
    "len_to_dlc", "python_can_bus",
]


def python_can_bus(vbus: VirtualBus, **kwargs: Any) -> InProcessBus:
    """A python-can ``BusABC`` on ``vbus``; see :mod:`gatewaylab.bus.transport.inprocess`."""
    from gatewaylab.bus.transport.inprocess import InProcessBus

    return InProcessBus(vbus, **kwargs)
