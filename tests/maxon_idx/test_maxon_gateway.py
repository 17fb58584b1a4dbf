"""CanGateway on a virtual bus: NMT and LSS frames (IDX guide 2.1.2.4, 2.1.3, 3.3.3.5, 3.5, chapter 5)."""

from __future__ import annotations

from typing import Any

from gatewaylab.bus import CanFrame, VirtualBus
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.common.errors import GatewaylabError
from gatewaylab.devices.maxon_idx.errors import ErrorCode, IdxRemoteError
from gatewaylab.devices.maxon_idx.gateway import CanGateway


class FakeSdo:
    def __init__(self) -> None:
        self.calls: list[tuple[Any, ...]] = []
        self.frames: list[CanFrame] = []

    def upload(self, node_id: int, index: int, sub: int, callback: Any, *,
               segmented: bool | None = None, block: bool = False) -> None:
        self.calls.append(("up", node_id, index, sub, segmented))

    def download(self, node_id: int, index: int, sub: int, data: bytes, callback: Any) -> None:
        self.calls.append(("down", node_id, index, sub, data))

    def on_frame(self, frame: CanFrame, t: float) -> None:
        self.frames.append(frame)


def make() -> tuple[SimulatedClock, VirtualBus, CanGateway, list[CanFrame], Any, list[int]]:
    clock = SimulatedClock()
    bus = VirtualBus(clock, "can0", bitrate=1_000_000)
    seen: list[CanFrame] = []
    sdo = FakeSdo()
    own: list[int] = []
    gw: CanGateway | None = None

    def on_frame(frame: CanFrame, t: float) -> None:
        assert gw is not None
        gw.on_frame(frame, t)

    idx = bus.attach("idx", on_frame=on_frame)
    gw = CanGateway(clock, idx.send, sdo, on_own_nmt=own.append, own_node_id=lambda: 1)
    other = bus.attach("other", on_frame=lambda f, t: seen.append(f))
    return clock, bus, gw, seen, (sdo, other), own


def test_nmt_frame_on_bus_and_applied_to_self() -> None:
    """Table 3-12: NMT COB-ID 0, CS then node id; node 0 addresses all nodes, the IDX included."""
    clock, _bus, gw, seen, _x, own = make()
    gw.send_nmt(2, 1)
    gw.send_nmt(0, 2)
    clock.advance(0.01)
    assert seen == [CanFrame(0, bytes([1, 2])), CanFrame(0, bytes([2, 0]))]
    assert own == [2]


def test_lss_request_and_answer() -> None:
    """3.5: master messages on 0x7E5, slave answers on 0x7E4; ReadLSS gets the next answer."""
    clock, _bus, gw, seen, (sdo, other), _own = make()
    results: list[bytes | GatewaylabError] = []
    gw.send_lss(bytes([0x5E]) + bytes(7))
    clock.advance(0.001)
    assert seen[-1] == CanFrame(0x7E5, bytes([0x5E]) + bytes(7))
    gw.read_lss(0.05, results.append)
    other.send(CanFrame(0x7E4, bytes([0x5E, 7]) + bytes(6)))
    clock.advance(0.001)
    assert results == [bytes([0x5E, 7]) + bytes(6)]
    assert sdo.frames == []


def test_lss_answer_before_read_is_kept() -> None:
    """2.1.3.2: the answer may reach the IDX before the host's ReadLSS; it is not lost."""
    clock, _bus, gw, _seen, (_sdo, other), _own = make()
    gw.send_lss(bytes([0x4C]) + bytes(7))
    other.send(CanFrame(0x7E4, bytes([0x50]) + bytes(7)))
    clock.advance(0.01)
    results: list[bytes | GatewaylabError] = []
    gw.read_lss(0.0, results.append)
    assert results == [bytes([0x50]) + bytes(7)]


def test_lss_timeout_and_not_armed() -> None:
    """2.1.3.2: ReadLSS only after SendLSS (0x08000022); no answer in time -> 0x05040000."""
    clock, _bus, gw, _seen, _x, _own = make()
    results: list[bytes | GatewaylabError] = []
    try:
        gw.read_lss(0.01, results.append)
    except IdxRemoteError as exc:
        assert exc.code == ErrorCode.WRONG_DEVICE_STATE
    else:
        raise AssertionError("ReadLSS without SendLSS accepted")
    gw.send_lss(bytes(8))
    gw.read_lss(0.02, results.append)
    clock.advance(0.019)
    assert results == []
    clock.advance(0.002)
    assert len(results) == 1 and isinstance(results[0], IdxRemoteError)
    assert results[0].code == ErrorCode.SDO_TIMEOUT


def test_sdo_frames_routed_to_client() -> None:
    """Chapter 5 steps 3-4: the node's SDO answer on 0x580+n reaches the gateway's SDO client."""
    clock, _bus, gw, _seen, (sdo, other), _own = make()
    other.send(CanFrame(0x582, bytes([0x4B, 0x41, 0x60, 0, 0x37, 0x02, 0, 0])))
    clock.advance(0.01)
    assert sdo.frames and sdo.frames[0].can_id == 0x582
    gw.upload(2, 0x6041, 0, lambda r: None, segmented=False)
    assert sdo.calls == [("up", 2, 0x6041, 0, None)]
