"""Property tests of the ECAN-Lite frame-stream codec (manual chapters 6-10, 13.2): round trips
over every legal layout, and nothing but StreamError out of any bytes."""

from __future__ import annotations

import struct

from ecanlite_stream_kit import can_packets, crc16_bitwise, layouts, tx_results
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gatewaylab.devices.ecanlite.stream import (
    HEADER_SIZE,
    MAX_FRAME_COUNT,
    Commit,
    DecodedStream,
    Direction,
    Packet,
    StreamError,
    StreamLayout,
    commit_state,
    decode_stream,
    encode_stream,
    packet_size,
)

_SETTINGS = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@st.composite
def streams(draw: st.DrawFn) -> tuple[StreamLayout, int, list[Packet]]:
    """A layout, a sequence and packets that fit its frame area."""
    layout = draw(layouts())
    choices = [can_packets(layout)]
    if layout.direction is Direction.TX and layout.options & 1:
        choices.append(tx_results(layout))
    candidates = draw(st.lists(st.one_of(*choices), max_size=40))
    packets: list[Packet] = []
    used = 0
    for p in candidates:
        size = packet_size(p, layout)
        if used + size <= layout.frame_area_bytes and len(packets) < MAX_FRAME_COUNT:
            packets.append(p)
            used += size
    return layout, draw(st.integers(0, 0xFFFF)), packets


def _decode_only_stream_errors(image: bytes, layout: StreamLayout) -> DecodedStream | None:
    try:
        return decode_stream(image, layout)
    except StreamError as exc:
        assert exc.pdo_error.value != 0
        return None


@_SETTINGS
@given(streams(), st.lists(st.integers(0, 0xFFFF), min_size=4, max_size=4), st.integers(0, 0x3F),
       st.integers(0, 1000))
def test_round_trip(stream: tuple[StreamLayout, int, list[Packet]], status: list[int], flags: int,
                    overflow: int) -> None:
    """Chapters 6, 8, 10: whatever a layout can carry comes back equal; payload_len is the sum of
    packet_size (8.3), the unused area is zero, overflow_sat saturates (6.1)."""
    layout, seq, packets = stream
    image = encode_stream(layout, seq, packets, status_words=status, flags=flags, overflow_sat=overflow)
    assert len(image) == layout.pdo_bytes
    decoded = decode_stream(image, layout)
    assert decoded.packets == tuple(packets)
    h = decoded.header
    assert (h.seq_begin, h.seq_end, h.frame_count, h.overflow_sat) == (seq, seq, len(packets), min(overflow, 255))
    assert h.channel_status == tuple(status) and h.layout_id == layout.layout_id
    assert h.payload_len == sum(packet_size(p, layout) for p in packets)
    assert image[HEADER_SIZE + h.payload_len:] == bytes(layout.frame_area_bytes - h.payload_len)
    assert commit_state(image, None) is Commit.NEW and commit_state(image, image) is Commit.SAME


@_SETTINGS
@given(layouts(), st.binary(max_size=3100))
def test_random_bytes_only_stream_errors(layout: StreamLayout, junk: bytes) -> None:
    """13.2: any bytes, any length, give a decoded stream or a StreamError with a LastPDOError."""
    _decode_only_stream_errors(junk, layout)
    _decode_only_stream_errors(junk[:layout.pdo_bytes].ljust(layout.pdo_bytes, b"\0"), layout)
    try:
        assert isinstance(commit_state(junk, junk[::-1] or None), Commit)
    except StreamError as exc:
        assert len(junk) < HEADER_SIZE and exc.pdo_error == 12


@_SETTINGS
@given(layouts(), st.binary(min_size=0, max_size=600), st.integers(0, 255), st.integers(0, 0xFFFF))
def test_random_payload_under_a_good_header(layout: StreamLayout, payload: bytes, count: int, seq: int) -> None:
    """Chapter 8 / 13.2: random packet bytes under a correct header and CRC reach the packet
    parser; only StreamError comes out, and whatever decodes re-encodes to the same bytes."""
    payload = payload[:layout.frame_area_bytes]
    crc, alg = (crc16_bitwise(payload), 1) if layout.crc_enabled else (0, 0)
    header = struct.pack("<BBHHHHHBBBB4H", 0x16, 0, seq, seq, len(payload), crc, layout.layout_id,
                         layout.channel_mask, count, 0, alg, 0, 0, 0, 0)
    image = (header + payload).ljust(layout.pdo_bytes, b"\0")
    decoded = _decode_only_stream_errors(image, layout)
    if decoded is not None:
        again = encode_stream(layout, seq, decoded.packets)
        # ID_AUX and the D64 window tail are 'receiver ignores' fields: compare what they carry
        assert decode_stream(again, layout).packets == decoded.packets
        assert len(decoded.packets) == count


@_SETTINGS
@given(streams(), st.lists(st.tuples(st.integers(0, 3099), st.integers(0, 255)), min_size=1, max_size=8),
       st.booleans())
def test_mutated_images_only_stream_errors(stream: tuple[StreamLayout, int, list[Packet]],
                                           edits: list[tuple[int, int]], fix_crc: bool) -> None:
    """6.1 / 13.2: a valid image with random bytes changed (and, half the time, the CRC fixed up
    so the packet checks run) decodes or raises StreamError, nothing else."""
    layout, seq, packets = stream
    image = bytearray(encode_stream(layout, seq, packets))
    for pos, value in edits:
        image[pos % len(image)] = value
    if fix_crc and layout.crc_enabled:
        n = struct.unpack_from("<H", image, 6)[0]
        if HEADER_SIZE + n <= len(image):
            struct.pack_into("<H", image, 8, crc16_bitwise(bytes(image[HEADER_SIZE:HEADER_SIZE + n])))
    _decode_only_stream_errors(bytes(image), layout)
    _decode_only_stream_errors(bytes(image), StreamLayout.default())
