"""Command and reply codecs of IDX guide 2.1: layouts, Len values, round trips."""

from __future__ import annotations

from collections.abc import Callable

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from maxon_helpers import SlaveHarness

from gatewaylab.common.errors import LocalError
from gatewaylab.devices.maxon_idx.codec import Frame, FrameDecoder, FrameReceived, encode_frame
from gatewaylab.devices.maxon_idx.commands import (
    InitiateSegmentedRead,
    InitiateSegmentedReadReply,
    InitiateSegmentedWrite,
    ReadLss,
    ReadLssReply,
    ReadObject,
    ReadObjectReply,
    Request,
    SegmentRead,
    SegmentReadReply,
    SegmentWrite,
    SegmentWriteReply,
    SendLss,
    SendNmtService,
    StatusReply,
    WriteObject,
    decode_reply,
    decode_request,
)

u8, u16, u32 = st.integers(0, 0xFF), st.integers(0, 0xFFFF), st.integers(0, 0xFFFFFFFF)
requests = st.one_of(
    st.builds(ReadObject, u8, u16, u8),
    st.builds(InitiateSegmentedRead, u8, u16, u8),
    st.builds(SegmentRead, st.booleans()),
    st.builds(WriteObject, u8, u16, u8, st.binary(min_size=4, max_size=4)),
    st.builds(InitiateSegmentedWrite, u8, u16, u8, u32),
    st.builds(SegmentWrite, st.booleans(), st.booleans(), st.binary(max_size=255)),
    st.builds(SendNmtService, u16, u16),
    st.builds(SendLss, st.binary(min_size=8, max_size=8)),
    st.builds(ReadLss, u16),
)


def test_request_lengths_match_the_guide() -> None:
    """2.1: Len of ReadObject 2, InitiateSegmentedRead 2, SegmentRead 1, WriteObject 4,
    InitiateSegmentedWrite 4, SegmentWrite 1..129, SendNMTService 2, SendLSS 4, ReadLSS 2 (a timeout
    WORD; the second word is zero)."""
    assert ReadObject(1, 0x30B0, 0).to_frame().length == 2
    assert InitiateSegmentedRead(1, 0x1008, 0).to_frame().length == 2
    assert SegmentRead(True).to_frame() == Frame(0x62, bytes([0x01, 0x00]))
    assert WriteObject(1, 0x6040, 0, bytes(4)).to_frame().length == 4
    assert InitiateSegmentedWrite(1, 0x1008, 0, 10).to_frame().length == 4
    assert SegmentWrite(False, False, b"").to_frame().length == 1
    assert SegmentWrite(True, True, bytes(255)).to_frame().length == 129
    assert SegmentWrite(True, True, b"abc").to_frame() == Frame(0x6A, bytes([3, 0x03]) + b"abc" + b"\x00")
    assert SendNmtService(2, 1).to_frame() == Frame(0x70, bytes([2, 0, 1, 0]))
    assert SendLss(bytes(8)).to_frame().length == 4
    assert ReadLss(100).to_frame() == Frame(0x7B, bytes([100, 0, 0, 0]))


def test_reply_lengths_match_the_guide() -> None:
    """2.1: ReadObject reply Len 4, InitiateSegmentedRead 5..132, SegmentRead 3..131, SegmentWrite 3,
    ReadLSS 6, the others 2."""
    assert ReadObjectReply(0, bytes(4)).to_frame().length == 4
    assert InitiateSegmentedReadReply(0, 0, b"").to_frame().length == 5
    assert InitiateSegmentedReadReply(0, 300, bytes(255)).to_frame().length == 132
    assert SegmentReadReply(0, False, True, b"").to_frame().length == 3
    assert SegmentReadReply(0, False, True, bytes(255)).to_frame().length == 131
    assert SegmentWriteReply(0, 255, True).to_frame() == Frame(0, bytes([0, 0, 0, 0, 255, 1]))
    assert ReadLssReply(0, bytes(8)).to_frame().length == 6
    assert StatusReply(0x05030000).to_frame() == Frame(0, bytes([0, 0, 3, 5]))


@settings(max_examples=300, deadline=None)
@given(requests)
def test_requests_round_trip_through_the_wire(request: Request) -> None:
    """2.2: any request, encoded, stuffed, decoded, is the same request."""
    frames: list[Frame] = []
    from gatewaylab.common.clock import SimulatedClock

    decoder = FrameDecoder(SimulatedClock(), lambda e: frames.append(e.frame)
                           if isinstance(e, FrameReceived) else None)
    decoder.feed(encode_frame(request.to_frame()))
    assert [decode_request(f) for f in frames] == [request]


@settings(max_examples=100, deadline=None)
@given(st.binary(max_size=1500), st.integers(1, 255), st.integers(1, 255))
def test_segmented_write_then_read_any_size(payload: bytes, host_segment: int, device_segment: int) -> None:
    """2.1.1.2/2.1.1.3/2.1.2.2/2.1.2.3: any length, any segment sizes up to 255: what is written
    in segments is read back in segments, toggles alternating, the last bit on the final segment."""
    h = SlaveHarness()
    h.objects.add(0x2100, 1, b"", size=None)
    h.slave.segment_size = device_segment

    def ask(req: Request) -> object:
        (frame,) = h.feed(encode_frame(req.to_frame()))
        return decode_reply(req.opcode, frame)

    assert ask(InitiateSegmentedWrite(0, 0x2100, 1, len(payload))) == StatusReply(0)
    toggle, offset = False, 0
    while True:
        chunk = payload[offset:offset + host_segment]
        offset += len(chunk)
        last = offset >= len(payload)
        assert ask(SegmentWrite(toggle, last, chunk)) == SegmentWriteReply(0, len(chunk), toggle)
        toggle = not toggle
        if last:
            break
    first = ask(InitiateSegmentedRead(0, 0x2100, 1))
    assert isinstance(first, InitiateSegmentedReadReply) and first.total_length == len(payload)
    data, toggle = bytearray(first.data), False
    while len(data) < len(payload):
        seg = ask(SegmentRead(toggle))
        assert isinstance(seg, SegmentReadReply) and seg.error == 0 and seg.toggle == toggle
        data += seg.data
        assert seg.last == (len(data) == len(payload))
        toggle = not toggle
    assert bytes(data) == payload


def test_fields_that_do_not_fit_are_refused_before_the_wire() -> None:
    """2.1: Node-ID is a BYTE (a WORD in SendNMTService), Index a WORD, Subindex a BYTE, the total
    length a DWORD, the ReadLSS timeout a WORD; a value that does not fit is a LocalError naming the
    field, not a struct.error from deep inside the codec."""
    cases: list[tuple[Callable[[], object], str]] = [
        (lambda: ReadObject(0, 0x10000, 0), "index"), (lambda: ReadObject(256, 0x1000, 0), "node id"),
             (lambda: InitiateSegmentedRead(0, 0x1000, 256), "subindex"),
             (lambda: WriteObject(-1, 0x1000, 0, bytes(4)), "node id"),
             (lambda: InitiateSegmentedWrite(0, 0x1000, 0, 1 << 32), "total length"),
             (lambda: SendNmtService(0x10000, 1), "node id"), (lambda: SendNmtService(0, -1), "command"),
             (lambda: ReadLss(70000), "timeout")]
    for make, field in cases:
        with pytest.raises(LocalError, match=field):
            make()
