"""The esd host library's sans-I/O parts on synthetic process images: the counter handshake
(manual 5.1.5.1-5.1.5.4, shared note 'esd-mdp5000-queues'), the 0x8001 filter areas (5.1.5.6),
the 0xF800 values (5.1.5.9) and the queue layout (5.1.3.7-5.1.3.9). The images are built and read
with the device's codec, the one codec of these bytes."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.errors import ConfigError, FrameError, LocalError
from gatewaylab.devices.esd_can_ethercat.codec import (
    IN_HEADER,
    OUT_HEADER,
    CanStatus,
    decode_tx11,
    decode_tx29,
    encode_rx11,
    encode_rx29,
    input_size,
    output_size,
)
from gatewaylab.hosts.esd_can_ethercat import (
    BitRate,
    FilterArea,
    Handshake,
    QueueLayout,
    TxQueueFull,
    api_numerical,
    api_register,
    api_table,
    for_bitrate,
)


def layout(extended: bool = False, tx: int = 16, rx: int = 16, status: bool = False) -> QueueLayout:
    return QueueLayout(extended, tx, rx, status, output_size(extended, tx), input_size(extended, rx) + 6 * status)


def inputs(lay: QueueLayout, tx: int, rx: int, tn: int, frames: list[CanFrame] = (), status: bytes = b"") -> bytes:  # type: ignore[assignment]
    """An input image as the gateway writes it (5.1.5.1/5.1.5.2)."""
    encode = encode_rx29 if lay.extended else encode_rx11
    img = bytearray(lay.input_bytes)
    IN_HEADER.pack_into(img, 0, tx, rx, len(frames), tn)
    body = b"".join(encode(f) for f in frames)
    img[IN_HEADER.size:IN_HEADER.size + len(body)] = body
    if status:
        off = lay.status_offset
        assert off is not None
        img[off:off + 6] = status
    return bytes(img)


def batch_of(lay: QueueLayout, out: bytearray) -> tuple[tuple[int, int, int], list[tuple[int, CanFrame]]]:
    """The outputs header and Tx messages as the gateway decodes them (5.1.5.3/5.1.5.4)."""
    header = OUT_HEADER.unpack_from(out, 0)
    size = 16 if lay.extended else 12
    decode = decode_tx29 if lay.extended else decode_tx11
    msgs = [decode(out, OUT_HEADER.size + i * size) for i in range(header[2])]
    return header, [(m.transaction, m.frame) for m in msgs]


def test_tx_batches_wait_for_the_tx_counter() -> None:
    """Note 'Sending' 1-3: the master writes only when output Tx counter == input Tx counter, fills
    the messages, sets NumTx and increments its counter; up to the Tx queue size per batch."""
    lay = layout()
    hs = Handshake(lay)
    out = bytearray(lay.output_bytes)
    frames = [CanFrame(0x100 + i, bytes([i])) for i in range(40)]
    assert hs.submit(frames) == list(range(1, 41))
    assert not hs.write_outputs(out)                      # no inputs seen yet: the gateway's counter is unknown
    hs.read_inputs(inputs(lay, 0, 0, 0), 0.0)
    assert hs.write_outputs(out)
    header, msgs = batch_of(lay, out)
    assert header == (1, 0, 16) and msgs == [(i + 1, f) for i, f in enumerate(frames[:16])]
    assert not hs.write_outputs(out) and batch_of(lay, out)[0] == (1, 0, 16)   # unchanged until acknowledged
    hs.read_inputs(inputs(lay, 0, 0, 0), 0.001)                                # not yet copied
    assert not hs.accepted(1) and not hs.write_outputs(out)
    hs.read_inputs(inputs(lay, 1, 0, 0), 0.002)                                # 'Tx messages copied'
    assert hs.accepted(16) and not hs.accepted(17) and not hs.completed(1)
    assert hs.write_outputs(out)
    assert batch_of(lay, out) == ((2, 0, 16), [(i + 17, f) for i, f in enumerate(frames[16:32])])
    hs.read_inputs(inputs(lay, 2, 0, 16), 0.003)
    assert hs.write_outputs(out)
    assert batch_of(lay, out) == ((3, 0, 8), [(i + 33, f) for i, f in enumerate(frames[32:])])
    assert hs.tx_batches == 3 and hs.pending == 0


def test_transaction_number_completes_in_order() -> None:
    """5.1.5.1 'Tx Transaction Number: ... the last sent Tx': reporting frame 5 completes 1..5;
    0 (after PREOP -> SAFEOP) and numbers not in flight complete nothing."""
    lay = layout()
    hs = Handshake(lay)
    out = bytearray(lay.output_bytes)
    tns = hs.submit([CanFrame(0x200 + i) for i in range(8)])
    hs.read_inputs(inputs(lay, 0, 0, 0), 0.0)
    hs.write_outputs(out)
    hs.read_inputs(inputs(lay, 1, 0, 0), 0.0)
    assert [hs.completed(t) for t in tns] == [False] * 8
    hs.read_inputs(inputs(lay, 1, 0, 5), 0.0)
    assert [hs.completed(t) for t in tns] == [True] * 5 + [False] * 3
    hs.read_inputs(inputs(lay, 1, 0, 999), 0.0)
    assert not hs.completed(6)
    hs.read_inputs(inputs(lay, 1, 0, 8), 0.0)
    assert all(hs.completed(t) for t in tns) and hs.in_flight == 0
    with pytest.raises(LocalError):
        hs.completed(9)


def test_transaction_numbers_wrap_past_ffff_without_zero() -> None:
    """5.1.5.3 'Bit 0-15: Transaction Number': u16; after FFFFh the next is 1 (0 is the input's value
    before anything was sent, so it is never handed out)."""
    lay = layout(tx=148)
    hs = Handshake(lay)
    out = bytearray(lay.output_bytes)
    counter = 0
    hs.read_inputs(inputs(lay, 0, 0, 0), 0.0)
    seen: list[int] = []
    while len(seen) < 0x10000 + 10:
        tns = hs.submit([CanFrame(0x7FF)] * 148)
        seen += tns
        hs.write_outputs(out)
        counter += 1
        hs.read_inputs(inputs(lay, counter & 0xFFFF, 0, tns[-1]), 0.0)
        assert hs.completed(tns[0]) and hs.completed(tns[-1])
    assert 0 not in seen
    assert seen[0xFFFE] == 0xFFFF and seen[0xFFFF] == 1
    assert batch_of(lay, out)[1][0][0] == seen[-148]


def test_rx_batches_are_read_stamped_and_acknowledged() -> None:
    """Note 'Receiving' 1-3: a new input Rx counter brings NumRx messages; the master reads them and
    sets its Rx counter equal; the same image seen again is not read twice."""
    lay = layout()
    hs = Handshake(lay)
    out = bytearray(lay.output_bytes)
    frames = [CanFrame(0x300, b"a"), CanFrame(0x301, b"", rtr=True, dlc=4), CanFrame(0x302, bytes(8))]
    img = inputs(lay, 0, 1, 0, frames)
    hs.read_inputs(img, 0.25)
    hs.read_inputs(img, 0.26)
    got = hs.take_received()
    assert [r.frame for r in got] == frames and {r.timestamp for r in got} == {0.25} and {r.batch for r in got} == {1}
    hs.write_outputs(out)
    assert OUT_HEADER.unpack_from(out, 0)[1] == 1
    hs.read_inputs(inputs(lay, 0, 2, 0, frames[:1]), 0.3)
    assert [r.frame for r in hs.take_received()] == frames[:1] and hs.rx_batches == 2


def test_rx_acknowledgement_waits_for_buffer_room() -> None:
    """Note 'Receiving' 2: the gateway keeps a batch until it is acknowledged, so a full host buffer
    defers the acknowledgement instead of dropping frames."""
    lay = layout(rx=3)
    hs = Handshake(lay, rx_limit=4)
    out = bytearray(lay.output_bytes)
    first = [CanFrame(0x10 + i) for i in range(3)]
    second = [CanFrame(0x20 + i) for i in range(3)]
    hs.read_inputs(inputs(lay, 0, 1, 0, first), 0.0)
    hs.read_inputs(inputs(lay, 0, 2, 0, second), 0.1)
    hs.write_outputs(out)
    assert hs.rx_deferred == 1 and OUT_HEADER.unpack_from(out, 0)[1] == 1
    assert [r.frame for r in hs.take_received()] == first
    hs.read_inputs(inputs(lay, 0, 2, 0, second), 0.2)
    hs.write_outputs(out)
    assert [r.frame for r in hs.take_received()] == second and OUT_HEADER.unpack_from(out, 0)[1] == 2
    with pytest.raises(LocalError):
        Handshake(lay, rx_limit=2)


def test_29bit_queues_carry_both_identifier_kinds() -> None:
    """5.1.5.2/5.1.5.4: in 29-bit mode extended and standard frames travel (bit 47/63); the 11-bit
    queues cannot carry a 29-bit identifier (a FrameError before anything is queued)."""
    lay29 = layout(extended=True, tx=4, rx=4)
    hs = Handshake(lay29)
    out = bytearray(lay29.output_bytes)
    frames = [CanFrame(0x1FFFFFFF, b"x", extended=True), CanFrame(0x7FF, b"y"),
              CanFrame(0x12345, b"", extended=True, rtr=True, dlc=8)]
    hs.submit(frames)
    hs.read_inputs(inputs(lay29, 0, 1, 0, frames), 0.0)
    hs.write_outputs(out)
    assert [f for _tn, f in batch_of(lay29, out)[1]] == frames
    assert [r.frame for r in hs.take_received()] == frames
    hs11 = Handshake(layout())
    with pytest.raises(FrameError):
        hs11.submit([CanFrame(0x100), CanFrame(0x100, extended=True)])
    assert hs11.pending == 0
    with pytest.raises(FrameError):
        hs11.submit([CanFrame(0x100, bytes(16), fd=True)])


def test_tx_limit_raises_with_the_count() -> None:
    """Frames kept by the host are bounded: TxQueueFull carries how many are queued or in flight."""
    hs = Handshake(layout(), tx_limit=10)
    hs.submit([CanFrame(1)] * 8)
    with pytest.raises(TxQueueFull) as exc:
        hs.submit([CanFrame(2)] * 3)
    assert exc.value.pending == 8 and hs.pending == 8


def test_status_pdo_overflow_reported_once_per_rise() -> None:
    """5.1.3.9 / 5.1.5.8: the 0x1A85 bytes after 0x1A00 decode to CanStatus; a rising 'Rx overflow'
    bit is reported once."""
    lay = layout(status=True)
    hs = Handshake(lay)
    hs.read_inputs(inputs(lay, 0, 0, 0, status=bytes([0b011, 0, 0, 0, 7, 255])), 0.0)
    assert hs.status == CanStatus(True, True, False, 7, 255) and not hs.overflow_reported()
    over = bytes([0b100, 0, 0, 0, 0, 0])
    hs.read_inputs(inputs(lay, 0, 0, 0, status=over), 0.0)
    hs.read_inputs(inputs(lay, 0, 0, 0, status=over), 0.0)
    assert hs.overflow_reported() and not hs.overflow_reported()
    hs.read_inputs(inputs(lay, 0, 0, 0), 0.0)
    hs.read_inputs(inputs(lay, 0, 0, 0, status=over), 0.0)
    assert hs.overflow_reported()


@settings(max_examples=300, deadline=None)
@given(raw=st.binary(max_size=300), extended=st.booleans(), rx=st.integers(1, 20), status=st.booleans())
def test_any_input_image_is_taken_without_error(raw: bytes, extended: bool, rx: int, status: bool) -> None:
    """Hypothesis: whatever bytes the inputs hold (counters, NumRx beyond the queue, short images),
    reading them raises nothing, takes at most the Rx queue size per batch and acknowledges only
    the counter it read."""
    lay = layout(extended, 4, rx, status)
    hs = Handshake(lay)
    out = bytearray(lay.output_bytes)
    hs.submit([CanFrame(0x100)] * 5)
    hs.read_inputs(raw, 0.0)
    hs.write_outputs(out)
    assert hs.buffered <= rx
    if len(raw) >= IN_HEADER.size:
        assert OUT_HEADER.unpack_from(out, 0)[1] in (0, IN_HEADER.unpack_from(raw, 0)[1])


def test_filter_area_values() -> None:
    """5.1.5.6: 'Byte 0-3: First identifier, Byte 4-7: Last identifier'; 'For 29-Bit CAN identifiers
    bit 31 and 63 must be set!'"""
    assert FilterArea(0x100, 0x1FF).value == 0x000001FF_00000100
    ext = FilterArea(0x1000000, 0x1000010, extended=True)
    assert ext.value == 0x81000010_81000000
    assert FilterArea.from_value(ext.value) == ext
    for bad in ((0x200, 0x100, False), (0, 0x800, False), (0, 0x20000000, True)):
        with pytest.raises(ConfigError):
            FilterArea(*bad)


def test_bit_rate_values() -> None:
    """5.1.5.9 Tables 6-10: Table 6 index for the rates it has (4.2.1), Table 9 index with LOM,
    UBRN numerical and UBR register values."""
    assert for_bitrate(500_000) == BitRate(2, BitRate().api)
    assert for_bitrate(800_000) == BitRate.table6(1)
    assert for_bitrate(500_000, listen_only=True) == BitRate.api_value(0x40000002)
    assert for_bitrate(666_666) == BitRate.api_value(0x1)
    assert for_bitrate(83_333) == BitRate.api_value(0x10)
    assert for_bitrate(200_000) == BitRate.api_value(0x20000000 | 200_000)
    assert api_table(0xE) == 0xE and api_numerical(1_000_000, True) == 0x600F4240
    assert api_register(0xB0763, listen_only=True) == 0xC00B0763
    assert BitRate.no_baudrate().api == 0x7FFFFFFF and BitRate.autobaud().api == 0x00FFFFFE
    with pytest.raises(ConfigError):
        api_numerical(0x1000000)


def test_layout_sizes() -> None:
    """5.1.3.7/5.1.3.8/5.1.3.9: 6 + T x 12 (16) out, 8 + R x 10 (14) in, + 6 with 0x1A85 right after."""
    lay = layout(status=True)
    assert (lay.output_bytes, lay.input_bytes, lay.status_offset) == (198, 174, 168) and lay.consistent()
    assert layout(extended=True).input_bytes == 232 and layout().status_offset is None
    assert not QueueLayout(False, 16, 16, False, 198, 170).consistent()


def test_rx29_message_without_a_frame_is_counted_and_skipped() -> None:
    """5.1.5.2 'Bit 47: 0 = 11-bit CAN identifier': such a message with an identifier above 0x7FF
    carries no CAN frame; the host counts it, keeps the batch's other frames and acknowledges."""
    lay = layout(extended=True, rx=4)
    hs = Handshake(lay)
    img = bytearray(inputs(lay, 0, 1, 0, [CanFrame(0x100, b"a"), CanFrame(0x101, b"b")]))
    img[IN_HEADER.size + 2:IN_HEADER.size + 6] = (0x800).to_bytes(4, "little")   # first message: id 0x800, 11-bit
    hs.read_inputs(bytes(img), 0.0)
    assert [r.frame for r in hs.take_received()] == [CanFrame(0x101, b"b")] and hs.rx_invalid == 1
    assert hs.out_rx == 1
