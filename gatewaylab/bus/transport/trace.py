"""Bus traces written by python-can's own writers (.log candump, .asc, .blf, .csv, ...)."""

from __future__ import annotations

import time
from pathlib import Path

import can

from ..bus import VirtualBus
from ..frame import CanFrame


class Trace:
    """Records every frame that completes on a bus, timestamped with bus time + wall-clock start."""

    def __init__(self, bus: VirtualBus, path: Path, epoch: float | None = None) -> None:
        self.bus = bus
        self.path = path
        #: Wall-clock time of bus time 0, so absolute-time formats (ASC, BLF) carry a real date.
        self.epoch = time.time() - bus.clock.now() if epoch is None else epoch
        self.writer: can.io.generic.MessageWriter = can.Logger(str(path))
        self.frames = 0
        bus.add_monitor(self._on_frame)

    def _on_frame(self, frame: CanFrame, t: float) -> None:
        self.frames += 1
        self.writer.on_message_received(frame.to_message(self.epoch + t, self.bus.name))

    def close(self) -> None:
        self.bus.remove_monitor(self._on_frame)
        self.writer.stop()
