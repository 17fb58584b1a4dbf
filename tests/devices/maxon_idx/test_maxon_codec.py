"""Frame codec tests against the IDX Communication Guide 2.2 and the verified notes."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.maxon_idx.codec import (
    CrcFailed,
    DecoderEvent,
    DiscardReason,
    Frame,
    FrameDecoder,
    FrameDiscarded,
    FrameReceived,
    crc_ccitt,
    encode_frame,
    frame_body,
    stuff,
)

GUIDE_REQUEST = bytes([0x90, 0x02, 0x60, 0x02, 0x01, 0xB0, 0x30, 0x00, 0x2E, 0x62])
GUIDE_RESPONSE = bytes([0x90, 0x02, 0x00, 0x04, 0x00, 0x00, 0x00, 0x00, 0x01, 0x90, 0x90, 0x00, 0x00,
                        0x9A, 0x5C])
BAD_CRC_ANSWER = bytes([0x90, 0x02, 0x00, 0x02, 0x04, 0x00, 0x04, 0x05, 0xF1, 0xE8])


def guide_calc_field_crc(words: list[int]) -> int:
    """Figure 2-6 CalcFieldCRC transcribed bit for bit, as an independent oracle for crc_ccitt."""
    crc = 0
    for c in words:
        shifter = 0x8000
        while shifter:
            carry = crc & 0x8000
            crc = (crc << 1) & 0xFFFF
            if c & shifter:
                crc += 1
            if carry:
                crc ^= 0x1021
            shifter >>= 1
    return crc


class Collector:
    def __init__(self, timeout: float | None = 0.5) -> None:
        self.clock = SimulatedClock()
        self.events: list[DecoderEvent] = []
        self.decoder = FrameDecoder(self.clock, self.events.append, timeout)

    @property
    def frames(self) -> list[Frame]:
        return [e.frame for e in self.events if isinstance(e, FrameReceived)]


def test_guide_request_encodes_byte_for_byte() -> None:
    """2.2.8 steps 1-8: ReadObject node 1 0x30B0:00 -> 90 02 60 02 01 B0 30 00 2E 62 (CRC 0x622E)."""
    frame = Frame(0x60, bytes([0x01, 0xB0, 0x30, 0x00]))
    assert crc_ccitt(bytes([0x60, 0x02, 0x01, 0xB0, 0x30, 0x00])) == 0x622E
    assert encode_frame(frame) == GUIDE_REQUEST


def test_guide_response_round_trips_with_stuffed_dle() -> None:
    """2.2.8 steps 9-12: the response carries 0x90 stuffed as 90 90; unstuffed CRC over all words is 0."""
    frame = Frame(0x00, bytes([0, 0, 0, 0, 0x01, 0x90, 0x00, 0x00]))
    assert encode_frame(frame) == GUIDE_RESPONSE
    c = Collector()
    c.decoder.feed(GUIDE_RESPONSE)
    assert c.frames == [frame]
    assert frame_body(frame) == bytes.fromhex("000400000000019000009A5C")
    assert int.from_bytes(frame.data[4:8], "little") == 0x9001


def test_crc_matches_guide_algorithm_with_zero_word() -> None:
    """2.2.3.2: DataArray[0] = Len<<8 | OpCode, ..., last word 0; crc_hqx over big-endian words agrees."""
    words = [0x0260, 0xB001, 0x0030, 0x0000]
    assert guide_calc_field_crc(words) == 0x622E
    words = [0x0400, 0x0000, 0x0000, 0x9001, 0x0000, 0x5C9A]
    assert guide_calc_field_crc(words) == 0


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 255), st.binary(max_size=286).filter(lambda b: len(b) % 2 == 0))
def test_crc_equals_guide_oracle(opcode: int, data: bytes) -> None:
    """2.2.3: the binascii.crc_hqx shortcut equals CalcFieldCRC for any frame."""
    body = bytes([opcode, len(data) // 2]) + data
    words = [body[i] | body[i + 1] << 8 for i in range(0, len(body), 2)] + [0]
    assert crc_ccitt(body) == guide_calc_field_crc(words)


def test_bad_crc_answer_vector() -> None:
    """2.2.2 Note ("as a reaction to a bad ... CRC value, the slave sends a frame containing the
    corresponding error code") + notes: OpCode 0x00, Len 2, DWORD 0x05040004 = 90 02 00 02 04 00 04 05 F1 E8."""
    assert encode_frame(Frame(0, (0x05040004).to_bytes(4, "little"))) == BAD_CRC_ANSWER


def test_stuffing_examples() -> None:
    """2.2.4 examples: 90 -> 90 90; 90 02 -> 90 90 02; 90 90 -> 90 90 90 90."""
    assert stuff(bytes([0x21, 0x90, 0x45])) == bytes([0x21, 0x90, 0x90, 0x45])
    assert stuff(bytes([0x21, 0x90, 0x02, 0x45])) == bytes([0x21, 0x90, 0x90, 0x02, 0x45])
    assert stuff(bytes([0x21, 0x90, 0x90, 0x45])) == bytes([0x21, 0x90, 0x90, 0x90, 0x90, 0x45])


def test_byte_by_byte_feeding() -> None:
    """2.2.2: frames are a byte stream; one byte at a time gives the same frames."""
    c = Collector()
    for b in GUIDE_REQUEST + GUIDE_RESPONSE:
        c.decoder.feed(bytes([b]))
    assert [f.opcode for f in c.frames] == [0x60, 0x00]


def test_garbage_before_inside_and_after() -> None:
    """2.2.2/2.2.4: the decoder resynchronises on DLE STX; a DLE STX inside a frame restarts it."""
    c = Collector()
    c.decoder.feed(b"\x00\x90\x55garbage\x90" + GUIDE_REQUEST + b"\x13\x37\x90")
    assert [f.opcode for f in c.frames] == [0x60]
    c.events.clear()
    c.decoder.feed(GUIDE_REQUEST[:6] + GUIDE_RESPONSE)       # frame cut by a new DLE STX
    assert [type(e) for e in c.events] == [FrameDiscarded, FrameReceived]
    assert isinstance(c.events[0], FrameDiscarded) and c.events[0].reason is DiscardReason.RESYNC
    c.events.clear()
    c.decoder.feed(GUIDE_REQUEST[:5] + b"\x90\x33" + GUIDE_REQUEST)    # DLE + junk inside a frame
    assert [type(e) for e in c.events] == [FrameDiscarded, FrameReceived]


def test_stuffed_crc_bytes() -> None:
    """2.2.4 Important: stuffing also applies to the CRC; find a frame whose CRC contains 0x90."""
    for n in range(10000):
        frame = Frame(0x68, n.to_bytes(8, "little"))
        body = frame_body(frame)
        if 0x90 in body[-2:] and 0x90 not in body[:-2]:
            break
    wire = encode_frame(frame)
    assert wire.count(0x90) == 1 + 2 * body[-2:].count(0x90)
    c = Collector()
    c.decoder.feed(wire)
    assert c.frames == [frame]


def test_crc_error_reported() -> None:
    """2.2.8 Important: a frame with a wrong CRC is neither accepted nor processed."""
    c = Collector()
    c.decoder.feed(GUIDE_REQUEST[:-1] + b"\x63")
    assert c.events == [CrcFailed(0x60, bytes([0x01, 0xB0, 0x30, 0x00]))]


def test_len_above_143_rejected() -> None:
    """2.2.2: Len is 0...143 words; a larger Len drops the frame and the decoder hunts again."""
    c = Collector()
    c.decoder.feed(bytes([0x90, 0x02, 0x60, 0x90, 0x90]) + bytes(10) + GUIDE_REQUEST)   # Len 144, stuffed
    assert isinstance(c.events[0], FrameDiscarded)
    assert c.events[0].reason is DiscardReason.LEN_TOO_LONG
    assert [f.opcode for f in c.frames] == [0x60]
    big = Frame(0x6A, bytes(286))
    c.events.clear()
    c.decoder.feed(encode_frame(big))
    assert c.frames == [big]


def test_timeout_mid_frame_discards_partial() -> None:
    """2.2.6: 0x2006 USB frame timeout (500 ms) -- a frame not complete in time is dropped."""
    c = Collector(timeout=0.5)
    c.decoder.feed(GUIDE_REQUEST[:6])
    c.clock.advance(0.499)
    assert c.events == []
    c.clock.advance(0.002)
    assert len(c.events) == 1 and isinstance(c.events[0], FrameDiscarded)
    assert c.events[0].reason is DiscardReason.TIMEOUT
    c.decoder.feed(GUIDE_REQUEST[6:])      # the rest alone is garbage now
    assert c.frames == []
    c.decoder.feed(GUIDE_REQUEST)
    assert len(c.frames) == 1


def test_timeout_follows_object_value() -> None:
    """2.2.6 Note: the timeout may be changed by writing the object; it applies from the next frame."""
    value = [0.5]
    c = Collector()
    c.decoder = FrameDecoder(c.clock, c.events.append, lambda: value[0])
    value[0] = 2.0
    c.decoder.feed(GUIDE_REQUEST[:3])
    c.clock.advance(1.5)
    c.decoder.feed(GUIDE_REQUEST[3:])
    assert len(c.frames) == 1


@settings(max_examples=300, deadline=None)
@given(st.lists(st.one_of(st.binary(max_size=40),
                          st.sampled_from([GUIDE_REQUEST, GUIDE_RESPONSE, b"\x90", b"\x90\x02"])),
                max_size=20))
def test_random_streams_yield_only_valid_frames_or_spec_errors(chunks: list[bytes]) -> None:
    """2.2.2-2.2.4: whatever arrives, the decoder only reports CRC-valid frames with Len <= 143,
    CRC failures (answered 0x05040004) or discarded partials -- and never raises."""
    c = Collector()
    for chunk in chunks:
        c.decoder.feed(chunk)
    stream = b"".join(chunks)
    for e in c.events:
        if isinstance(e, FrameReceived):
            # The frame was really on the wire and its received CRC checked: the stuffed bytes from
            # DLE STX to the CRC the guide's algorithm gives (encode_frame) occur in the stream.
            assert encode_frame(e.frame) in stream
            assert e.frame.length <= 143
        elif isinstance(e, CrcFailed):
            # A complete frame (DLE STX, OpCode, Len <= 143, Len words) was on the wire.
            head = bytes([e.opcode, len(e.data) // 2]) + e.data
            assert b"\x90\x02" + stuff(head) in stream
            assert len(e.data) // 2 <= 143
        else:
            assert isinstance(e, FrameDiscarded)


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 255), st.binary(max_size=286).filter(lambda b: len(b) % 2 == 0), st.binary(max_size=30))
def test_any_frame_round_trips_after_garbage(opcode: int, data: bytes, garbage: bytes) -> None:
    """2.2.2/2.2.4: any frame, stuffed, is recovered after garbage that ends outside a frame."""
    frame = Frame(opcode, data)
    c = Collector()
    c.decoder.feed(garbage)
    c.decoder.reset()
    for b in encode_frame(frame):
        c.decoder.feed(bytes([b]))
    assert c.frames == [frame]
