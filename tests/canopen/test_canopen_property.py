"""Property tests: random SDO / NMT / PDO frames only ever produce valid answers or silence.

Manual: IDX Communication Guide 3.3.3.2 (SDO), table 6-20 (abort codes), table 3-12 (NMT);
DEVELOPERS.md: bad input gets the spec's error, never a crash.
"""

from __future__ import annotations

from canopen_testkit import sample_od
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gatewaylab.bus import CanFrame, VirtualBus
from gatewaylab.canopen.node import Node
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.od import SdoAbort, SdoAbortCode

#: Commands that make the random walk reach every server state, plus anything at all.
_SDO_CS = st.sampled_from([0x00, 0x01, 0x10, 0x11, 0x21, 0x22, 0x23, 0x2B, 0x2F, 0x40, 0x60, 0x70, 0x80,
                           0xA0, 0xA1, 0xA2, 0xA3, 0xA4, 0xC0, 0xC1, 0xC2, 0xC4, 0xC6, 0x81, 0x05])
_INDEX = st.sampled_from([0x1000, 0x1003, 0x1010, 0x1011, 0x1017, 0x1400, 0x1600, 0x1800, 0x1A00,
                          0x2000, 0x2001, 0x2002, 0x2003, 0x2004, 0x2005, 0x2100, 0x2200, 0x3000])


@st.composite
def sdo_payload(draw: st.DrawFn) -> bytes:
    if draw(st.booleans()):
        return draw(st.binary(min_size=0, max_size=8))
    cs = draw(st.one_of(_SDO_CS, st.integers(0, 255)))
    index = draw(_INDEX)
    sub = draw(st.integers(0, 4))
    rest = draw(st.binary(min_size=4, max_size=4))
    return bytes([cs, index & 0xFF, index >> 8, sub]) + rest


def _valid_response(data: bytes) -> bool:
    """8 bytes; 0x80 (never a block segment: sequence numbers start at 1) is an abort with a known code."""
    if len(data) != 8:
        return False
    if data[0] == 0x80:
        return SdoAbortCode.known(int.from_bytes(data[4:], "little"))
    return True


def _setup() -> tuple[SimulatedClock, VirtualBus, Node, list[tuple[float, CanFrame]], object]:
    clock = SimulatedClock()
    vbus = VirtualBus(clock, "can0")
    node = Node(clock, vbus, 5, sample_od())
    node.start()
    out: list[tuple[float, CanFrame]] = []
    ctrl = vbus.attach("fuzzer", on_frame=lambda f, t: out.append((t, f)))
    clock.advance(0.001)
    out.clear()
    return clock, vbus, node, out, ctrl


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(sdo_payload(), st.floats(0, 1.5)), min_size=1, max_size=25))
def test_random_sdo_requests_get_valid_answers_or_silence(requests: list[tuple[bytes, float]]) -> None:
    """Table 6-20: every answer is an SDO response with a known command specifier or an abort with
    a code of the table; the server never raises and ends up usable."""
    clock, _vbus, _node, out, ctrl = _setup()
    for payload, pause in requests:
        ctrl.send(CanFrame(0x605, payload))  # type: ignore[attr-defined]
        clock.advance(pause)
    clock.advance(0.01)
    for _, frame in out:
        assert frame.can_id in (0x585, 0x85, 0x705), frame
        if frame.can_id == 0x585:
            assert _valid_response(frame.data), frame
    # usable afterwards: end whatever runs and read 0x1000
    out.clear()
    ctrl.send(CanFrame(0x605, bytes([0x80, 0, 0, 0, 0, 0, 0, 0])))  # type: ignore[attr-defined]
    ctrl.send(CanFrame(0x605, bytes([0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0])))  # type: ignore[attr-defined]
    clock.advance(0.01)
    assert [f.data[:4] for _, f in out if f.can_id == 0x585] == [bytes([0x43, 0x00, 0x10, 0x00])]


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(st.sampled_from([0x000, 0x080, 0x185, 0x205, 0x305, 0x605, 0x705, 0x707, 0x7E5]),
                          st.binary(max_size=8), st.booleans()), min_size=1, max_size=30))
def test_random_nmt_sync_pdo_frames_never_crash(frames: list[tuple[int, bytes, bool]]) -> None:
    """Table 3-12 and 3.3.3.1: random NMT, SYNC, PDO, guarding frames give only legal frames back."""
    clock, _vbus, node, out, ctrl = _setup()
    node.set(0x1017, 0, 10)
    node.heartbeat.start()
    for n, value in ((0, 0x20110010), (1, 0x20000020)):
        node.od.values[(0x1600 + n, 1)] = value
        node.od.values[(0x1600 + n, 0)] = 1
        node.od.values[(0x1A00 + n, 1)] = value
        node.od.values[(0x1A00 + n, 0)] = 1
    node.od.values[(0x1800, 2)] = 1
    node.pdo.reconfigure()
    ctrl.send(CanFrame(0, b"\x01\x05"))  # type: ignore[attr-defined]
    for can_id, data, rtr in frames:
        frame = CanFrame(can_id, b"", rtr=True, dlc=len(data)) if rtr else CanFrame(can_id, data)
        ctrl.send(frame)  # type: ignore[attr-defined]
        clock.advance(0.003)
    allowed = {0x85, 0x185, 0x285, 0x585, 0x705}
    for _, frame in out:
        assert frame.can_id in allowed, frame
        if frame.can_id == 0x705:
            assert len(frame.data) == 1 and frame.data[0] & 0x7F in (0, 4, 5, 0x7F)
        if frame.can_id == 0x85:
            assert len(frame.data) == 8


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(["upload", "segmented", "block_up", "download", "seg_down", "block_down"]),
       st.lists(st.binary(min_size=0, max_size=8), min_size=1, max_size=12))
def test_sdo_client_survives_random_answers(kind: str, answers: list[bytes]) -> None:
    """CiA 301 7.2.4 / table 6-20: whatever a server answers, the client ends every transfer with
    exactly one callback (data, None or an SdoAbort) and never raises."""
    from gatewaylab.canopen.sdo_client import SdoClient

    clock = SimulatedClock()
    sent: list[CanFrame] = []
    client = SdoClient(clock, sent.append, timeout=0.5)
    results: list[object] = []
    if kind in ("upload", "segmented", "block_up"):
        client.upload(5, 0x2000, 0, results.append, block=kind == "block_up")
    else:
        client.download(5, 0x2000, 0, b"x" * (3 if kind == "download" else 20), results.append,
                        segmented=kind == "seg_down", block=kind == "block_down")
    for data in answers:
        client.on_frame(CanFrame(0x585, data), clock.now())
    clock.advance(1.0)
    assert len(results) == 1, results
    assert results[0] is None or isinstance(results[0], (bytes, SdoAbort))   # a server's own code passes through
    for frame in sent:
        assert frame.can_id == 0x605 and len(frame.data) == 8
