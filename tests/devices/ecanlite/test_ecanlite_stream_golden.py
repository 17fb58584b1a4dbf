"""Golden vectors and tables of the ECAN-Lite manual, chapters 5.2, 5.4.4, 6-10 and 13.2/13.8."""

from __future__ import annotations

import struct

import pytest
from ecanlite_stream_kit import (
    crc16_bitwise,
    ctrl_word,
    ext_packet,
    image_by_hand,
    layout_id_by_hand,
    std_packet,
    tx_result_bytes,
)

from gatewaylab.devices.ecanlite.budget import BudgetPolicy
from gatewaylab.devices.ecanlite.stream import (
    DEFAULT_FEATURES,
    OPTION_MASK,
    PROFILE_MASK,
    CanPacket,
    Direction,
    Feature,
    HeaderFlags,
    Option,
    PacketKind,
    PdoError,
    ProfileStatus,
    StreamHeader,
    StreamLayout,
    Tsf,
    TxResultCode,
    TxResultPacket,
    check_layout,
    check_options,
    crc16,
    decode_stream,
    dlc_to_len,
    encode_stream,
    packet_size,
    timestamp_ticks,
)

#: 5.4.4.1 step 1: "The bytes starting at offset 24 are"
MANUAL_FRAME = bytes.fromhex("40 00 23 01 11 22 33 44 55 66 77 88")


def test_crc16_check_value() -> None:
    """5.4.4.1: CRC-16/CCITT-FALSE, poly 0x1021, init 0xFFFF, xorout 0, not reflected: its standard
    check value over b"123456789" is 0x29B1, by the codec and by a bitwise reference."""
    assert crc16(b"123456789") == 0x29B1
    assert crc16_bitwise(b"123456789") == 0x29B1
    for data in (b"", MANUAL_FRAME, bytes(range(256)) * 12):
        assert crc16(data) == crc16_bitwise(data)


def test_manual_rxpdo_frame_encodes_to_the_byte() -> None:
    """5.4.4.1: N=8, mask 0x0F, CAN0 std id 0x123 DLC 8 data 11..88 -> ctrl 0x0040, StdIdField
    0x0123, `40 00 23 01 11 22 33 44 55 66 77 88` at offset 24; header 0x16, flags 0, seq twice,
    payload_len 12, CRC over rxpdo[24..35], folded layout_id, mask 0x0F, frame_count 1,
    overflow_sat 0, crc_alg 1, status 0; the rest of the 1024 bytes 0."""
    layout = StreamLayout.default()
    seq = 1
    image = encode_stream(layout, seq, [CanPacket.of(0, 0x123, data=bytes.fromhex("1122334455667788"))])
    crc = crc16_bitwise(MANUAL_FRAME)
    assert crc == 0x56D3   # the reference's value for the manual's 12 bytes, kept as a golden number
    layout_id = layout_id_by_hand(8, 0x0F, 0, 0, 0)
    assert layout_id == 0x01E7
    expected = (bytes([0x16, 0x00]) + struct.pack("<HHHHH", seq, seq, 12, crc, layout_id)
                + bytes([0x0F, 1, 0, 1]) + bytes(8) + MANUAL_FRAME)
    expected += bytes(1024 - len(expected))
    assert image == expected
    assert image[24:36] == MANUAL_FRAME
    assert struct.unpack_from("<HH", image, 24) == (0x0040, 0x0123)


def test_manual_rxpdo_frame_decodes() -> None:
    """5.4.4.1 read back: the hand-built image of step 1-4 decodes to the one CAN0 frame."""
    layout = StreamLayout.default()
    image = image_by_hand(layout, 7, MANUAL_FRAME, 1)
    decoded = decode_stream(image, layout)
    assert decoded.header == StreamHeader(HeaderFlags(0), 7, 7, 12, crc16_bitwise(MANUAL_FRAME), 0x01E7, 0x0F, 1,
                                          0, 1, (0, 0, 0, 0), 0x16)
    (packet,) = decoded.packets
    assert packet == CanPacket.of(0, 0x123, data=bytes.fromhex("1122334455667788"))
    assert packet.frame.can_id == 0x123 and packet.frame.data == bytes.fromhex("1122334455667788")


def test_control_word_formula_of_the_example() -> None:
    """5.4.4.1: ctrl = channel | dlc<<3 | ide<<7 | fdf<<8 | brs<<9 | x<<10 | tsf<<11 | kind<<13;
    the example's values give 0x0040."""
    assert ctrl_word(0, 8) == 0x0040
    packet = CanPacket.of(0, 0x123, data=bytes(8))
    assert encode_stream(StreamLayout.default(), 1, [packet])[24:26] == b"\x40\x00"


@pytest.mark.parametrize(("field", "value", "bit"), [
    ("channel", 3, 0), ("dlc", 15, 3), ("ide", 1, 7), ("fdf", 1, 8), ("brs", 1, 9), ("x", 1, 10),
    ("tsf", 3, 11), ("kind", 1, 13), ("d64", 1, 15)])
def test_control_word_bit_positions(field: str, value: int, bit: int) -> None:
    """Chapter 8: Byte0 bit0..2 CH, bit3..6 DLC, bit7 IDE; Byte1 bit0 FDF, bit1 BRS, bit2 X,
    bit3..4 TSF, bit5..6 KIND, bit7 D64; the codec decodes each field from its own bits."""
    kw = {"ch" if field == "channel" else field: value}
    assert ctrl_word(**kw) == value << bit
    # decode a packet with just that field set (plus what makes it legal) and check the field
    layout = StreamLayout(profile=5, options=Option.TX_RESULT_ENABLE, direction=Direction.TX)
    if field == "channel":
        payload = std_packet(3, 0x10, b"")
        assert decode_stream(image_by_hand(layout, 1, payload, 1), layout).packets[0].channel == 3
    elif field == "kind":
        payload = tx_result_bytes(0, 1, 0, 0)
        assert decode_stream(image_by_hand(layout, 1, payload, 1), layout).packets[0].kind is PacketKind.TX_RESULT
    else:
        fd = field in ("dlc", "fdf", "brs", "x", "d64")
        data = bytes(64) if field == "dlc" else b""
        args = {"fdf": int(fd), "dlc": value if field == "dlc" else 0}
        if field in ("brs", "x", "d64"):
            args[field] = 1
        if field == "tsf":
            args["tsf"] = 3
            args["ts"] = bytes(8)
        if field == "d64":
            data = bytes(64)
        build = ext_packet if field == "ide" else std_packet
        payload = build(0, 0x10, data, **args)
        p = decode_stream(image_by_hand(layout, 1, payload, 1), layout).packets[0]
        assert isinstance(p, CanPacket)
        expect = {"dlc": ("data", bytes(64)), "ide": ("extended", True), "fdf": ("fd", True), "brs": ("brs", True),
                  "x": ("esi", True), "tsf": ("tsf", Tsf.FULL64), "d64": ("d64", True)}[field]
        assert getattr(p, expect[0]) == expect[1]


def test_std_id_field_and_id_aux() -> None:
    """8.1 StdIdField: bits 0..10 STD_ID, 11..13 ID_AUX; ExtIdField bits 0..28 EXT_ID, 29..31 ID_AUX."""
    layout = StreamLayout.default()
    image = encode_stream(layout, 1, [CanPacket.of(0, 0x7FF, id_aux=5), CanPacket.of(1, 0x1FFFFFFF, True, id_aux=7)])
    assert struct.unpack_from("<H", image, 26)[0] == 0x7FF | 5 << 11
    assert struct.unpack_from("<I", image, 30)[0] == 0x1FFFFFFF | 7 << 29
    a, b = decode_stream(image, layout).packets
    assert isinstance(a, CanPacket) and isinstance(b, CanPacket)
    assert (a.can_id, a.id_aux, b.can_id, b.id_aux, b.extended) == (0x7FF, 5, 0x1FFFFFFF, 7, True)


def test_dlc_table() -> None:
    """8.2: DLC 0..15 -> 0 1 2 3 4 5 6 7 8 12 16 20 24 32 48 64 bytes."""
    assert [dlc_to_len(d) for d in range(16)] == [0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64]
    layout = StreamLayout(multiplier=2)
    for dlc in range(16):
        n = dlc_to_len(dlc)
        image = encode_stream(layout, 1, [CanPacket.of(0, 1, fd=True, data=bytes(range(n)))])
        assert image[24] >> 3 & 15 == dlc and struct.unpack_from("<H", image, 6)[0] == 4 + n


@pytest.mark.parametrize(("packet", "raw", "aligned"), [
    (CanPacket.of(0, 0x123, data=bytes(8)), 12, 12),
    (CanPacket.of(0, 0x123456, True, data=bytes(8)), 14, 16),
    (CanPacket.of(0, 0x123, fd=True, data=bytes(64)), 68, 68),
    (CanPacket.of(0, 0x123456, True, fd=True, data=bytes(64), tsf=Tsf.DELTA16, timestamp=9), 72, 72),
])
def test_align4_length_examples(packet: CanPacket, raw: int, aligned: int) -> None:
    """8.3.1 length example: std DLC8 12/12; ext DLC8 14/16 (last 2 B padding 0); std FD DLC15
    68/68; ext FD DLC15 delta16 72/72 -- packet_bytes and payload_len, padding zero."""
    plain = StreamLayout(profile=1, direction=Direction.TX)
    align = StreamLayout(profile=1, options=Option.ALIGN_4_ENABLE, direction=Direction.TX)
    assert packet_size(packet, plain) == raw
    assert packet_size(packet, align) == aligned
    image = encode_stream(align, 1, [packet])
    assert struct.unpack_from("<H", image, 6)[0] == aligned
    assert image[24 + raw:24 + aligned] == bytes(aligned - raw)
    assert decode_stream(image, align).packets == (packet,)
    assert struct.unpack_from("<H", encode_stream(plain, 1, [packet]), 6)[0] == raw


def test_multi_frame_offsets_and_align4() -> None:
    """5.4.4.1 'For multiple frames': the second packet follows the first's packet_bytes;
    payload_len is their sum, frame_count their number; with ALIGN4 each advances by align4(raw)."""
    a = CanPacket.of(0, 0x100, True, data=b"\x01")          # 2 + 4 + 1 = 7 -> 8
    b = CanPacket.of(1, 0x200, data=b"\x02\x03")             # 2 + 2 + 2 = 6 -> 8
    plain = StreamLayout()
    image = encode_stream(plain, 1, [a, b])
    assert image[24:37] == ext_packet(0, 0x100, b"\x01") + std_packet(1, 0x200, b"\x02\x03")
    assert struct.unpack_from("<HxxxxBx", image, 6)[0] == 13
    assert image[13] == 2
    align = StreamLayout(options=Option.ALIGN_4_ENABLE)
    image = encode_stream(align, 1, [a, b])
    assert image[24:40] == ext_packet(0, 0x100, b"\x01", pad=1) + std_packet(1, 0x200, b"\x02\x03", pad=2)
    assert struct.unpack_from("<H", image, 6)[0] == 16


def test_tsf_sizes_and_schedule_format() -> None:
    """8.4: TSF 0/1/2/3 -> 0/2/4/8 bytes; RxPDO TSF_FULL64 reservation = format u8 1, flags u8 0,
    tag u16, offset_ns u32 after the id field."""
    tx = StreamLayout(profile=5, direction=Direction.TX, features=DEFAULT_FEATURES | Feature.TSF_DELTA32)
    for tsf, nbytes in zip(Tsf, (0, 2, 4, 8)):
        p = CanPacket.of(0, 1, tsf=tsf, timestamp=(1 << (8 * nbytes)) - 1 if nbytes else 0)
        assert packet_size(p, tx) == 4 + nbytes
        image = encode_stream(tx, 1, [p])
        assert image[28:28 + nbytes] == b"\xff" * nbytes
        assert decode_stream(image, tx).packets == (p,)
    rx = StreamLayout()
    p = CanPacket.of(2, 0x181, tsf=Tsf.FULL64, scheduled=True, tag=0xBEEF, offset_ns=100_000, data=b"\xaa")
    image = encode_stream(rx, 9, [p])
    assert image[24:37] == std_packet(2, 0x181, b"\xaa", tsf=3, ts=struct.pack("<BBHI", 1, 0, 0xBEEF, 100_000))
    assert decode_stream(image, rx).packets == (p,)


def test_header_offsets() -> None:
    """Chapter 6 table: ver_ihl 0, header_flags 1, seq_begin 2, seq_end 4, payload_len 6,
    payload_crc16 8, layout_id 10, channel_mask 12, frame_count 13, overflow_sat 14, crc_alg 15,
    channel_status[4] 16..23, little-endian; version 1 / ihl 6."""
    h = StreamHeader(HeaderFlags(0x2A), 0x0201, 0x0403, 0x0605, 0x0807, 0x0A09, 0x0B, 0x0C, 0x0D, 0x0E,
                     (0x1110, 0x1312, 0x1514, 0x1716), 0x16)
    raw = h.pack()
    assert raw == bytes([0x16, 0x2A, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 0x0B, 0x0C, 0x0D, 0x0E]) + bytes(range(0x10, 0x18))
    assert StreamHeader.unpack(raw) == h
    assert (h.version, h.ihl) == (1, 6)


def test_header_flag_bits() -> None:
    """Chapter 6 header_flags: bit0 STREAM_TRUNCATED .. bit5 OVERFLOW_SAT_VALID; 6/7 ignored."""
    assert [f.value for f in HeaderFlags] == [1, 2, 4, 8, 16, 32]
    assert [f.name for f in HeaderFlags] == ["STREAM_TRUNCATED", "ANY_CHANNEL_ERROR", "TX_RESULT_PRESENT",
                                             "STATUS_CHANGED", "SEQ_WRAP", "OVERFLOW_SAT_VALID"]
    layout = StreamLayout.default()
    image = image_by_hand(layout, 1, b"", 0, flags=0xC1)
    assert decode_stream(image, layout).header.header_flags == HeaderFlags.STREAM_TRUNCATED


def test_status_words_carried() -> None:
    """Chapter 7: four 16-bit channel status words at 16..23 (e.g. CAN1 state run 2, fd_enabled,
    rx_pending_sat 7)."""
    layout = StreamLayout.default(Direction.TX)
    words = (0x0000, 0x2 | 1 << 3 | 7 << 10, 0xFFFF, 0x0025)
    image = encode_stream(layout, 3, [], status_words=words)
    assert struct.unpack_from("<4H", image, 16) == words
    assert decode_stream(image, layout).header.channel_status == words


def test_overflow_sat_saturates_and_incomplete() -> None:
    """6.1: overflow_sat increases and saturates at 255; overflow_sat != 0 or STREAM_TRUNCATED
    marks the cycle incomplete."""
    layout = StreamLayout.default(Direction.TX)
    assert encode_stream(layout, 1, [], overflow_sat=1000)[14] == 255
    h = decode_stream(encode_stream(layout, 1, [], overflow_sat=3), layout).header
    assert h.overflow_sat == 3 and h.incomplete
    h = decode_stream(encode_stream(layout, 1, [], flags=HeaderFlags.STREAM_TRUNCATED), layout).header
    assert h.incomplete
    assert not decode_stream(encode_stream(layout, 1, []), layout).header.incomplete


def test_pdo_size_table() -> None:
    """5.2: ActivePDOBytes = 128*N, ActiveFrameAreaBytes = 128*N - 24, for every row of the table."""
    for n, pdo, area in ((1, 128, 104), (2, 256, 232), (3, 384, 360), (4, 512, 488), (6, 768, 744),
                         (8, 1024, 1000), (12, 1536, 1512), (16, 2048, 2024), (24, 3072, 3048)):
        layout = StreamLayout(multiplier=n)
        assert (layout.pdo_bytes, layout.frame_area_bytes) == (pdo, area)
        assert len(encode_stream(layout, 1, [])) == pdo


def test_profile_word_bits_and_layout_id() -> None:
    """13.2 Active profile word: 0..4 N-1, 5..12 mask, 13..18 profile, 19..20 budget, 21..28
    options; layout_id is its 5.4.4.1 fold, for a spread of layouts."""
    layout = StreamLayout(multiplier=24, channel_mask=0x0A, profile=5, budget_policy=BudgetPolicy.DETERMINISTIC,
                          options=0x1F)
    assert layout.profile_word == 23 | 0x0A << 5 | 5 << 13 | 2 << 19 | 0x1F << 21
    for n, mask, profile, budget, options in ((1, 1, 0, 0, 0), (3, 0x0F, 1, 1, 2), (24, 0x0F, 5, 2, 0x1F),
                                              (8, 0x03, 4, 0, 0x13)):
        lay = StreamLayout(n, mask, profile, budget, options)
        assert lay.layout_id == layout_id_by_hand(n, mask, profile, budget, options)
        assert decode_stream(encode_stream(lay, 1, []), lay).header.layout_id == lay.layout_id


def test_configuration_example_of_6_1() -> None:
    """6.1 configuration example and 9.2 defaults: N=8, CAN0..3, profile 0, Balanced, options 0
    -> 1024 / 1000 bytes; the default layout is exactly that."""
    layout = StreamLayout(8, 0x0F, 0, 0, 0)
    assert layout == StreamLayout.default()
    assert (layout.pdo_bytes, layout.frame_area_bytes, layout.channels) == (1024, 1000, (0, 1, 2, 3))
    assert layout.budget_policy == BudgetPolicy.BALANCED


def test_tx_result_layout_and_codes() -> None:
    """Chapter 10: Ctrl[2] (KIND=1, CH) + RefPacketSeq[2] + RefFrameIndex[1] + ResultCode[1];
    ResultCode 0 OK, 1 queued, 2 bus busy, 3 invalid channel, 4 tx fifo full, 5 bus off."""
    assert [(c.value, c.name) for c in TxResultCode] == [
        (0, "OK"), (1, "QUEUED"), (2, "BUS_BUSY"), (3, "INVALID_CHANNEL"), (4, "TX_FIFO_FULL"), (5, "BUS_OFF")]
    layout = StreamLayout(options=Option.TX_RESULT_ENABLE, direction=Direction.TX)
    packets = [TxResultPacket(2, 0x1234, 5, TxResultCode.BUS_OFF), CanPacket.of(1, 0x80)]
    image = encode_stream(layout, 1, packets)
    assert image[24:30] == tx_result_bytes(2, 0x1234, 5, 5) == bytes([0x02, 0x20, 0x34, 0x12, 5, 5])
    decoded = decode_stream(image, layout)
    assert decoded.packets == tuple(packets)
    assert decoded.header.header_flags & HeaderFlags.TX_RESULT_PRESENT
    assert decoded.tx_results == (packets[0],) and decoded.frames == (packets[1],)


def test_crc_covers_payload_only() -> None:
    """6.1 / 11: payload_crc16 covers [24, 24+payload_len), not the header: changing a status word
    keeps the CRC, changing a payload byte changes it."""
    layout = StreamLayout.default(Direction.TX)
    p = [CanPacket.of(0, 0x123, data=b"\x01\x02")]
    a = encode_stream(layout, 1, p, status_words=(1, 2, 3, 4))
    b = encode_stream(layout, 1, p)
    assert a[8:10] == b[8:10]
    c = encode_stream(layout, 1, [CanPacket.of(0, 0x123, data=b"\x01\x03")])
    assert c[8:10] != b[8:10]
    assert struct.unpack_from("<H", a, 8)[0] == crc16_bitwise(a[24:24 + 6])


def test_no_crc16_header() -> None:
    """9.1 NO_CRC16_ENABLE: crc_alg 0 and payload_crc16 0 in the header."""
    layout = StreamLayout(options=Option.NO_CRC16_ENABLE)
    image = encode_stream(layout, 1, [CanPacket.of(0, 5, data=b"x")])
    assert image[15] == 0 and image[8:10] == b"\0\0"
    assert decode_stream(image, layout).packets == (CanPacket.of(0, 5, data=b"x"),)


def test_last_pdo_error_table() -> None:
    """13.2 Last PDO error values 0, 2..16 with their names."""
    assert [(e.value, e.name) for e in PdoError] == [
        (0, "OK"), (2, "FRAME_OVERRUN"), (3, "PACKET_OVERRUN"), (4, "UNKNOWN_KIND"), (5, "INVALID_DLC"),
        (6, "INVALID_CHANNEL"), (7, "INVALID_TSF"), (8, "TRUNCATED"), (9, "UNSUPPORTED_PROFILE"),
        (10, "DUPLICATE_SEQUENCE"), (11, "UNSUPPORTED_OPTION"), (12, "ACTIVE_AREA"), (13, "RESERVED_BIT"),
        (14, "BAD_HEADER"), (15, "BAD_CRC"), (16, "BAD_SCHEDULE")]


def test_apply_status_table_and_checks() -> None:
    """13.2 Status values; 5.2 N 1..24; 9 profiles 0/1/4/5 (mask 0x33, 13.8); 12 policy 3
    reserved; 9.1 reserved option bits 5..7 -> 10 unsupported option flag."""
    assert [s.value for s in ProfileStatus] == [0, 1, 2, 3, 4, 5, 7, 8, 9, 10]
    assert check_layout(8, 0x0F, 0, 0, 0) is ProfileStatus.OK
    assert check_layout(0, 0x0F, 0, 0, 0) is ProfileStatus.INVALID_MULTIPLIER
    assert check_layout(25, 0x0F, 0, 0, 0) is ProfileStatus.INVALID_MULTIPLIER
    assert check_layout(8, 0x10, 0, 0, 0) is ProfileStatus.INVALID_CHANNEL_MASK
    assert [check_layout(8, 0x0F, p, 0, 0) is ProfileStatus.OK for p in range(8)] == [
        bool(PROFILE_MASK >> p & 1) for p in range(8)]
    assert check_layout(8, 0x0F, 2, 0, 0) is ProfileStatus.INVALID_PROFILE
    assert check_layout(8, 0x0F, 0, 3, 0) is ProfileStatus.INVALID_PROFILE
    for value in (0x00, 0x01, 0x02, 0x03, 0x04, 0x08, 0x10, 0x1F):   # 9.1 "Commonly written values"
        assert check_options(value) is ProfileStatus.OK
    for bit in (0x20, 0x40, 0x80):
        assert check_options(bit) is ProfileStatus.UNSUPPORTED_OPTION
        assert check_layout(8, 0x0F, 0, 0, bit | 1) is ProfileStatus.UNSUPPORTED_OPTION


def test_option_and_feature_masks() -> None:
    """9.1 option bits 0x01..0x10; 13.8 0xF000:15 = 0x1F, :16 = 0x1F3B (no delta32, no CRC32)."""
    assert [(o.name, o.value) for o in Option] == [
        ("TX_RESULT_ENABLE", 1), ("ALIGN_4_ENABLE", 2), ("NO_CRC16_ENABLE", 4), ("APP_BYPASS_ENABLE", 8),
        ("PAYLOAD_ONLY_ENABLE", 16)]
    assert OPTION_MASK == 0x1F and PROFILE_MASK == 0x33
    assert DEFAULT_FEATURES == 0x1F3B
    assert not DEFAULT_FEATURES & (Feature.TSF_DELTA32 | Feature.STREAM_CRC32)
    assert DEFAULT_FEATURES & Feature.RX_TSF_SCHEDULE_TX and DEFAULT_FEATURES & Feature.D64


@pytest.mark.parametrize("profile", [0, 1, 4, 5])
def test_profile_feature_table(profile: int) -> None:
    """Chapter 9: D64 only in profiles 4/5, delta16 only in 1/5 (TxPDO timestamps)."""
    tx = StreamLayout(profile=profile, direction=Direction.TX)
    assert tx.allows_tsf(Tsf.DELTA16) == (profile in (1, 5))
    d64 = CanPacket.of(0, 1, fd=True, data=bytes(8), d64=True)
    if profile in (4, 5):
        assert packet_size(d64, tx) == 2 + 2 + 64
    else:
        with pytest.raises(ValueError):
            packet_size(d64, tx)


def test_timestamp_ticks() -> None:
    """8.4: delta16/delta32 are the low 16/32 bits of the difference to the cycle's reference time
    (the master treats wrap as an unsigned difference); full64 the whole time; 1 us ticks."""
    assert timestamp_ticks(1.5, Tsf.NONE) == 0
    assert timestamp_ticks(10.000250, Tsf.DELTA16, reference=10.0) == 250
    assert timestamp_ticks(10.070000, Tsf.DELTA16, reference=10.0) == 70_000 - 65_536
    assert timestamp_ticks(10.000250, Tsf.DELTA32, reference=10.0) == 250
    assert timestamp_ticks(3.25, Tsf.FULL64) == 3_250_000
    h = StreamHeader(payload_crc16=0xBEEF)
    assert h.crc == 0xBEEF
