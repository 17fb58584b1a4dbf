"""The cross-process record format of docs/bus-wire.md: golden bytes, streaming, malformed input."""

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gatewaylab.bus import CanFrame, wire
from gatewaylab.common.errors import ProtocolError


def test_frame_record_golden_bytes() -> None:
    """docs/bus-wire.md: u16 length, type 0x03, u32 id, u8 flags, u8 dlc, f64 time, data."""
    rec = wire.encode_frame(CanFrame(0x123, b"\xAA\xBB", extended=True), 0.0)
    assert rec == bytes.fromhex("1100" "03" "23010000" "01" "02" "0000000000000000" "AABB")


def test_hello_and_welcome_golden_bytes() -> None:
    """docs/bus-wire.md HELLO and WELCOME layouts, byte for byte."""
    assert wire.encode_hello("ab", receive_own=True, fd=True) == bytes.fromhex("0500" "01" "01" "03" "6162")
    assert wire.encode_welcome("can0", 1_000_000, 5_000_000) == bytes.fromhex(
        "0F00" "02" "01" "01" "40420F00" "404B4C00" "63616E30")


def test_records_survive_byte_by_byte_feeding() -> None:
    """docs/bus-wire.md: the record stream decodes the same however it is split (byte-by-byte feeding)."""
    frames = [CanFrame(0x100 + i, bytes([i] * (i % 9))) for i in range(20)]
    frames.append(CanFrame(0x1, bytes(64), fd=True, brs=True))
    stream = b"".join(wire.encode_frame(f, i * 0.5) for i, f in enumerate(frames))
    dec = wire.RecordDecoder()
    out: list[wire.Record] = []
    for b in stream:
        out.extend(dec.feed(bytes([b])))
    assert [r.frame for r in out if isinstance(r, wire.FrameRecord)] == frames
    assert dec.buffered == 0


@pytest.mark.parametrize("garbage, reason", [
    (b"\x00\x00\x03", "record length 0"),
    (b"\xff\xff\x03", "record length 65535"),
    (b"\x02\x00\x7f\x00", "unknown record type"),
    (bytes.fromhex("0F00" "03" "00080000" "00" "00" "0000000000000000"), "out of range"),
    (bytes.fromhex("0F00" "03" "23010000" "80" "00" "0000000000000000"), "unknown frame flags"),
    (bytes.fromhex("1800" "03" "23010000" "00" "09" "0000000000000000") + bytes(9), "DLC > 8"),
])
def test_malformed_records_raise_protocol_error(garbage: bytes, reason: str) -> None:
    """docs/bus-wire.md: malformed records (bad length, unknown type, impossible frame) raise ProtocolError, which
    drops the client."""
    with pytest.raises(ProtocolError, match=reason):
        wire.RecordDecoder().feed(garbage)


@given(st.binary(max_size=300))
def test_random_bytes_give_records_or_protocol_error(data: bytes) -> None:
    """Property: arbitrary client bytes never raise anything but ProtocolError."""
    try:
        records = wire.RecordDecoder().feed(data)
    except ProtocolError:
        return
    for r in records:
        assert isinstance(r, (wire.Hello, wire.Welcome, wire.FrameRecord, wire.Status, wire.Bye, wire.TxDone,
                              wire.TimeBase, wire.Filters))


def test_txdone_timebase_filter_golden_bytes() -> None:
    """docs/bus-wire.md TXDONE (u8 outcome, u16 count), TIMEBASE (f64 Unix time of bus time 0) and FILTER
    (u32 can_id, u32 mask, u8 match per entry), byte for byte."""
    assert wire.encode_txdone(wire.TxOutcome.REFUSED, 3) == bytes.fromhex("0400" "06" "02" "0300")
    assert wire.encode_timebase(1.5) == bytes.fromhex("0900" "07" "000000000000F83F")
    f = wire.AcceptanceFilter(0x123, 0x7FF, wire.FilterMatch.STANDARD)
    assert wire.encode_filters([f]) == bytes.fromhex("0A00" "08" "23010000" "FF070000" "01")
    assert wire.encode_filters([]) == bytes.fromhex("0100" "08")
    recs = wire.RecordDecoder().feed(wire.encode_txdone(wire.TxOutcome.TRANSMITTED) + wire.encode_timebase(2.0)
                                     + wire.encode_filters([f]))
    assert recs == [wire.TxDone(wire.TxOutcome.TRANSMITTED, 1), wire.TimeBase(2.0), wire.Filters((f,))]


def test_echo_flag_marks_own_frames() -> None:
    """docs/bus-wire.md FRAME flags bit 5: the client's own frame coming back (receive-own option)."""
    rec = wire.encode_frame(CanFrame(0x10, b"\x01"), 0.25, echo=True)
    assert rec[7] == 0x20
    (out,) = wire.RecordDecoder().feed(rec)
    assert isinstance(out, wire.FrameRecord) and out.echo and out.timestamp == 0.25


def test_acceptance_filter_rule() -> None:
    """python-can set_filters: a frame matches when id & mask == can_id & mask and, if given, its id type."""
    f = wire.AcceptanceFilter(0x100, 0x7F0, wire.FilterMatch.STANDARD)
    assert f.accepts(CanFrame(0x10A)) and not f.accepts(CanFrame(0x110))
    assert not f.accepts(CanFrame(0x10A, extended=True))
    assert wire.AcceptanceFilter(0x100, 0x7F0).accepts(CanFrame(0x10A, extended=True))


@pytest.mark.parametrize("garbage, reason", [
    (bytes.fromhex("0300" "06" "00" "01"), "TXDONE record has the wrong size"),
    (bytes.fromhex("0400" "06" "09" "0100"), "malformed record"),
    (bytes.fromhex("0500" "07" "00000000"), "TIMEBASE record has the wrong size"),
    (bytes.fromhex("0500" "08" "00000000"), "not a whole number of entries"),
    (bytes.fromhex("0A00" "08" "23010000" "FF070000" "07"), "malformed record"),
])
def test_malformed_new_records_raise_protocol_error(garbage: bytes, reason: str) -> None:
    """docs/bus-wire.md: malformed TXDONE, TIMEBASE and FILTER records raise ProtocolError."""
    with pytest.raises(ProtocolError, match=reason):
        wire.RecordDecoder().feed(garbage)


@given(st.integers(min_value=0, max_value=255), st.binary(max_size=wire.MAX_RECORD - 1))
def test_any_record_type_with_any_body_gives_a_record_or_protocol_error(rtype: int, body: bytes) -> None:
    """Property (docs/bus-wire.md): a well-framed record of any type with any body decodes to a record or
    raises ProtocolError, never anything else (the server drops such a client and carries on)."""
    try:
        records = wire.RecordDecoder().feed(wire.LENGTH.pack(len(body) + 1) + bytes((rtype,)) + body)
    except ProtocolError:
        return
    assert len(records) == 1
