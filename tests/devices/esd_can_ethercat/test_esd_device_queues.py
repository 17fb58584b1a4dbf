"""The MDP 5000 counter-handshake queues on the in-process master (manual 5.1.5.1-5.1.5.6 and the shared
note 'esd-mdp5000-queues'): Tx and Rx batches, transaction numbers, 29-bit mode, queue sizes, filters,
local queue overflows."""

from __future__ import annotations

from typing import Any

import pytest

from gatewaylab.bus.frame import CanFrame
from gatewaylab.devices.esd_can_ethercat.codec import IN_HEADER, OUT_HEADER, encode_tx11
from gatewaylab.od import SdoAbort, SdoAbortCode


def _frames(n: int, base: int = 0x100, ext: bool = False) -> list[CanFrame]:
    return [CanFrame(base + i, bytes([i & 0xFF, (i >> 8) & 0xFF, 0xA5]), extended=ext) for i in range(n)]


def _drain(kit: Any, cycles: int = 50) -> None:
    kit.cycle(cycles)


def test_tx_batches_go_out_in_order_and_the_counter_is_acknowledged(kit: Any) -> None:
    """5.1.5.3 / Figure 27: the master writes messages + NumTx and increments its Tx counter; the
    gateway copies them into its local queue and sets the input Tx counter equal; frames go out in order."""
    kit.op()
    sent: list[CanFrame] = []
    for size in (5, 16, 1, 3):
        batch = _frames(size, base=0x100 + len(sent))
        cycles = kit.send(batch, first_tn=len(sent) + 1)
        assert cycles == 1          # acknowledged in the first cycle after the write
        sent += batch
    _drain(kit)
    assert kit.heard == sent
    assert kit.master.sdo_upload32(0, 0x2010, 0x30) == len(sent)   # Tx requested
    assert kit.master.sdo_upload32(0, 0x2010, 0x31) == len(sent)   # forwarded to the driver
    assert kit.master.sdo_upload32(0, 0x2010, 0x3C) == len(sent)   # driver: standard frames sent


def test_tx_transaction_number_is_that_of_the_last_frame_actually_sent(kit: Any) -> None:
    """5.1.5.1 'Tx Transaction Number: the transaction number of the last sent Tx message' (and the
    note: the frame on the bus, not the copy): right after the acknowledge of 16 frames (about 3.6 ms
    at 500 kbit/s) it lags behind, once the bus is done it is the last one's."""
    kit.op()
    batch = [CanFrame(0x200 + i, bytes(8)) for i in range(16)]
    kit.send(batch, first_tn=1000)
    tx, _rx, _n, tn = kit.inputs()
    assert tx == kit.tx_counter and tn < 1015
    _drain(kit, 10)
    assert kit.inputs()[3] == 1015
    kit.send(_frames(2), first_tn=7)
    _drain(kit, 5)
    assert kit.inputs()[3] == 8


def test_a_batch_is_taken_only_when_the_output_tx_counter_changes(kit: Any) -> None:
    """5.1.5.3: messages and NumTx written without a new Tx counter send nothing; the same counter
    again sends nothing twice."""
    kit.op()
    body = b"".join(encode_tx11(i, f) for i, f in enumerate(_frames(4)))
    kit.master.pdo_write(0, 0, OUT_HEADER.pack(0, 0, 4) + body)
    _drain(kit, 5)
    assert kit.heard == []
    kit.master.pdo_write(0, 0, OUT_HEADER.pack(1, 0, 4) + body)
    _drain(kit, 10)
    assert len(kit.heard) == 4
    _drain(kit, 10)
    assert len(kit.heard) == 4 and kit.inputs()[0] == 1


def test_rx_batches_wait_for_the_masters_acknowledge(kit: Any) -> None:
    """5.1.5.1 / Figure 25: the gateway writes up to the Rx queue size (16) frames, NumRx, increments
    its Rx counter, and changes nothing until the master sets its Rx counter equal."""
    kit.op()
    frames = _frames(40, base=0x300)
    for f in frames:
        kit.peer.send(f)
    _drain(kit, 15)                 # the bus carries all 40 meanwhile; the master does not acknowledge
    _tx, rx, num, _tn = kit.inputs()
    assert (rx, num) == (1, 1)      # the first frame found the counters equal
    before = kit.master.pdo_read(0, 0, kit.in_size)
    _drain(kit, 5)
    assert kit.master.pdo_read(0, 0, kit.in_size) == before
    batches = [kit.receive() for _ in range(5)]
    assert [len(b) for b in batches] == [1, 16, 16, 7, 0]
    assert [f for b in batches for f in b] == frames
    assert kit.master.sdo_upload32(0, 0x2010, 0x32) == 40     # CAN frames RX (copied to the Rx objects)
    assert kit.master.sdo_upload32(0, 0x2010, 0x38) == 40     # driver: standard frames received


def _raw_batch(kit: Any, size: int) -> bytes:
    """Wait for a new Rx batch, return its first message's raw bytes, acknowledge it."""
    for _ in range(10):
        kit.cycle()
        _tx, rx, _num, _tn = kit.inputs()
        if rx != kit.rx_counter:
            raw = kit.master.pdo_read(0, IN_HEADER.size, size)
            kit.rx_counter = rx
            kit.master.pdo_write(0, 2, rx.to_bytes(2, "little"))
            return bytes(raw)
    raise AssertionError("no Rx batch")


def test_rx_message_layouts_11_bit_with_rtr_and_length(kit: Any) -> None:
    """5.1.5.1 / Figure 24: bits 0-3 length, bit 4 RTR, bits 5-15 identifier, bits 16-79 data."""
    kit.op()
    kit.peer.send(CanFrame(0x7FF, b"\x01\x02\x03\x04\x05\x06\x07\x08"))
    assert _raw_batch(kit, 10) == (0x7FF << 5 | 8).to_bytes(2, "little") + bytes(range(1, 9))
    kit.peer.send(CanFrame(0x123, rtr=True, dlc=5))
    assert _raw_batch(kit, 10)[:2] == (0x123 << 5 | 0x10 | 5).to_bytes(2, "little")


def test_29_bit_mode_sizes_mapping_and_layouts(kit: Any) -> None:
    """4.2 + 5.1.5.5: 0x8000:20 bit 0 selects 29-bit queues (0x7001/0x6001, 128/112-bit entries):
    outputs 262 B, inputs 232 B; 5.1.5.2/5.1.5.4 layouts with RTR and the 29-bit flag."""
    m = kit.master
    kit.preop()
    m.sdo_download16(0, 0x8000, 0x20, 0x0001)
    assert m.sdo_upload8(0, 0x1600, 0) == 19
    assert [m.sdo_upload32(0, 0x1600, i) for i in (1, 4, 19)] == [0x70010110, 0x70010480, 0x70011380]
    assert [m.sdo_upload32(0, 0x1A00, i) for i in (1, 5, 20)] == [0x60010110, 0x60010570, 0x60011470]
    kit.op()
    assert (kit.out_size, kit.in_size) == (262, 232)
    out = [CanFrame(0x18FF1234, b"\x11\x22", extended=True), CanFrame(0x0AB, b"\x33"),
           CanFrame(0x1ABCDEF0, extended=True, rtr=True, dlc=3)]
    kit.send(out, first_tn=40)
    _drain(kit, 5)
    assert kit.heard == out and kit.inputs()[3] == 42
    incoming = [CanFrame(0x1FFFFFFF, b"\x99" * 8, extended=True), CanFrame(0x555, b"\x01"),
                CanFrame(0x00000001, extended=True, rtr=True, dlc=8)]
    for f in incoming:
        kit.peer.send(f)
    assert kit.receive_all() == incoming
    kit.peer.send(CanFrame(0x1FFFFFFF, b"\x99" * 8, extended=True))
    assert _raw_batch(kit, 14) == bytes.fromhex("0800ffffff9f") + b"\x99" * 8   # bit 47 = 29-bit flag
    kit.peer.send(CanFrame(0x123, rtr=True, dlc=2, extended=True))
    assert _raw_batch(kit, 14)[:6] == bytes.fromhex("0200230100c0")          # + bit 46 = RTR
    kit.peer.send(CanFrame(0x123, b"x"))
    assert _raw_batch(kit, 14)[:7] == bytes.fromhex("01002301000078")        # an 11-bit frame: flag clear


def test_29_bit_tx_message_with_an_11_bit_id_out_of_range_is_aborted(kit: Any) -> None:
    """5.1.5.4: bit 63 clear means an 11-bit identifier; 0x800 cannot be one: nothing is sent, the
    frame counts as aborted (0x2010:37), the rest of the batch goes out."""
    m = kit.master
    kit.preop()
    m.sdo_download16(0, 0x8000, 0x20, 1)
    kit.op()
    bad = (1).to_bytes(2, "little") + (1).to_bytes(2, "little") + (0x800).to_bytes(4, "little") + bytes(8)
    good = (2).to_bytes(2, "little") + (1).to_bytes(2, "little") + (0x7FF).to_bytes(4, "little") + bytes(8)
    kit.master.pdo_write(0, 0, OUT_HEADER.pack(1, 0, 2) + bad + good)
    _drain(kit, 5)
    assert kit.heard == [CanFrame(0x7FF, b"\0")]
    assert m.sdo_upload32(0, 0x2010, 0x37) == 1


def test_queue_sizes_resize_mapping_and_image_in_preop_only(kit: Any) -> None:
    """5.1.5.5 'Rx/Tx queue size' (1 .. what SM and mapping allow): the mapping a master reads
    afterwards has the new sizes (4.2); writable in PREOP only (0x08000022)."""
    m = kit.master
    kit.preop()
    m.sdo_download8(0, 0x8000, 0x21, 4)
    m.sdo_download8(0, 0x8000, 0x22, 8)
    assert (m.sdo_upload8(0, 0x1A00, 0), m.sdo_upload8(0, 0x1600, 0)) == (8, 11)
    assert m.sdo_upload8(0, 0x6000, 0) == 8 and m.sdo_upload8(0, 0x7000, 0) == 11
    with pytest.raises(SdoAbort) as err:
        m.sdo_upload(0, 0x6000, 9)
    assert err.value.code == SdoAbortCode.SUBINDEX_DOES_NOT_EXIST
    for sub, value, code in ((0x21, 0, SdoAbortCode.VALUE_TOO_LOW), (0x22, 200, SdoAbortCode.VALUE_TOO_HIGH)):
        with pytest.raises(SdoAbort) as err:
            m.sdo_download8(0, 0x8000, sub, value)
        assert err.value.code == code
    kit.op()
    assert (kit.out_size, kit.in_size) == (6 + 8 * 12, 8 + 4 * 10)
    for f in _frames(10, base=0x400):
        kit.peer.send(f)
    kit.cycle(10)
    batches = [kit.receive(), kit.receive(), kit.receive(), kit.receive()]
    assert [len(b) for b in batches] == [1, 4, 4, 1]
    with pytest.raises(SdoAbort) as err:
        m.sdo_download8(0, 0x8000, 0x21, 5)
    assert err.value.code == SdoAbortCode.DATA_CANNOT_BE_STORED_DEVICE_STATE


def test_largest_queues_fit_the_sync_managers(kit: Any) -> None:
    """5.1.5.5 '* Also limited by SM size/configuration': the largest accepted sizes map and run."""
    m = kit.master
    kit.preop()
    m.sdo_download8(0, 0x8000, 0x22, 148)
    m.sdo_download8(0, 0x8000, 0x21, 203)
    with pytest.raises(SdoAbort):
        m.sdo_download16(0, 0x8000, 0x20, 1)   # 29-bit would not fit these sizes
    kit.op()
    assert (kit.out_size, kit.in_size) == (6 + 148 * 12, 8 + 203 * 10)
    batch = _frames(148, base=0x10)
    kit.send(batch)
    kit.cycle(60)
    assert kit.heard == batch


def test_filter_areas_pass_only_their_identifiers(kit: Any) -> None:
    """5.1.5.6: bytes 0-3 first, 4-7 last identifier; bits 31 and 63 for 29-bit areas; not configured
    (subindex 0 = 0): every frame passes."""
    m = kit.master
    kit.preop()
    m.sdo_download64(0, 0x8001, 1, 0x100 | 0x1FF << 32)
    m.sdo_download64(0, 0x8001, 2, (0x18FF0000 | 0x80000000) | (0x18FFFFFF | 0x80000000) << 32)
    m.sdo_download64(0, 0x8001, 3, 0x7FF | 0x7FF << 32)
    m.sdo_download8(0, 0x8001, 0, 3)
    m.sdo_download16(0, 0x8000, 0x20, 1)
    kit.op()
    frames = [CanFrame(0x0FF, b"a"), CanFrame(0x100, b"b"), CanFrame(0x1FF, b"c"), CanFrame(0x200, b"d"),
              CanFrame(0x7FF, b"e"), CanFrame(0x18FF0000, b"f", extended=True),
              CanFrame(0x18FEFFFF, b"g", extended=True), CanFrame(0x100, b"h", extended=True)]
    for f in frames:
        kit.peer.send(f)
    assert kit.receive_all() == [frames[i] for i in (1, 2, 4, 5)]
    assert m.sdo_upload32(0, 0x2010, 0x38) == 5 and m.sdo_upload32(0, 0x2010, 0x3A) == 3


def test_unconfigured_filter_passes_everything_and_bad_areas_are_refused(kit: Any) -> None:
    """5.1.5.6 'In case this object is not configured, all received CAN messages' pass; an area with
    bit 31 but not bit 63, first > last, or an 11-bit id above 0x7FF is refused."""
    m = kit.master
    kit.preop()
    for value, code in ((0x80000001 | 0x00000002 << 32, SdoAbortCode.VALUE_RANGE_EXCEEDED),
                        (0x200 | 0x100 << 32, SdoAbortCode.MAX_LESS_THAN_MIN),
                        (0x100 | 0x800 << 32, SdoAbortCode.VALUE_RANGE_EXCEEDED)):
        with pytest.raises(SdoAbort) as err:
            m.sdo_download64(0, 0x8001, 1, value)
        assert err.value.code == code
    m.sdo_download16(0, 0x8000, 0x20, 1)
    kit.op()
    frames = [CanFrame(0x001, b"1"), CanFrame(0x1FFFFFFF, b"2", extended=True)]
    for f in frames:
        kit.peer.send(f)
    assert kit.receive_all() == frames


def test_11_bit_queues_do_not_carry_29_bit_frames(kit: Any) -> None:
    """5.1.1 / 5.1.5.1: the 11-bit Rx message has room for an 11-bit identifier only; 29-bit frames
    are counted by the driver (0x2010:3A) but not queued."""
    kit.op()
    kit.peer.send(CanFrame(0x18FF0000, b"x", extended=True))
    kit.peer.send(CanFrame(0x123, b"y"))
    assert kit.receive_all() == [CanFrame(0x123, b"y")]
    assert kit.master.sdo_upload32(0, 0x2010, 0x3A) == 1


def test_local_rx_queue_overflow_is_counted_never_silent(kit: Any) -> None:
    """5.1.5.5 'Local Rx queue size' (here 5) full: 0x2010:35 'CANDriver FIFO overrun' counts every
    lost frame and 0xF108:03 'Rx overflow' is set."""
    m = kit.master
    kit.preop()
    m.sdo_download16(0, 0x8000, 0x23, 5)
    kit.op()
    for f in _frames(20):
        kit.peer.send(f)
    kit.cycle(20)                                   # the master does not acknowledge meanwhile
    assert m.sdo_upload32(0, 0x2010, 0x35) == 14    # 1 in the image, 5 waiting, 14 lost
    assert m.sdo_upload8(0, 0xF108, 3) == 1
    assert len(kit.receive_all()) == 6


def test_full_local_tx_queue_holds_the_acknowledge_back(kit: Any) -> None:
    """5.1.5.3 'copies the messages into its local CAN send queue, then sets the input Tx counter
    equal': with a local Tx queue of 4 the second batch is acknowledged only once it has room."""
    m = kit.master
    kit.preop()
    m.sdo_download16(0, 0x8000, 0x24, 4)
    kit.op()
    first, second = _frames(4, base=0x10), _frames(4, base=0x20)
    kit.write_batch(first)
    kit.master.exchange_process_data()              # taken at once (no time passes in between)
    kit.write_batch(second, first_tn=5)
    kit.master.exchange_process_data()
    kit.master.exchange_process_data()
    assert kit.inputs()[0] == 1 != kit.tx_counter   # not yet: the queue is full
    kit.cycle(10)
    assert kit.inputs()[0] == kit.tx_counter
    kit.cycle(5)
    assert kit.heard == first + second and m.sdo_upload32(0, 0x2010, 0x37) == 0


def test_num_tx_above_the_queue_size_is_limited_to_it(kit: Any) -> None:
    """5.1.5.3 'N = 1 ... m-3': a NumTx larger than the Tx queue sends the queue's 16 messages."""
    kit.op()
    body = b"".join(encode_tx11(i, f) for i, f in enumerate(_frames(16)))
    kit.master.pdo_write(0, 0, OUT_HEADER.pack(1, 0, 999) + body)
    kit.cycle(10)
    assert kit.heard == _frames(16) and kit.master.sdo_upload32(0, 0x2010, 0x30) == 16


def test_coe_read_of_the_tx_queue_objects_shows_the_outputs(kit: Any) -> None:
    """5.1.5.3: 0x7000:01-03 and the Tx messages are the mapped outputs: an SDO upload in OP returns
    what the master wrote in the last cycle (decoded from the image, not stored every cycle)."""
    kit.op()
    kit.send([CanFrame(0x321, b"\x01\x02")], first_tn=77)
    m = kit.master
    assert [m.sdo_upload16(0, 0x7000, s) for s in (1, 2, 3)] == [1, 0, 1]
    assert m.sdo_upload(0, 0x7000, 4) == encode_tx11(77, CanFrame(0x321, b"\x01\x02"))
