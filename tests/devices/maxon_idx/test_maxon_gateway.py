"""CanGateway on a virtual bus: NMT and LSS frames (IDX guide 2.1.2.4, 2.1.3, 3.3.3.5, 3.5, chapter 5)."""

from __future__ import annotations

from typing import Any

from gatewaylab.bus import CanFrame, VirtualBus
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.common.errors import GatewaylabError
from gatewaylab.devices.maxon_idx.errors import IdxRemoteError, SdoAbortCode
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
        assert exc.code == SdoAbortCode.DATA_CANNOT_BE_STORED_DEVICE_STATE
    else:
        raise AssertionError("ReadLSS without SendLSS accepted")
    gw.send_lss(bytes(8))
    gw.read_lss(0.02, results.append)
    clock.advance(0.019)
    assert results == []
    clock.advance(0.002)
    assert len(results) == 1 and isinstance(results[0], IdxRemoteError)
    assert results[0].code == SdoAbortCode.SDO_PROTOCOL_TIMED_OUT


def test_sdo_frames_routed_to_client() -> None:
    """Chapter 5 steps 3-4: the node's SDO answer on 0x580+n reaches the gateway's SDO client."""
    clock, _bus, gw, _seen, (sdo, other), _own = make()
    other.send(CanFrame(0x582, bytes([0x4B, 0x41, 0x60, 0, 0x37, 0x02, 0, 0])))
    clock.advance(0.01)
    assert sdo.frames and sdo.frames[0].can_id == 0x582
    gw.upload(2, 0x1008, 0, lambda r: None, segmented=True)
    assert sdo.calls == [("up", 2, 0x1008, 0, True)]


def test_read_object_is_an_expedited_upload() -> None:
    """Chapter 5 + notes ("maxon's own PC library performs ReadObject via an expedited upload"):
    ReadObject to node 2 is a CiA 301 initiate upload 0x40 on 0x602; an expedited answer with the
    size indicated gives exactly its bytes; an abort passes its code through."""
    clock, _bus, gw, seen, (sdo, other), _own = make()
    results: list[bytes | GatewaylabError] = []
    gw.upload(2, 0x6041, 0, results.append, segmented=False)
    clock.advance(0.001)
    assert seen[-1] == CanFrame(0x602, bytes([0x40, 0x41, 0x60, 0, 0, 0, 0, 0]))
    other.send(CanFrame(0x582, bytes([0x4B, 0x41, 0x60, 0, 0x37, 0x02, 0, 0])))    # 2 bytes (n = 2)
    clock.advance(0.001)
    assert results == [b"\x37\x02"] and sdo.calls == [] and sdo.frames == []
    gw.upload(2, 0x6041, 0, results.append, segmented=False)
    clock.advance(0.001)
    other.send(CanFrame(0x582, bytes([0x80, 0x41, 0x60, 0, 0x00, 0x00, 0x02, 0x06])))
    clock.advance(0.001)
    assert isinstance(results[1], IdxRemoteError) and results[1].code == 0x06020000


def test_read_object_of_a_long_object_aborts_the_segmented_answer() -> None:
    """2.1.1.1 ReadObject reads "up to 4 bytes": when the node starts a segmented upload (cs 0x41,
    e = 0) the gateway aborts it on the bus with 0x06070010 instead of fetching every segment, and
    answers the same code."""
    clock, _bus, gw, seen, (_sdo, other), _own = make()
    results: list[bytes | GatewaylabError] = []
    gw.upload(2, 0x1008, 0, results.append, segmented=False)
    clock.advance(0.001)
    other.send(CanFrame(0x582, bytes([0x41, 0x08, 0x10, 0, 29, 0, 0, 0])))
    clock.advance(0.001)
    assert seen[-1] == CanFrame(0x602, bytes([0x80, 0x08, 0x10, 0, 0x10, 0x00, 0x07, 0x06]))
    assert isinstance(results[0], IdxRemoteError) and results[0].code == SdoAbortCode.LENGTH_MISMATCH
    assert [f for f in seen if f.can_id == 0x602 and f.data[0] & 0xE0 == 0x60] == []   # no segment request


def test_read_object_of_a_silent_node_times_out() -> None:
    """Chapter 6: no answer within the SDO timeout -> 0x05040000, and the transfer is aborted."""
    clock, _bus, gw, seen, _x, _own = make()
    results: list[bytes | GatewaylabError] = []
    gw.upload(9, 0x1000, 0, results.append, segmented=False)
    clock.advance(0.49)
    assert results == []
    clock.advance(0.02)
    assert isinstance(results[0], IdxRemoteError) and results[0].code == 0x05040000
    assert seen[-1] == CanFrame(0x609, bytes([0x80, 0x00, 0x10, 0, 0x00, 0x00, 0x04, 0x05]))
