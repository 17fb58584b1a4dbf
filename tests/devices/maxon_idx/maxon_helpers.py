"""Helpers of the maxon IDX tests (a uniquely named module: every test folder has a conftest)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from gatewaylab.common.clock import SimulatedClock
from gatewaylab.common.errors import GatewaylabError
from gatewaylab.devices.maxon_idx.codec import Frame, FrameDecoder, FrameReceived
from gatewaylab.devices.maxon_idx.errors import IdxRemoteError, SdoAbortCode
from gatewaylab.devices.maxon_idx.protocol import IdxSlave


class DictObjects:
    """ObjectAccess over a dict {(index, sub): (bytes, size or None, access)}."""

    def __init__(self) -> None:
        self.values: dict[tuple[int, int], bytearray] = {}
        self.sizes: dict[tuple[int, int], int | None] = {}
        self.access: dict[tuple[int, int], str] = {}

    def add(self, index: int, sub: int, value: bytes, size: int | None = None, access: str = "rw") -> None:
        self.values[(index, sub)] = bytearray(value)
        self.sizes[(index, sub)] = size
        self.access[(index, sub)] = access

    def _key(self, index: int, sub: int) -> tuple[int, int]:
        if (index, sub) not in self.values:
            raise IdxRemoteError(SdoAbortCode.OBJECT_DOES_NOT_EXIST)
        return (index, sub)

    def read(self, index: int, subindex: int) -> bytes:
        key = self._key(index, subindex)
        if self.access[key] == "wo":
            raise IdxRemoteError(SdoAbortCode.WRITE_ONLY)
        return bytes(self.values[key])

    def write(self, index: int, subindex: int, data: bytes) -> None:
        key = self._key(index, subindex)
        if self.access[key] == "ro":
            raise IdxRemoteError(SdoAbortCode.READ_ONLY)
        size = self.sizes[key]
        if size is not None and len(data) != size:
            raise IdxRemoteError(SdoAbortCode.LENGTH_MISMATCH)
        self.values[key] = bytearray(data)

    def value_size(self, index: int, subindex: int) -> int | None:
        return self.sizes[self._key(index, subindex)]

    def check_write(self, index: int, subindex: int) -> None:
        if self.access[self._key(index, subindex)] == "ro":
            raise IdxRemoteError(SdoAbortCode.READ_ONLY)


@dataclass
class ScriptedGateway:
    """Gateway whose answers the test hands out by calling the stored callbacks."""

    uploads: list[tuple[int, int, int, bool, Callable[[bytes | GatewaylabError], None]]] = field(
        default_factory=list)
    downloads: list[tuple[int, int, int, bytes, Callable[[GatewaylabError | None], None]]] = field(
        default_factory=list)
    nmt: list[tuple[int, int]] = field(default_factory=list)
    lss_sent: list[bytes] = field(default_factory=list)
    lss_reads: list[tuple[float, Callable[[bytes | GatewaylabError], None]]] = field(default_factory=list)

    def upload(self, node_id: int, index: int, subindex: int,
               callback: Callable[[bytes | GatewaylabError], None], *, segmented: bool) -> None:
        self.uploads.append((node_id, index, subindex, segmented, callback))

    def download(self, node_id: int, index: int, subindex: int, data: bytes,
                 callback: Callable[[GatewaylabError | None], None]) -> None:
        self.downloads.append((node_id, index, subindex, data, callback))

    def send_nmt(self, node_id: int, command: int) -> None:
        self.nmt.append((node_id, command))

    def send_lss(self, data: bytes) -> None:
        self.lss_sent.append(data)

    def read_lss(self, timeout: float, callback: Callable[[bytes | GatewaylabError], None]) -> None:
        if not self.lss_sent:
            raise IdxRemoteError(SdoAbortCode.DATA_CANNOT_BE_STORED_DEVICE_STATE)
        self.lss_reads.append((timeout, callback))


class SlaveHarness:
    """An IdxSlave on a simulated clock whose replies are decoded back into frames."""

    def __init__(self, own_node_id: int = 1) -> None:
        self.clock = SimulatedClock()
        self.objects = DictObjects()
        self.gateway = ScriptedGateway()
        self.wire: list[bytes] = []
        self.replies: list[Frame] = []
        self.slave = IdxSlave(self.clock, self.objects, self.gateway, lambda: own_node_id, self.wire.append)
        self._rx = FrameDecoder(self.clock, self._on_reply, timeout=None)

    def _on_reply(self, event: object) -> None:
        assert isinstance(event, FrameReceived), event
        self.replies.append(event.frame)

    def feed(self, data: bytes) -> list[Frame]:
        """Feed request bytes; return the reply frames that came out since the last call."""
        self.slave.receive(data)
        return self.collect()

    def collect(self) -> list[Frame]:
        start = len(self.replies)
        for chunk in self.wire:
            self._rx.feed(chunk)
        self.wire.clear()
        return self.replies[start:]


# -- real-time rig loop (transport and end-to-end tests) -------------------------------------------
class RunningRig:
    """A real-time Rig whose loop runs in a thread; setup happens under ``clock.lock``."""

    def __init__(self, data: dict[str, object]) -> None:
        from gatewaylab.common.clock import RealTimeClock
        from gatewaylab.rig.config import parse_rig
        from gatewaylab.rig.runtime import Rig

        self.rig = Rig(parse_rig(data), clock=RealTimeClock(), endpoints=False)
        self.thread: object = None

    def start(self) -> None:
        self.thread = self.rig.run_in_thread()

    def close(self) -> None:
        import threading

        self.rig.request_stop()
        if isinstance(self.thread, threading.Thread):
            self.thread.join(5)
        self.rig.close()


class IdxRig(RunningRig):
    """A real-time rig with the IDX (node 1, pty + TCP) from a rig-file dict, plus plain drives."""

    def __init__(self, drives: list[tuple[int | None, int]], latency_ms: float = 0.0) -> None:
        super().__init__({
            "clock": "realtime",
            "bus": [{"name": "can0", "bitrate": 1_000_000, "endpoint": "none"}],
            "device": [{"kind": "maxon_idx", "name": "idx1", "bus": "can0", "node_id": 1, "serial": 0x2001,
                        "usb": {"pty": True, "tcp_port": 0, "latency_ms": latency_ms}}],
        })
        from gatewaylab.bus import CanFrame
        from gatewaylab.devices.canopen_drive.device import Drive

        rig = self.rig
        self.bus = rig.buses["can0"]
        self.frames: list[CanFrame] = []
        self.bus.add_monitor(lambda frame, t: self.frames.append(frame))
        with rig.clock.lock:
            self.drives = [Drive(rig.clock, self.bus, node_id, serial, f"drive{serial:x}")
                           for node_id, serial in drives]
            for d in self.drives:
                d.start()
            rig.start()
        self.idx = rig.participants[0]
        self.info = rig.ready_info()
        self.start()

    def close(self) -> None:
        super().close()
        for d in self.drives:
            d.stop()
