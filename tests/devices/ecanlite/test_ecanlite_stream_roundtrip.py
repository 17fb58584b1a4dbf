"""Encode -> decode of every ECAN-Lite packet shape, byte-by-byte partial images, the 5.4.4.1
commit order and trailing bytes after payload_len (manual chapters 5.4.4, 6, 8-10)."""

from __future__ import annotations

import struct
from contextlib import nullcontext

import pytest
from ecanlite_stream_kit import FD_LENGTHS, crc16_bitwise

from gatewaylab.bus.frame import CanFrame
from gatewaylab.devices.ecanlite.stream import (
    DEFAULT_FEATURES,
    HEADER_SIZE,
    CanPacket,
    Commit,
    Direction,
    Feature,
    Option,
    Packet,
    StreamError,
    StreamLayout,
    Tsf,
    TxResultCode,
    TxResultPacket,
    commit_state,
    decode_stream,
    encode_into,
    encode_stream,
    next_seq,
    packet_size,
)

ALL_TSF = DEFAULT_FEATURES | Feature.TSF_DELTA32


def _layouts(direction: Direction) -> list[StreamLayout]:
    return [StreamLayout(multiplier=4, profile=profile, options=options, direction=direction, features=ALL_TSF)
            for profile in (0, 1, 4, 5) for options in (0, Option.ALIGN_4_ENABLE | Option.TX_RESULT_ENABLE)]


def _shapes(layout: StreamLayout) -> list[Packet]:
    """Every packet shape the layout can carry, on every channel in turn."""
    out: list[Packet] = []
    tsfs = [t for t in Tsf if layout.allows_tsf(t)]
    i = 0
    for extended in (False, True):
        can_id = 0x1ABCDEF5 if extended else 0x5A5
        for tsf in tsfs:
            scheduled = tsf is Tsf.FULL64 and layout.direction is Direction.RX
            stamp = 0 if scheduled or tsf is Tsf.NONE else (1 << (8 * (2, 4, 8)[tsf - 1])) - 3
            kw = {"tsf": tsf, "timestamp": stamp, "scheduled": scheduled, "offset_ns": 250_000 if scheduled else 0,
                  "tag": 0x77 if scheduled else 0}
            for n in range(9):
                out.append(CanPacket.of(i % 4, can_id, extended, data=bytes(range(n)), id_aux=i % 8, **kw))
                i += 1
            for dlc in range(9):
                out.append(CanPacket.of(i % 4, can_id, extended, rtr=True, dlc=dlc, **kw))
                i += 1
            for n in FD_LENGTHS:
                out.append(CanPacket.of(i % 4, can_id, extended, fd=True, brs=bool(i & 1), esi=bool(i & 2),
                                     data=bytes(range(100, 100 + n)), **kw))
                i += 1
                if layout.profile in (4, 5):
                    out.append(CanPacket.of(i % 4, can_id, extended, fd=True, data=bytes(range(n)), d64=True, **kw))
                    i += 1
    if layout.direction is Direction.TX and layout.options & Option.TX_RESULT_ENABLE:
        out += [TxResultPacket(ch, 0xFFFF - ch, ch * 50, code) for ch, code in zip(range(4), TxResultCode)]
    return out


@pytest.mark.parametrize("layout", _layouts(Direction.TX) + _layouts(Direction.RX), ids=lambda lay: (
    f"{lay.direction.value}-p{lay.profile}-o{lay.options:02x}"))
def test_every_shape_round_trips(layout: StreamLayout) -> None:
    """Chapter 8/10: every KIND, TSF, FD length (8.2), 11 and 29-bit id, remote frames, D64 (9),
    ALIGN4 (8.3) and TX_RESULT comes back field for field; payload_len is the sum of packet_size."""
    shapes = _shapes(layout)
    while shapes:
        batch: list[Packet] = []
        used = 0
        while shapes and used + packet_size(shapes[0], layout) <= layout.frame_area_bytes:
            used += packet_size(shapes[0], layout)
            batch.append(shapes.pop(0))
        image = encode_stream(layout, 0xFFFF, batch)
        decoded = decode_stream(image, layout)
        assert decoded.packets == tuple(batch)
        assert decoded.header.payload_len == used and decoded.header.frame_count == len(batch)
        assert image[HEADER_SIZE + used:] == bytes(layout.pdo_bytes - HEADER_SIZE - used)


def test_packets_and_bus_frames() -> None:
    """8.1: a packet is a bus frame plus its channel: from_frame / frame round trip, remote DLC kept."""
    frames = [CanFrame(0x123, b"\x01\x02"), CanFrame(0x1FFFFFFF, bytes(64), extended=True, fd=True, brs=True),
              CanFrame(0x7FF, rtr=True, dlc=5), CanFrame(0x10, bytes(12), fd=True, esi=True)]
    layout = StreamLayout(profile=1, direction=Direction.TX)
    packets = [CanPacket.from_frame(k, f, tsf=Tsf.DELTA16, timestamp=k) for k, f in enumerate(frames)]
    decoded = decode_stream(encode_stream(layout, 1, packets), layout)
    assert [p.frame for p in decoded.frames] == frames
    assert [p.channel for p in decoded.frames] == [0, 1, 2, 3]


def test_prefixes_of_an_image() -> None:
    """5.4.4 / 6.1: a receiver given only the first k bytes of an image (the rest still zero, or
    missing) gets a StreamError or, once header and payload are all there, exactly the packets."""
    layout = StreamLayout(multiplier=2, options=Option.ALIGN_4_ENABLE)
    packets = [CanPacket.of(1, 0x100, data=b"\xa5" * 5),
               CanPacket.of(2, 0x1234567, True, fd=True, data=bytes(range(20))),
               CanPacket.of(3, 0x7F, rtr=True, dlc=2),
               CanPacket.of(0, 0x55, tsf=Tsf.FULL64, scheduled=True, offset_ns=9)]
    image = encode_stream(layout, 0x1234, packets)
    complete = HEADER_SIZE + struct.unpack_from("<H", image, 6)[0]
    for k in range(len(image) + 1):
        with pytest.raises(StreamError) if k < len(image) else nullcontext():
            decode_stream(image[:k], layout)          # missing bytes: never the mapped length
        zero_filled = image[:k] + bytes(len(image) - k)
        try:
            decoded = decode_stream(zero_filled, layout)
        except StreamError:
            assert k < complete     # (the last bytes may be zeros already: k < complete can decode)
            continue
        assert decoded.packets == tuple(packets)


def test_commit_order_never_shows_a_half_image() -> None:
    """5.4.4.1 step 4: frame area first, then header 0..3 and 6..23, seq_end last. Over the old
    image, every intermediate state is TORN (the old header's CRC no longer matches, or the
    sequences differ) or SAME (only bytes beyond the old payload changed) until seq_end lands;
    then NEW with the new frames."""
    layout = StreamLayout.default()
    old = encode_stream(layout, 41, [CanPacket.of(0, 0x111, data=b"old")])
    new = encode_stream(layout, 42, [CanPacket.of(1, 0x222, data=b"newframe"), CanPacket.of(2, 0x333, fd=True,
                                                                                        data=bytes(48))])
    order = [*range(HEADER_SIZE, len(new)), 0, 1, 2, 3, *range(6, HEADER_SIZE), 4, 5]
    state = bytearray(old)
    for pos in order:
        state[pos] = new[pos]
        verdict = commit_state(state, old)
        if state != new:    # (seq 41 -> 42 commits with the low byte of seq_end: the high byte is equal)
            assert verdict in (Commit.TORN, Commit.SAME), pos
            if verdict is Commit.SAME:     # only the frame area beyond the old payload changed so far
                assert decode_stream(bytes(state), layout).packets == decode_stream(old, layout).packets
        else:
            assert verdict is Commit.NEW
            assert decode_stream(bytes(state), layout).packets == decode_stream(new, layout).packets


def test_payload_len_boundaries_give_fewer_packets() -> None:
    """6: payload_len and frame_count say how many packets count; the same bytes with a header
    covering only the first k packets decode to exactly those k (the rest is ignored)."""
    layout = StreamLayout(multiplier=3, channel_mask=0x0F)
    packets = [CanPacket.of(k % 4, 0x100 + k, data=bytes([k]) * (k % 9)) for k in range(12)]
    image = bytearray(encode_stream(layout, 7, packets))
    off = HEADER_SIZE
    for k in range(len(packets) + 1):
        trimmed = bytearray(image)
        struct.pack_into("<HH", trimmed, 6, off - HEADER_SIZE, crc16_bitwise(bytes(image[HEADER_SIZE:off])))
        trimmed[13] = k
        assert decode_stream(bytes(trimmed), layout).packets == tuple(packets[:k])
        if k < len(packets):
            off += packet_size(packets[k], layout)


def test_trailing_garbage_ignored_but_not_under_the_crc() -> None:
    """9.1 PAYLOAD_ONLY / 6.1: receivers ignore bytes beyond payload_len (garbage there changes
    nothing); the CRC covers exactly [24, 24+payload_len), so a CRC taken over the garbage too fails."""
    layout = StreamLayout.default()
    packets = [CanPacket.of(0, 0x123, data=b"\x11\x22")]
    image = bytearray(encode_stream(layout, 1, packets))
    image[30:] = bytes((i * 37 + 11) & 0xFF for i in range(len(image) - 30))
    assert decode_stream(bytes(image), layout).packets == tuple(packets)
    struct.pack_into("<H", image, 8, crc16_bitwise(bytes(image[24:40])))
    with pytest.raises(StreamError) as info:
        decode_stream(bytes(image), layout)
    assert info.value.pdo_error == 15


def test_payload_only_leaves_the_rest_of_the_buffer() -> None:
    """9.1 PAYLOAD_ONLY_ENABLE: 'update only the 24-byte header and valid payload'; without it the
    unused frame area is zeroed (8.3)."""
    buf = bytearray(b"\xee" * 1024)
    n = encode_into(buf, StreamLayout(options=Option.PAYLOAD_ONLY_ENABLE), 3, [CanPacket.of(0, 1, data=b"a")])
    assert n == 5 and buf[29:] == b"\xee" * (1024 - 29)
    encode_into(buf, StreamLayout(), 4, [CanPacket.of(0, 1, data=b"a")])
    assert buf[29:] == bytes(1024 - 29)


def test_sequence_wrap() -> None:
    """6.1: seq_begin increments per published image and wraps at 16 bits (SEQ_WRAP)."""
    assert next_seq(0xFFFE) == (0xFFFF, False)
    assert next_seq(0xFFFF) == (0, True)
    layout = StreamLayout.default(Direction.TX)
    assert decode_stream(encode_stream(layout, 0x1_0005, []), layout).seq == 5


def test_process_image_views() -> None:
    """5.4.4: the device writes and reads the PDO in place: encode_into a memoryview of the process
    image gives the bytes encode_stream returns, and decode_stream / commit_state read views too."""
    layout = StreamLayout(multiplier=3, options=Option.ALIGN_4_ENABLE | Option.TX_RESULT_ENABLE,
                          direction=Direction.TX)
    packets: list[Packet] = [TxResultPacket(1, 2, 3, TxResultCode.QUEUED), CanPacket.of(3, 0x1F, data=b"\x01\x02\x03")]
    process = bytearray(b"\xaa" * 1000)
    view = memoryview(process)[100:100 + layout.pdo_bytes]
    assert encode_into(view, layout, 77, packets) == 8 + 8
    assert bytes(view) == encode_stream(layout, 77, packets)
    assert process[:100] == b"\xaa" * 100 and process[100 + layout.pdo_bytes:] == b"\xaa" * (900 - layout.pdo_bytes)
    assert decode_stream(view, layout).packets == tuple(packets)
    assert decode_stream(bytearray(view), layout).packets == tuple(packets)
    assert commit_state(view, bytes(view)) is Commit.SAME
