"""Every LastPDOError of the ECAN-Lite manual 13.2 the frame-stream codec can produce, one test
each, with the parse diagnostic of 16.2 (offset, packet_end, ctrl, seq, payload_len, crc,
layout_id, ch, dlc, tsf, kind)."""

from __future__ import annotations

import struct
from collections.abc import Callable

import pytest
from ecanlite_stream_kit import (
    MISTYPED,
    PACKETS_COMPILED,
    ctrl_word,
    ext_packet,
    image_by_hand,
    std_packet,
    tx_result_bytes,
)

from gatewaylab.common.errors import LocalError, ProtocolError
from gatewaylab.devices.ecanlite.stream import (
    DEFAULT_FEATURES,
    CanPacket,
    Commit,
    Direction,
    Feature,
    Option,
    PdoError,
    StreamEncodeError,
    StreamError,
    StreamHeader,
    StreamLayout,
    Tsf,
    TxResultCode,
    TxResultPacket,
    commit_state,
    decode_stream,
    encode_into,
    encode_stream,
    packet_size,
)

RX = StreamLayout.default(Direction.RX)
TX = StreamLayout(profile=1, options=Option.TX_RESULT_ENABLE, direction=Direction.TX)
GOOD = std_packet(0, 0x123, bytes.fromhex("1122334455667788"))


def rejected(image: bytes, layout: StreamLayout, code: PdoError) -> StreamError:
    with pytest.raises(StreamError) as info:
        decode_stream(image, layout)
    assert info.value.pdo_error is code, info.value
    assert info.value.code == int(code)
    assert isinstance(info.value, ProtocolError)
    return info.value


def test_active_area_wrong_length() -> None:
    """13.2 code 12 'active area': an image whose length is not 128*N of the active layout (the
    master mapped another N than 0x8011:03, 5.4.2)."""
    image = image_by_hand(RX, 1, GOOD, 1)
    rejected(image[:-128], RX, PdoError.ACTIVE_AREA)
    rejected(image + bytes(128), RX, PdoError.ACTIVE_AREA)
    rejected(image[:10], RX, PdoError.ACTIVE_AREA)
    with pytest.raises(StreamError) as info:
        StreamHeader.unpack(image[:23])
    assert info.value.pdo_error is PdoError.ACTIVE_AREA


def test_active_area_layout_id_mismatch() -> None:
    """5.4.4.1 step 3: layout_id keeps the header consistent with the active profile; another
    layout_id (or channel_mask) is 12 'active PDO/frame area inconsistent with the master mapping'."""
    err = rejected(image_by_hand(RX, 4, GOOD, 1, layout_id=RX.layout_id ^ 1), RX, PdoError.ACTIVE_AREA)
    assert err.diag.layout_id == RX.layout_id ^ 1 and err.diag.seq == 4
    rejected(image_by_hand(RX, 4, GOOD, 1, channel_mask=0x01), RX, PdoError.ACTIVE_AREA)


@pytest.mark.parametrize("ver_ihl", [0x00, 0x15, 0x26, 0x17, 0xFF])
def test_bad_header_version(ver_ihl: int) -> None:
    """Chapter 6 / 13.2 code 14: ver_ihl must be version 1, ihl 6 (0x16)."""
    rejected(image_by_hand(RX, 1, GOOD, 1, ver_ihl=ver_ihl), RX, PdoError.BAD_HEADER)


def test_bad_header_torn() -> None:
    """6.1 step 2: seq_begin != seq_end is a half-written image: commit_state says TORN (ignore
    quietly); decode_stream refuses it as 14 bad header."""
    image = image_by_hand(RX, 5, GOOD, 1, seq_end=4)
    assert commit_state(image, None) is Commit.TORN
    err = rejected(image, RX, PdoError.BAD_HEADER)
    assert "torn" in err.diag.reason


@pytest.mark.parametrize("crc_alg", [0, 2, 0xFF])
def test_bad_header_crc_alg(crc_alg: int) -> None:
    """6.1 step 3: crc_alg must be 1; 'the payload must not be parsed when it is not equal to 1'."""
    rejected(image_by_hand(RX, 1, GOOD, 1, crc_alg=crc_alg), RX, PdoError.BAD_HEADER)


def test_bad_header_no_crc16_fields() -> None:
    """9.1 NO_CRC16_ENABLE: the header uses crc_alg=0 and payload_crc16=0; anything else is 14."""
    layout = StreamLayout(options=Option.NO_CRC16_ENABLE)
    assert decode_stream(image_by_hand(layout, 1, GOOD, 1, crc_alg=0, crc=0), layout).packets
    rejected(image_by_hand(layout, 1, GOOD, 1, crc_alg=1), layout, PdoError.BAD_HEADER)
    rejected(image_by_hand(layout, 1, GOOD, 1, crc_alg=0, crc=0x1234), layout, PdoError.BAD_HEADER)


@pytest.mark.parametrize("count", [0, 2, 255])
def test_bad_header_frame_count(count: int) -> None:
    """Chapter 6: frame_count is the number of packets in the payload; another count is 14."""
    err = rejected(image_by_hand(RX, 1, GOOD, count), RX, PdoError.BAD_HEADER)
    assert "frame_count" in err.diag.reason


def test_packet_overrun_payload_len() -> None:
    """6.1 step 4 / 13.2 code 3: payload_len > ActiveFrameAreaBytes (1000 at N=8)."""
    layout = StreamLayout(multiplier=1)
    err = rejected(image_by_hand(layout, 1, GOOD, 1, payload_len=105), layout, PdoError.PACKET_OVERRUN)
    assert err.diag.payload_len == 105
    assert decode_stream(image_by_hand(layout, 1, GOOD, 1), layout)


def test_bad_crc() -> None:
    """6.1 step 5 / 13.2 code 15: a payload byte that does not match payload_crc16."""
    image = bytearray(image_by_hand(RX, 3, GOOD, 1))
    image[30] ^= 0x01
    err = rejected(bytes(image), RX, PdoError.BAD_CRC)
    assert (err.diag.seq, err.diag.payload_len, err.diag.crc) == (3, 12, struct.unpack_from("<H", image, 8)[0])


@pytest.mark.parametrize("kind", [2, 3])
def test_unknown_kind(kind: int) -> None:
    """Chapter 8 / 13.2 code 4: KIND 2 STREAM_META (no STREAM_CRC32 capability, 13.8) and KIND 3
    ('must currently be considered illegal')."""
    payload = struct.pack("<HH", ctrl_word(0, 0, kind=kind), 0)
    err = rejected(image_by_hand(RX, 1, GOOD + payload, 2), RX, PdoError.UNKNOWN_KIND)
    assert (err.diag.offset, err.diag.kind, err.diag.ctrl) == (36, kind, ctrl_word(0, 0, kind=kind))


def test_unknown_kind_tx_result_where_not_enabled() -> None:
    """Chapter 10 / 9.1: TX_RESULT is a TxPDO packet that needs 0x8010:07 bit0; in the RxPDO or
    with the option off it is 4 unknown kind."""
    payload = tx_result_bytes(0, 1, 0, 0)
    rejected(image_by_hand(RX, 1, payload, 1), RX, PdoError.UNKNOWN_KIND)
    plain_tx = StreamLayout(direction=Direction.TX)
    rejected(image_by_hand(plain_tx, 1, payload, 1), plain_tx, PdoError.UNKNOWN_KIND)
    rx_with_bit0 = StreamLayout(options=Option.TX_RESULT_ENABLE)   # 'bit0 is not used for RxPDO'
    rejected(image_by_hand(rx_with_bit0, 1, payload, 1), rx_with_bit0, PdoError.UNKNOWN_KIND)


def test_unknown_kind_result_code() -> None:
    """Chapter 10: ResultCode 0..5 only; 6 is a TX_RESULT this version does not know (4)."""
    rejected(image_by_hand(TX, 1, tx_result_bytes(0, 1, 0, 6), 1), TX, PdoError.UNKNOWN_KIND)


@pytest.mark.parametrize("ch", [4, 5, 6, 7])
def test_invalid_channel_beyond_capability(ch: int) -> None:
    """13.2 code 6: the channel number exceeds the capability range (4 channels, 0xF000:14)."""
    err = rejected(image_by_hand(RX, 1, std_packet(ch, 1, b""), 1), RX, PdoError.INVALID_CHANNEL)
    assert err.diag.ch == ch and err.diag.offset == 24


def test_invalid_channel_not_in_mask() -> None:
    """13.2 code 6: a channel 'not enabled in the channel mask' (0x8011:04 = 0x05)."""
    layout = StreamLayout(channel_mask=0x05)
    assert decode_stream(image_by_hand(layout, 1, std_packet(2, 1, b""), 1), layout)
    rejected(image_by_hand(layout, 1, std_packet(1, 1, b""), 1), layout, PdoError.INVALID_CHANNEL)
    tx = StreamLayout(channel_mask=0x01, options=Option.TX_RESULT_ENABLE, direction=Direction.TX)
    rejected(image_by_hand(tx, 1, tx_result_bytes(3, 1, 0, 0), 1), tx, PdoError.INVALID_CHANNEL)


@pytest.mark.parametrize("payload", [
    std_packet(0, 1, bytes(8), dlc=9),                  # classic DLC > 8
    std_packet(0, 1, bytes(8), dlc=15),
    std_packet(0, 1, bytes(8), brs=1),                  # BRS without FDF
    std_packet(0, 1, bytes(64), dlc=8, d64=1),          # D64 without FDF
], ids=["dlc9", "dlc15", "brs", "d64"])
def test_invalid_dlc(payload: bytes) -> None:
    """8.2 / 13.2 code 5: classic CAN has DLC <= 8, BRS = 0, D64 = 0."""
    layout = StreamLayout(profile=4)
    err = rejected(image_by_hand(layout, 1, payload, 1), layout, PdoError.INVALID_DLC)
    assert err.diag.dlc == payload[0] >> 3 & 15


def test_frame_overrun_d64_outside_profile() -> None:
    """Chapter 9 / 13.2 code 2: the D64 window exceeds what profiles 0/1 can encapsulate."""
    payload = std_packet(0, 1, bytes(64), dlc=8, fdf=1, d64=1)
    rejected(image_by_hand(RX, 1, payload, 1), RX, PdoError.FRAME_OVERRUN)
    p4 = StreamLayout(profile=4)
    (p,) = decode_stream(image_by_hand(p4, 1, payload, 1), p4).packets
    assert isinstance(p, CanPacket) and p.d64 and p.data == bytes(8)


def test_invalid_tsf_profile() -> None:
    """Chapter 9 / 8.4 / 13.2 code 7: a TxPDO delta16 timestamp in profile 0 (no timestamp)."""
    tx0 = StreamLayout(direction=Direction.TX)
    payload = std_packet(0, 1, b"", tsf=1, ts=b"\x01\x00")
    err = rejected(image_by_hand(tx0, 1, payload, 1), tx0, PdoError.INVALID_TSF)
    assert err.diag.tsf == 1
    assert decode_stream(image_by_hand(TX, 1, payload, 1), TX)


def test_invalid_tsf_delta32_not_a_capability() -> None:
    """8.4 / 13.8: delta32's capability bit is not set by default: 7 even in profile 1."""
    payload = std_packet(0, 1, b"", tsf=2, ts=bytes(4))
    rejected(image_by_hand(TX, 1, payload, 1), TX, PdoError.INVALID_TSF)
    wide = StreamLayout(profile=1, direction=Direction.TX, features=DEFAULT_FEATURES | Feature.TSF_DELTA32)
    assert decode_stream(image_by_hand(wide, 1, payload, 1), wide)


def test_invalid_tsf_direction() -> None:
    """8.4 / 13.2 code 7 'not supported by the current profile or direction': in the RxPDO only
    TSF_NONE (send now) and TSF_FULL64 (reservation) exist, so delta16 is 7 even in profile 1."""
    rx1 = StreamLayout(profile=1)
    rejected(image_by_hand(rx1, 1, std_packet(0, 1, b"", tsf=1, ts=bytes(2)), 1), rx1, PdoError.INVALID_TSF)


def test_truncated_packet() -> None:
    """13.2 code 8: payload_len ends inside a packet (here 2 bytes short, and the control word cut)."""
    payload = GOOD + std_packet(1, 2, b"\x01\x02\x03\x04")
    err = rejected(image_by_hand(RX, 1, payload, 2, payload_len=len(payload) - 2), RX, PdoError.TRUNCATED)
    assert (err.diag.offset, err.diag.packet_end, err.diag.payload_len) == (36, 36 + 8, len(payload) - 2)
    image = bytearray(image_by_hand(RX, 1, GOOD + b"\x00", 2))
    err = rejected(bytes(image), RX, PdoError.TRUNCATED)
    assert err.diag.offset == 36


def test_reserved_bit_std_id_field() -> None:
    """8.1 StdIdField bits 14/15 'reserved, must be 0' -> 13 reserved bit."""
    for bit in (14, 15):
        payload = std_packet(0, 0, b"", id_field=0x123 | 1 << bit)
        err = rejected(image_by_hand(RX, 1, payload, 1), RX, PdoError.RESERVED_BIT)
        assert err.diag.ctrl == 0


def test_reserved_bit_tx_result_ctrl() -> None:
    """Chapter 10: a TX_RESULT control word carries CH and KIND=1; other bits set -> 13."""
    payload = struct.pack("<HHBB", ctrl_word(0, 3, kind=1), 1, 0, 0)
    rejected(image_by_hand(TX, 1, payload, 1), TX, PdoError.RESERVED_BIT)


def test_reserved_bit_align4_padding() -> None:
    """8.3 / 9.1: ALIGN4 'padding must be 0'; a non-zero padding byte is 13."""
    layout = StreamLayout(options=Option.ALIGN_4_ENABLE)
    good = ext_packet(0, 0x1234, bytes(8), pad=2)
    assert decode_stream(image_by_hand(layout, 1, good, 1), layout)
    rejected(image_by_hand(layout, 1, good[:-1] + b"\x01", 1), layout, PdoError.RESERVED_BIT)
    tx = StreamLayout(options=Option.TX_RESULT_ENABLE | Option.ALIGN_4_ENABLE, direction=Direction.TX)
    rejected(image_by_hand(tx, 1, tx_result_bytes(0, 1, 0, 0) + b"\x00\x07", 1), tx, PdoError.RESERVED_BIT)


@pytest.mark.parametrize(("fmt", "flags"), [(0, 0), (2, 0), (1, 1), (0xFF, 0x80)])
def test_bad_schedule_format(fmt: int, flags: int) -> None:
    """8.4 / 13.8 / 13.2 code 16: RxPDO TSF_FULL64 must be format u8 = 1, flags u8 = 0."""
    ts = struct.pack("<BBHI", fmt, flags, 7, 100_000)
    err = rejected(image_by_hand(RX, 1, std_packet(0, 1, b"", tsf=3, ts=ts), 1), RX, PdoError.BAD_SCHEDULE)
    assert err.diag.tsf == 3


def test_bad_schedule_capability() -> None:
    """13.2 code 16 '... or the capability is not supported': 0xF000:16 bit8 cleared."""
    layout = StreamLayout(features=DEFAULT_FEATURES & ~Feature.RX_TSF_SCHEDULE_TX)
    ts = struct.pack("<BBHI", 1, 0, 7, 100_000)
    rejected(image_by_hand(layout, 1, std_packet(0, 1, b"", tsf=3, ts=ts), 1), layout, PdoError.BAD_SCHEDULE)
    with pytest.raises(StreamEncodeError) as info:
        encode_stream(layout, 1, [CanPacket.of(0, 1, tsf=Tsf.FULL64, scheduled=True)])
    assert info.value.pdo_error is PdoError.BAD_SCHEDULE


def test_duplicate_sequence() -> None:
    """13.2 code 10 / 13.8: the exact same image again is an idempotent no-op (SAME); the same
    sequence with other contents is a duplicate sequence (DUPLICATE); the next sequence is NEW."""
    first = image_by_hand(RX, 9, GOOD, 1)
    assert commit_state(first, None) is Commit.NEW
    assert commit_state(first, first) is Commit.SAME
    other = image_by_hand(RX, 9, std_packet(1, 0x55, b""), 1)
    assert commit_state(other, first) is Commit.DUPLICATE
    assert commit_state(image_by_hand(RX, 10, GOOD, 1), first) is Commit.NEW
    # bytes after payload_len do not make an image new (PAYLOAD_ONLY receivers ignore them, 9.1)
    assert commit_state(image_by_hand(RX, 9, GOOD, 1, tail=b"junk"), first) is Commit.SAME


def test_unsupported_profile_and_option_are_layout_errors() -> None:
    """13.2 codes 9 / 11 and apply status 4 / 10: a profile outside 0xF000:12 or an option outside
    0xF000:15 never becomes a layout; the apply check (check_layout) reports them instead."""
    with pytest.raises(LocalError):
        StreamLayout(profile=2)
    with pytest.raises(LocalError):
        StreamLayout(options=0x20)


@pytest.mark.parametrize(("make", "code", "mistyped"), [p if len(p) == 3 else (*p, False) for p in [
    (lambda: CanPacket.of(8, 1), PdoError.INVALID_CHANNEL),
    (lambda: CanPacket.of(-1, 1), PdoError.INVALID_CHANNEL),
    (lambda: CanPacket.of(0, 1, data=bytes(9)), PdoError.INVALID_DLC),
    (lambda: CanPacket.of(0, 1, fd=True, data=bytes(9)), PdoError.INVALID_DLC),
    (lambda: CanPacket.of(0, 1, rtr=True, dlc=9), PdoError.INVALID_DLC),
    (lambda: CanPacket.of(0, 1, rtr=True, data=b"x"), PdoError.INVALID_DLC),
    (lambda: CanPacket.of(0, 1, fd=True, rtr=True), PdoError.INVALID_DLC),
    (lambda: CanPacket.of(0, 1, brs=True), PdoError.INVALID_DLC),
    (lambda: CanPacket.of(0, 1, d64=True), PdoError.INVALID_DLC),
    (lambda: CanPacket.of(0, 1, data=b"ab", dlc=3), PdoError.INVALID_DLC),
    (lambda: CanPacket.of(0, 1, tsf=4), PdoError.INVALID_TSF, True),                         # type: ignore[arg-type]
    (lambda: CanPacket.of(0, 1, tsf=Tsf.DELTA16, timestamp=0x10000), PdoError.INVALID_TSF),
    (lambda: CanPacket.of(0, 1, timestamp=5), PdoError.INVALID_TSF),
    (lambda: CanPacket.of(0, 1, scheduled=True), PdoError.BAD_SCHEDULE),
    (lambda: CanPacket.of(0, 1, tsf=Tsf.FULL64, scheduled=True, offset_ns=1 << 32), PdoError.BAD_SCHEDULE),
    (lambda: CanPacket.of(0, 1, tsf=Tsf.FULL64, offset_ns=5), PdoError.BAD_SCHEDULE),
    (lambda: CanPacket.of(0, 0x800), PdoError.RESERVED_BIT),
    (lambda: CanPacket.of(0, 0x20000000, True), PdoError.RESERVED_BIT),
    (lambda: CanPacket.of(0, 1, id_aux=8), PdoError.RESERVED_BIT),
    (lambda: TxResultPacket(0, 1, 256, TxResultCode.OK), PdoError.UNKNOWN_KIND),
    (lambda: TxResultPacket(0, 1, 0, 6), PdoError.UNKNOWN_KIND, True),                   # type: ignore[arg-type]
    (lambda: TxResultPacket(9, 1, 0, TxResultCode.OK), PdoError.INVALID_CHANNEL),
]])
def test_packets_no_layout_can_carry(make: Callable[[], object], code: PdoError, mistyped: bool) -> None:
    """Chapters 8-10: a packet that fits no control word or field (CH 0..7, the 8.2 DLC rules, TSF
    sizes, the 8.4 reservation format, id widths, ResultCode 0..5) is refused when built, with the
    LastPDOError a receiver would report for it."""
    with pytest.raises(MISTYPED if mistyped else StreamEncodeError) as info:
        make()
    if isinstance(info.value, StreamEncodeError):
        assert info.value.pdo_error is code
        assert isinstance(info.value, LocalError)


@pytest.mark.parametrize(("layout", "packet", "code"), [
    (RX, CanPacket.of(4, 1), PdoError.INVALID_CHANNEL),
    (StreamLayout(channel_mask=1), CanPacket.of(1, 1), PdoError.INVALID_CHANNEL),
    (RX, CanPacket.of(0, 1, fd=True, d64=True), PdoError.FRAME_OVERRUN),
    (TX, CanPacket.of(0, 1, tsf=Tsf.DELTA32), PdoError.INVALID_TSF),
    (StreamLayout(direction=Direction.TX), CanPacket.of(0, 1, tsf=Tsf.DELTA16), PdoError.INVALID_TSF),
    (RX, CanPacket.of(0, 1, tsf=Tsf.DELTA16), PdoError.INVALID_TSF),
    (RX, CanPacket.of(0, 1, tsf=Tsf.FULL64), PdoError.BAD_SCHEDULE),
    (TX, CanPacket.of(0, 1, tsf=Tsf.FULL64, scheduled=True), PdoError.BAD_SCHEDULE),
    (RX, TxResultPacket(0, 1, 0, TxResultCode.OK), PdoError.UNKNOWN_KIND),
    (StreamLayout(direction=Direction.TX), TxResultPacket(0, 1, 0, TxResultCode.OK), PdoError.UNKNOWN_KIND),
    (TX, TxResultPacket(5, 1, 0, TxResultCode.OK), PdoError.INVALID_CHANNEL),
])
def test_encoder_refuses_with_the_receivers_code(layout: StreamLayout, packet: CanPacket | TxResultPacket,
                                                 code: PdoError) -> None:
    """Chapters 8-10, 9, 13.2: a packet this layout cannot carry (mask, profile, direction,
    options) is refused before anything is written, with the code the receiver would report;
    packet_size and encode_stream agree."""
    with pytest.raises(StreamEncodeError) as info:
        packet_size(packet, layout)
    assert info.value.pdo_error is code
    buf = bytearray(b"\x55" * layout.pdo_bytes)
    with pytest.raises(StreamEncodeError) as info:
        encode_into(buf, layout, 1, [CanPacket.of(0, 2), packet])
    assert info.value.pdo_error is code
    assert buf == b"\x55" * layout.pdo_bytes


def test_encoder_packet_overrun_and_frame_count() -> None:
    """Chapter 12: packets must fit the frame area whole (3 packet overrun); frame_count is one
    byte, so at most 255 packets per image."""
    layout = StreamLayout(multiplier=1)
    with pytest.raises(StreamEncodeError) as info:
        encode_stream(layout, 1, [CanPacket.of(0, 1, fd=True, data=bytes(64))] * 2)
    assert info.value.pdo_error is PdoError.PACKET_OVERRUN
    big = StreamLayout(multiplier=24)
    assert len(decode_stream(encode_stream(big, 1, [CanPacket.of(0, 1)] * 255), big).packets) == 255
    with pytest.raises(StreamEncodeError):
        encode_stream(big, 1, [CanPacket.of(0, 1)] * 256)


def test_diag_fields_of_a_packet_error() -> None:
    """16.2: parse_diag carries offset, packet_end, ctrl, seq, payload_len, crc, layout_id, ch,
    dlc, tsf, kind of the failing packet."""
    bad = std_packet(2, 0x10, bytes(8), dlc=8, id_field=0x8010)
    image = image_by_hand(RX, 0x4242, GOOD + bad, 2)
    err = rejected(image, RX, PdoError.RESERVED_BIT)
    d = err.diag
    assert (d.offset, d.packet_end, d.ctrl, d.seq, d.payload_len, d.layout_id) == (
        36, 48, ctrl_word(2, 8), 0x4242, 24, RX.layout_id)
    assert d.crc == struct.unpack_from("<H", image, 8)[0]
    assert (d.ch, d.dlc, d.tsf, d.kind) == (2, 8, 0, 0)
    assert "RESERVED_BIT (13)" in str(err)


@pytest.mark.parametrize("make", [
    lambda: CanPacket.of(0, 1.0),                            # type: ignore[arg-type]
    lambda: CanPacket.of(0, 1, data="text"),                 # type: ignore[arg-type]
    lambda: CanPacket.of(0, 1, tsf=Tsf.DELTA16, timestamp=2.5),  # type: ignore[arg-type]
    pytest.param(lambda: CanPacket.of(True, 1), marks=pytest.mark.skipif(
        PACKETS_COMPILED, reason="compiled, a bool given for an int argument arrives as that int (channel 1)")),
    lambda: TxResultPacket(0, 1.0, 0, TxResultCode.OK),   # type: ignore[arg-type]
])
def test_non_integer_fields_refused(make: Callable[[], object]) -> None:
    """8.1 / 10: every packet field is an integer (or bytes) of a fixed width; anything else is
    refused when built, not half-written into an image. Pure Python refuses it with the
    LastPDOError a receiver would report; compiled, an argument of a type mypy rejects is a
    TypeError at the call (docs/performance.md, "Rules that keep a module compilable")."""
    with pytest.raises(MISTYPED):
        make()


def test_a_kept_error_does_not_pin_the_image() -> None:
    """13.2: a device keeps the last StreamError for its diagnostics while it reuses its buffer;
    the error (and its traceback) holds no view of that buffer."""
    image = bytearray(image_by_hand(RX, 1, GOOD, 1))
    image[30] ^= 1
    try:
        decode_stream(image, RX)
    except StreamError as exc:
        kept = exc
    image.extend(b"\0")      # would raise BufferError while a memoryview of it were alive
    assert kept.pdo_error is PdoError.BAD_CRC
