"""The branches the codec's speed work added (issue 10 benchmarks, issue 22), checked against the
manual: packets the decoder builds are the same frozen packets the constructor makes, packets carry
their own wire bytes (8.1, 8.3) and the encoder joins them, and the decoder's one-test fast path
for common control words never changes what is accepted or refused (chapters 8-10, 13.2)."""

from __future__ import annotations

import copy
import dataclasses
import pickle
import struct

import pytest
from ecanlite_stream_kit import (
    MISTYPED,
    PACKETS_COMPILED,
    can_packets,
    ext_packet,
    image_by_hand,
    layouts,
    std_packet,
    tx_result_bytes,
    tx_results,
)
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.errors import LocalError
from gatewaylab.devices.ecanlite.stream import (
    MAX_FRAME_COUNT,
    CanPacket,
    Direction,
    HeaderFlags,
    Option,
    Packet,
    PdoError,
    StreamEncodeError,
    StreamError,
    StreamHeader,
    StreamLayout,
    Tsf,
    TxResultCode,
    TxResultPacket,
    decode_stream,
    encode_into,
    encode_stream,
    packet_size,
)

_SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
D64_LAYOUT = StreamLayout(multiplier=2, channel_mask=0x0F, profile=4)
TX_RESULT_LAYOUT = StreamLayout(multiplier=2, channel_mask=0x0F, options=Option.TX_RESULT_ENABLE,
                                direction=Direction.TX)


@st.composite
def packet_lists(draw: st.DrawFn) -> tuple[StreamLayout, list[Packet]]:
    """A layout and packets that fit its frame area (CAN_FRAMEs, and TX_RESULTs where enabled)."""
    layout = draw(layouts())
    choices = [can_packets(layout)]
    if layout.direction is Direction.TX and layout.options & Option.TX_RESULT_ENABLE:
        choices.append(tx_results(layout))
    packets: list[Packet] = []
    used = 0
    for p in draw(st.lists(st.one_of(*choices), max_size=40)):
        size = packet_size(p, layout)
        if used + size <= layout.frame_area_bytes and len(packets) < MAX_FRAME_COUNT:
            packets.append(p)
            used += size
    return layout, packets


def _outcome(image: bytes, layout: StreamLayout) -> object:
    try:
        return decode_stream(image, layout)
    except StreamError as exc:
        return exc.pdo_error, exc.diag


@_SETTINGS
@given(packet_lists(), st.integers(0, 0xFFFF))
def test_decoded_packets_encode_to_the_same_image(stream: tuple[StreamLayout, list[Packet]], seq: int) -> None:
    """8.1, 8.3, 5.4.4.1 step 4: a decoded packet carries the bytes it came from, so encoding the
    decoded packets again gives the received image byte for byte (same layout, fresh layout)."""
    layout, packets = stream
    image = encode_stream(layout, seq, packets)
    decoded = decode_stream(image, layout)
    assert decoded.packets == tuple(packets)
    assert encode_stream(layout, seq, decoded.packets) == image
    assert encode_stream(dataclasses.replace(layout), seq, decoded.packets) == image


@_SETTINGS
@given(packet_lists())
def test_decoded_packets_are_ordinary_frozen_packets(stream: tuple[StreamLayout, list[Packet]]) -> None:
    """Chapter 8: a packet read from an image is the packet its fields describe: same type, equal,
    same hash, same derived control word and length, frozen, picklable; rebuilding it from its
    fields gives the same wire bytes (8.3 raw_packet_bytes)."""
    layout, packets = stream
    decoded = decode_stream(encode_stream(layout, 1, packets), layout).packets
    for built, read in zip(packets, decoded, strict=True):
        assert type(read) is type(built) and read == built and hash(read) == hash(built)
        assert repr(read) == repr(built) and read.ctrl == built.ctrl
        assert packet_size(read, layout) == packet_size(built, layout)
        assert pickle.loads(pickle.dumps(read)) == read
        with pytest.raises(dataclasses.FrozenInstanceError):
            read.channel = 3  # type: ignore[misc]
        if type(read) is CanPacket:
            assert type(built) is CanPacket
            assert read.raw_size == built.raw_size and read.frame == built.frame
            assert dataclasses.replace(read) == read
            assert encode_stream(layout, 1, [dataclasses.replace(read)]) == encode_stream(layout, 1, [read])


def test_a_decoded_image_pickles_and_copies() -> None:
    """Chapter 6, chapter 10: the records of a decoded image (its header, the image with its
    CAN_FRAME and TX_RESULT packets) are values like the packets: pickled, copied and deep-copied
    they come back equal (compiled, the header and the image needed their own ``__reduce__``:
    mypyc's default refills a frozen record through setattr)."""
    packets = [CanPacket.of(1, 0x55, data=b"ab"), TxResultPacket(2, 7, 0, TxResultCode.OK)]
    image = encode_stream(TX_RESULT_LAYOUT, 7, packets,
                          status_words=(1, 2, 3, 4), overflow_sat=3)
    decoded = decode_stream(image, TX_RESULT_LAYOUT)
    for record in (decoded, decoded.header, StreamHeader()):
        for twin in (pickle.loads(pickle.dumps(record)), copy.copy(record), copy.deepcopy(record),
                     dataclasses.replace(record)):
            assert twin == record and hash(twin) == hash(record) and repr(twin) == repr(record)
    assert pickle.loads(pickle.dumps(decoded)).header.channel_status == (1, 2, 3, 4)


@_SETTINGS
@given(layouts(), st.binary(max_size=3100), st.binary(max_size=3100))
def test_a_warm_layout_judges_like_a_fresh_one(layout: StreamLayout, first: bytes, second: bytes) -> None:
    """13.2: the control words a layout has already judged do not change the next verdict: any
    bytes decode (or fail with the same LastPDOError and diag) alike on a layout that has seen
    other images and on a fresh copy, and only StreamError comes out."""
    for junk in (first, second, first):
        warm = _outcome(junk, layout)
        fresh = _outcome(junk, dataclasses.replace(layout))
        assert warm == fresh
        if isinstance(warm, tuple):
            assert warm[0] is not PdoError.OK


@_SETTINGS
@given(packet_lists(), st.data())
def test_warm_layout_random_payload_under_a_good_header(stream: tuple[StreamLayout, list[Packet]],
                                                        data: st.DataObject) -> None:
    """6.1, 13.2: a valid image's frame area overwritten with random bytes (header and CRC made
    to match) decodes to packets or fails with a StreamError, the same on a warm layout as on a
    fresh one."""
    layout, packets = stream
    decode_stream(encode_stream(layout, 1, packets), layout)       # warm the cache
    payload = data.draw(st.binary(max_size=layout.frame_area_bytes))
    count = data.draw(st.integers(0, 255))
    image = image_by_hand(layout, 2, payload, count, crc_alg=0 if layout.options & Option.NO_CRC16_ENABLE else 1,
                          crc=0 if layout.options & Option.NO_CRC16_ENABLE else None)
    assert _outcome(image, layout) == _outcome(image, dataclasses.replace(layout))


def test_d64_window_tail_is_written_zero() -> None:
    """8.1, 8.3: a D64 packet occupies a 64-byte window and the unused bytes are 0; a received
    window with other bytes in its tail reads as the DLC's data, and re-sending it writes zeros."""
    window = bytes(range(1, 13)) + bytes(range(0xA0, 0xA0 + 52))     # 12 data bytes, junk tail
    payload = std_packet(1, 0x123, window, dlc=9, fdf=1, d64=1)
    image = image_by_hand(D64_LAYOUT, 5, payload, 1)
    (p,) = decode_stream(image, D64_LAYOUT).packets
    assert isinstance(p, CanPacket)
    assert p.d64 and p.data == bytes(range(1, 13)) and p.raw_size == 2 + 2 + 64
    clean = image_by_hand(D64_LAYOUT, 5, std_packet(1, 0x123, bytes(range(1, 13)) + bytes(52), dlc=9, fdf=1, d64=1), 1)
    assert encode_stream(D64_LAYOUT, 5, [p]) == clean
    assert p == CanPacket.of(1, 0x123, fd=True, d64=True, data=bytes(range(1, 13)))


def test_cached_control_words_still_get_the_per_packet_checks() -> None:
    """8.4: TSF_FULL64 is a reservation in the RxPDO and a timestamp in the TxPDO, per packet,
    also once the control word is known to the layout; chapter 6: TX_RESULT_PRESENT is set on
    every image with a TX_RESULT, not only the first."""
    rx = StreamLayout(multiplier=1)
    good = CanPacket.of(0, 0x10, data=b"\1", tsf=Tsf.FULL64, scheduled=True, offset_ns=500, tag=7)
    stamped = CanPacket.of(0, 0x10, data=b"\1", tsf=Tsf.FULL64, timestamp=99)
    assert good.ctrl == stamped.ctrl
    for _ in range(2):
        encode_stream(rx, 1, [good])
        with pytest.raises(StreamEncodeError) as info:
            encode_stream(rx, 1, [good, stamped])
        assert info.value.pdo_error is PdoError.BAD_SCHEDULE
    result = TxResultPacket(2, 7, 0, TxResultCode.OK)
    frame = CanPacket.of(2, 0x55, data=b"ab")
    for _ in range(2):
        assert encode_stream(TX_RESULT_LAYOUT, 1, [frame])[1] == 0
        image = encode_stream(TX_RESULT_LAYOUT, 1, [frame, result])
        assert image[1] == HeaderFlags.TX_RESULT_PRESENT
        assert image[24:24 + 4 + 2 + 6] == std_packet(2, 0x55, b"ab") + tx_result_bytes(2, 7, 0, 0)


def test_first_refused_packet_in_stream_order() -> None:
    """13.2, chapter 8: of several packets a layout cannot carry, the encoder reports the first in
    stream order (here channel 3 outside mask 0x07, then a D64 packet outside profiles 4/5)."""
    layout = StreamLayout(multiplier=1, channel_mask=0x07)
    ok = CanPacket.of(0, 1, data=b"x")
    wrong_channel = CanPacket.of(3, 1, data=b"x")
    d64 = CanPacket.of(1, 1, fd=True, d64=True, data=b"x")
    for first, code in ((wrong_channel, PdoError.INVALID_CHANNEL), (d64, PdoError.FRAME_OVERRUN)):
        second = d64 if first is wrong_channel else wrong_channel
        encode_stream(layout, 1, [ok])
        with pytest.raises(StreamEncodeError) as info:
            encode_stream(layout, 1, [ok, first, second])
        assert info.value.pdo_error is code


def test_refused_or_foreign_packets_write_nothing() -> None:
    """5.4.4.1 step 4: nothing is written from an image the encoder refuses, a control word
    already judged or not; a non-packet is a local error."""
    layout = StreamLayout(multiplier=1, channel_mask=0x01)
    buf = bytearray(encode_stream(layout, 9, [CanPacket.of(0, 2, data=b"keep")]))
    before = bytes(buf)
    for packets in ([CanPacket.of(0, 1, data=b"y"), CanPacket.of(1, 1, data=b"x")],
                    [CanPacket.of(0, 1, data=b"y")] * 40):
        with pytest.raises(StreamEncodeError):
            encode_into(buf, layout, 10, packets)
        assert bytes(buf) == before
    for foreign in (b"\0\0\0\0", struct.pack("<HH", 0, 1), None):
        with pytest.raises(LocalError):
            encode_into(buf, layout, 10, [CanPacket.of(0, 1, data=b"y"), foreign])  # type: ignore[list-item]
        assert bytes(buf) == before


def test_truncated_control_word_after_it_was_judged() -> None:
    """8, 13.2: a control word cut by payload_len is TRUNCATED (8) even when the same control
    word was accepted in an earlier packet of the image."""
    layout = StreamLayout(multiplier=1)
    body = std_packet(0, 1, b"a") + ext_packet(1, 0x1234567, b"bc")
    payload = body + body[:1]
    image = image_by_hand(layout, 3, payload, 3)
    with pytest.raises(StreamError) as info:
        decode_stream(image, layout)
    assert info.value.pdo_error is PdoError.TRUNCATED
    assert info.value.diag.offset == 24 + len(body) and info.value.diag.packet_end == 24 + len(body) + 2


def test_packets_are_plain_records_holding_a_frame() -> None:
    """8.1, 10 (issue 22: plain frozen packets; a CanPacket holds a CanFrame instead of re-checking
    CAN rules): the packets' fields are their record, ctrl and wire are derived from them, and
    what no receiver would take is refused with the LastPDOError it would report."""
    assert [f.name for f in dataclasses.fields(CanPacket)] == [
        "channel", "frame", "tsf", "timestamp", "scheduled", "offset_ns", "tag", "id_aux", "d64", "ctrl", "wire"]
    assert [f.name for f in dataclasses.fields(TxResultPacket) if not f.init] == ["ctrl", "wire"]
    p = CanPacket.of(2, 0x123, data=b"xy")
    assert p.frame == CanFrame(0x123, b"xy") and p == CanPacket(2, CanFrame(0x123, b"xy"))
    assert (p.ctrl, p.wire) == (0x12, std_packet(2, 0x123, b"xy"))
    assert TxResultPacket(5, 1, 2, TxResultCode.TX_FIFO_FULL).ctrl == 0x2005
    if not PACKETS_COMPILED:   # the ResultCode as a plain int: pure Python takes it (compiled: TypeError)
        assert TxResultPacket(5, 1, 2, 4) == TxResultPacket(5, 1, 2, TxResultCode.TX_FIFO_FULL)  # type: ignore[arg-type]
    ok = TxResultCode.OK
    for args, code in (((8, 0, 0, ok), PdoError.INVALID_CHANNEL), ((0, 0x10000, 0, ok), PdoError.UNKNOWN_KIND),
                       ((0, 0, 256, ok), PdoError.UNKNOWN_KIND), ((0, 0, 0, 6), PdoError.UNKNOWN_KIND)):
        with pytest.raises(MISTYPED) as err:
            TxResultPacket(*args)  # type: ignore[arg-type]
        assert not isinstance(err.value, StreamEncodeError) or err.value.pdo_error is code
    for bad, code in ((dict(channel=8), PdoError.INVALID_CHANNEL), (dict(data=bytes(9)), PdoError.INVALID_DLC),
                      (dict(tsf=4), PdoError.INVALID_TSF), (dict(can_id=0x800), PdoError.RESERVED_BIT),
                      (dict(tag=1), PdoError.BAD_SCHEDULE), (dict(can_id=1.0), PdoError.RESERVED_BIT)):
        kwargs: dict[str, object] = dict(channel=0, can_id=1) | bad
        with pytest.raises(MISTYPED) as info:
            CanPacket.of(**kwargs)  # type: ignore[arg-type]
        assert not isinstance(info.value, StreamEncodeError) or info.value.pdo_error is code
    for bad_packet, code in ((dict(frame=b"\1"), PdoError.INVALID_DLC), (dict(id_aux=8), PdoError.RESERVED_BIT),
                             (dict(d64=True), PdoError.INVALID_DLC)):
        fields: dict[str, object] = dict(channel=0, frame=CanFrame(1)) | bad_packet
        with pytest.raises(MISTYPED) as info:
            CanPacket(**fields)  # type: ignore[arg-type]
        assert not isinstance(info.value, StreamEncodeError) or info.value.pdo_error is code
