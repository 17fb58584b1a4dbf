from collections.abc import Callable

import pytest

from gatewaylab.bus import BusEvent, CanFrame, Controller, VirtualBus
from gatewaylab.common.clock import SimulatedClock


class Recorder:
    """Collects what one controller receives and the events it reports."""

    def __init__(self) -> None:
        self.frames: list[tuple[CanFrame, float]] = []
        self.events: list[BusEvent] = []

    def on_frame(self, frame: CanFrame, t: float) -> None:
        self.frames.append((frame, t))

    def on_event(self, ev: BusEvent) -> None:
        self.events.append(ev)

    @property
    def ids(self) -> list[int]:
        return [f.can_id for f, _ in self.frames]


@pytest.fixture
def clock() -> SimulatedClock:
    return SimulatedClock()


@pytest.fixture
def bus(clock: SimulatedClock) -> VirtualBus:
    return VirtualBus(clock, "can0", 1_000_000, 5_000_000)


@pytest.fixture
def attach(bus: VirtualBus) -> Callable[..., tuple[Controller, Recorder]]:
    def _attach(name: str, **kwargs: object) -> tuple[Controller, Recorder]:
        rec = Recorder()
        ctrl = bus.attach(name, on_frame=rec.on_frame, on_event=rec.on_event, **kwargs)  # type: ignore[arg-type]
        return ctrl, rec

    return _attach
