"""Shared helpers of the ecan-mcan tests: an McanModel on simulated buses with its dictionary.

No master: the tests read and write the dictionary as CoE SDO would (``od.read`` / ``od.write``
with wire bytes), so aborts and status codes come out exactly as a master sees them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from gatewaylab.bus import CanFrame, VirtualBus
from gatewaylab.bus.bus import BusEvent, Controller
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.ecanlite.model import McanModel
from gatewaylab.ethercat.description import DeviceDescription, build_od
from gatewaylab.od import ObjectDictionary


class Recorder:
    """What one peer controller receives and the events it reports."""

    def __init__(self) -> None:
        self.frames: list[tuple[CanFrame, float]] = []
        self.events: list[BusEvent] = []

    def on_frame(self, frame: CanFrame, t: float) -> None:
        self.frames.append((frame, t))

    def on_event(self, ev: BusEvent) -> None:
        self.events.append(ev)


@dataclass
class Rig:
    """One ECAN-Lite model, its dictionary and one bus per connected channel with a peer node."""

    clock: SimulatedClock
    buses: list[VirtualBus]
    peers: list[Controller]
    recorders: list[Recorder]
    model: McanModel
    od: ObjectDictionary
    reboots: list[float] = field(default_factory=list)

    # -- SDO-like access --------------------------------------------------------------------
    def w(self, index: int, sub: int, value: int) -> None:
        """Download ``value`` in the entry's size (raises SdoAbort like a CoE server)."""
        size = self.od.entry(index, sub).bit_length // 8
        self.od.write(index, sub, int(value).to_bytes(size, "little"))

    def r(self, index: int, sub: int) -> int:
        """Upload an entry as an unsigned integer."""
        return int.from_bytes(self.od.read(index, sub), "little")

    def configure(self, k: int, nominal: int = 1_000_000, data: int | None = 5_000_000, sp: int = 875,
                  **subs: int) -> int:
        """Phase E of 5.4.3 for channel k (FD when ``data``), extra subs as ``s62=...``; returns 0x800x:02."""
        index = 0x8001 + k
        self.w(index, 7, 0)
        self.w(index, 8, 0)
        self.w(index, 15, 1 if data else 0)
        self.w(index, 19, nominal)
        if data:
            self.w(index, 20, data)
        for s in (21, 22, 23, 24):
            self.w(index, s, sp)
        if not data:
            for s in (65, 66, 68, 72):
                self.w(index, s, 0)
        for name, value in subs.items():
            self.w(index, int(name[1:]), value)
        self.w(index, 1, 1)
        return self.r(index, 2)

    def run(self, dt: float = 0.01) -> None:
        """Let the buses run for ``dt`` seconds of simulated time."""
        self.clock.advance(dt)


def make_rig(channels: int = 1, bitrate: int = 1_000_000, data_bitrate: int | None = 5_000_000,
             flash_path: Path | None = None, *, connected: int | None = None) -> Rig:
    """A model with ``channels`` connected MCANs (each on its own bus with one peer), installed in a
    dictionary built from its object_defs."""
    clock = SimulatedClock()
    buses, peers, recorders, ctrls = [], [], [], []
    for k in range(channels if connected is None else connected):
        bus = VirtualBus(clock, f"can{k}", bitrate, data_bitrate)
        rec = Recorder()
        peers.append(bus.attach(f"peer{k}", on_frame=rec.on_frame, on_event=rec.on_event))
        buses.append(bus)
        recorders.append(rec)
        ctrls.append(bus.attach(f"mcan{k}"))
    model = McanModel(clock, ctrls, flash_path)
    od = build_od(DeviceDescription(name="ECAN-Lite", vendor_id=0x47574C42, product_code=0xEC1,
                                    objects=model.object_defs()))
    model.install(None, od)
    rig = Rig(clock, buses, peers, recorders, model, od)
    model.system.on_reboot = lambda: rig.reboots.append(clock.now())
    return rig
