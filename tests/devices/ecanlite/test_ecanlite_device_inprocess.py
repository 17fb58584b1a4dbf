"""The ECAN-Lite device driven by the in-process master on a simulated clock (manual 5, 6-12, 13.2, 14)."""

from __future__ import annotations

import struct
from pathlib import Path

import can
import pytest
from ecanlite_device_kit import CYCLE, Rig, bring_up, make_rig

from gatewaylab.bus import python_can_bus
from gatewaylab.devices.ecanlite.image import SM_SIZE
from gatewaylab.devices.ecanlite.stream import (
    CanPacket,
    Direction,
    HeaderFlags,
    PdoError,
    ProfileStatus,
    StreamLayout,
    Tsf,
    TxResultCode,
    TxResultPacket,
    crc16,
    decode_stream,
    encode_stream,
)
from gatewaylab.ethercat.errors import AlStatusCode, AlStatusError
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.esi import export_esi


def rx_layout(n: int = 8, mask: int = 0x0F, options: int = 0, profile: int = 0) -> StreamLayout:
    return StreamLayout(multiplier=n, channel_mask=mask, options=options, profile=profile, direction=Direction.RX)


def tx_layout(n: int = 8, mask: int = 0x0F, options: int = 0, profile: int = 0) -> StreamLayout:
    return StreamLayout(multiplier=n, channel_mask=mask, options=options, profile=profile, direction=Direction.TX)


def publish(rig: Rig, image: bytes, cycles: int = 1) -> None:
    """Write one RxPDO image and run cycles (the bus gets time to transmit)."""
    rig.master.pdo_write(0, 0, image)
    rig.cycle(cycles)


def read_tx(rig: Rig, layout: StreamLayout) -> list[CanPacket | TxResultPacket]:
    """One cycle, then the TxPDO the master read in it, decoded."""
    rig.master.exchange_process_data()
    rig.clock.advance(CYCLE)
    return list(decode_stream(_inputs(rig, layout), layout).packets)


def _inputs(rig: Rig, layout: StreamLayout) -> bytes:
    return rig.master.pdo_read(0, 0, layout.pdo_bytes)


def test_sii_and_esi_keep_the_large_single_buffer_layout(rig: Rig) -> None:
    """5.3 / 15.7: SM2 0x1100, 3072 B, control byte 0x66; SM3 0x1D00, 3072 B, 0x22; the ESI says the
    same, and its 48 chunk maps carry 8 STRING(16) units each (5.1)."""
    sms = rig.master.slaves[0].sii.sync_managers
    assert [sm[:3] for sm in sms[2:4]] == [(0x1100, SM_SIZE, 0x66), (0x1D00, SM_SIZE, 0x22)]
    assert SM_SIZE == 3072
    esi = export_esi(rig.device.slave.desc, rig.device.slave.od)
    assert 'StartAddress="#x1100"' in esi and 'ControlByte="#x66"' in esi and 'DefaultSize="3072"' in esi
    assert "STRING(16)" in esi
    rig.master.set_state(AlState.PREOP)
    assert rig.master.sdo_upload_str(0, 0x1008) == "ECAN-Lite"


def test_a_master_that_configures_nothing_reaches_op_with_1024_bytes(rig: Rig) -> None:
    """5.1 / 9.2: at power-on the default profile (N 8, mask 0x0F, profile 0, Balanced, options 0) is
    active and 0x1C12/0x1C13 assign 8 chunks: a plain bring-up maps 1024 B each way and runs."""
    m = rig.master
    m.set_state(AlState.PREOP)
    assert m.config_map() == 2 * 1024
    assert m.sdo_upload32(0, 0x8010, 12) == 0x000001E7 and m.sdo_upload32(0, 0x8011, 12) == 0x000001E7
    m.set_state(AlState.SAFEOP)
    m.exchange_process_data()
    m.set_state(AlState.OP)
    assert rig.cycle(5) == m.expected_wkc
    header = decode_stream(_inputs(rig, tx_layout()), tx_layout()).header
    assert header.ver_ihl == 0x16 and header.layout_id == 0x01E7 and header.crc_alg == 1


def test_chunk_maps_follow_the_5_1_1_formula(rig: Rig) -> None:
    """5.1.1: chunk c unit u maps 0x7000 + c*0x80 + u*0x10 (RxPDO) / 0x6000 + ... (TxPDO), 16 B each."""
    m = rig.master
    m.set_state(AlState.PREOP)
    for c in (0, 1, 23):
        assert m.sdo_upload8(0, 0x1600 + c, 0) == 8
        for u in range(8):
            assert m.sdo_upload32(0, 0x1600 + c, u + 1) == (0x7000 + c * 0x80 + u * 0x10) << 16 | 0x0180
            assert m.sdo_upload32(0, 0x1A00 + c, u + 1) == (0x6000 + c * 0x80 + u * 0x10) << 16 | 0x0180


@pytest.mark.parametrize("n", [1, 3, 8, 24])
def test_bring_up_5_4_3_and_the_5_4_4_1_frame(tmp_path: Path, n: int) -> None:
    """5.4.3 phases A-F with N chunks and 5.4.4.1 step by step: the frame `40 00 23 01 11 22 33 44 55 66
    77 88` at RxPDO offset 24 goes out on CAN0 as 0x123 / 11 22 33 44 55 66 77 88; the master's image
    is 128 * N each way and every cycle gets the full working counter."""
    rig = make_rig(tmp_path)
    m = rig.master
    m.set_state(AlState.PREOP)
    # phase A: capabilities
    assert m.sdo_upload8(0, 0xF000, 2) >= 4
    assert m.sdo_upload8(0, 0xF000, 10) <= n <= m.sdo_upload8(0, 0xF000, 11)
    assert m.sdo_upload32(0, 0xF000, 12) & 1
    assert m.sdo_upload16(0, 0xF000, 17) == 128 and m.sdo_upload16(0, 0xF000, 18) == 24
    bring_up(rig, n=n)
    # phase D readback
    word = (n - 1) | 0x0F << 5
    for index in (0x8010, 0x8011):
        assert m.sdo_upload16(0, index, 9) == 128 * n
        assert m.sdo_upload16(0, index, 10) == 128 * n - 24
        assert m.sdo_upload32(0, index, 12) == word
    assert [s.output_bytes for s in m.slaves] == [128 * n] and [s.input_bytes for s in m.slaves] == [128 * n]
    client = python_can_bus(rig.buses[0])
    try:
        # 5.4.4.1 steps 1-4, written by hand
        image = bytearray(128 * n)
        image[24:36] = bytes.fromhex("40 00 23 01 11 22 33 44 55 66 77 88")
        layout_word = (n - 1) & 0x1F | (0x0F << 5)
        layout_id = (layout_word ^ (layout_word >> 16)) & 0xFFFF
        struct.pack_into("<BBHHHHHBBBB", image, 0, 0x16, 0, 1, 0, 12, crc16(image[24:36]), layout_id, 0x0F, 1, 0, 1)
        struct.pack_into("<H", image, 4, 1)  # seq_end last
        publish(rig, bytes(image), cycles=3)
        msg = client.recv(0)
        assert msg is not None and msg.arbitration_id == 0x123 and not msg.is_extended_id
        assert bytes(msg.data) == bytes.fromhex("11 22 33 44 55 66 77 88") and not msg.is_fd
        assert client.recv(0) is None  # the same image again is a no-op (13.8)
        assert rig.cycle(1) == m.expected_wkc
        assert m.sdo_upload16(0, 0x8011, 14) == 0 and m.sdo_upload32(0, 0x8011, 15) == 0
        assert m.sdo_upload16(0, 0x8011, 13) == 1
    finally:
        client.shutdown()


def test_frames_both_directions_on_all_four_channels_classic_and_fd(rig: Rig) -> None:
    """Chapters 6, 8: RxPDO CAN_FRAMEs of every channel (standard, extended, CAN FD with BRS) reach
    their bus; frames a bus delivers come back in the TxPDO with their channel, id and data."""
    bring_up(rig, n=8)
    clients = [python_can_bus(b) for b in rig.buses]
    try:
        packets = []
        for ch in range(4):
            packets.append(CanPacket.of(ch, 0x100 + ch, data=bytes([ch]) * 8))
            packets.append(CanPacket.of(ch, 0x1000000 + ch, extended=True, fd=True, brs=True, data=bytes(range(64))))
        publish(rig, encode_stream(rx_layout(), 7, packets), cycles=5)
        for ch, c in enumerate(clients):
            a, b = c.recv(0), c.recv(0)
            assert a is not None and b is not None
            assert (a.arbitration_id, bytes(a.data), a.is_fd) == (0x100 + ch, bytes([ch]) * 8, False)
            assert (b.arbitration_id, b.is_extended_id, b.is_fd, b.bitrate_switch, bytes(b.data)) == (
                0x1000000 + ch, True, True, True, bytes(range(64)))
        for ch, c in enumerate(clients):
            c.send(can.Message(arbitration_id=0x200 + ch, data=bytes([0xA0 + ch]) * 3, is_extended_id=False))
            c.send(can.Message(arbitration_id=0x1FFFFFF0 + ch, is_extended_id=True, is_fd=True, bitrate_switch=True,
                               data=bytes(range(20))))
        rig.clock.advance(0.002)
        got: list[CanPacket] = []
        for _ in range(3):
            got += [p for p in read_tx(rig, tx_layout()) if isinstance(p, CanPacket)]
        seen = {(p.channel, p.can_id, p.extended, p.fd, p.brs, p.data) for p in got}
        for ch in range(4):
            assert (ch, 0x200 + ch, False, False, False, bytes([0xA0 + ch]) * 3) in seen
            assert (ch, 0x1FFFFFF0 + ch, True, True, True, bytes(range(20)).ljust(20, b"\0")) in seen
        assert len(got) == 8
    finally:
        for c in clients:
            c.shutdown()


def test_tx_result_reports_each_rxpdo_frame(rig: Rig) -> None:
    """Chapter 10 / 9.1 bit0 on 0x8010: the TxPDO carries a TX_RESULT per RxPDO frame with
    RefPacketSeq = the committed RxPDO sequence and RefFrameIndex = its CAN_FRAME index."""
    bring_up(rig, n=3, tx_options=0x01)
    peers = [python_can_bus(rig.buses[ch]) for ch in (0, 2)]  # someone must acknowledge the frames
    publish(rig, encode_stream(rx_layout(3), 41,
                               [CanPacket.of(0, 0x10, data=b"\1"), CanPacket.of(2, 0x20, data=b"\2")]))
    results: list[TxResultPacket] = []
    for _ in range(4):
        results += [p for p in read_tx(rig, tx_layout(3, options=1)) if isinstance(p, TxResultPacket)]
    for p in peers:
        p.shutdown()
    assert {(r.channel, r.ref_packet_seq, r.ref_frame_index) for r in results} == {(0, 41, 0), (2, 41, 1)}
    assert all(r.result in (TxResultCode.OK, TxResultCode.QUEUED) for r in results)


def test_align4_both_directions(rig: Rig) -> None:
    """8.3.1: with ALIGN_4_ENABLE in 0x8010/0x8011:07 the profile word carries option bit1 and packets
    are padded to 4 bytes in both directions (an extended DLC 8 frame takes 16 B)."""
    bring_up(rig, n=3, tx_options=0x02, rx_options=0x02)
    assert rig.master.sdo_upload32(0, 0x8011, 12) == 2 | 0x0F << 5 | 0x02 << 21
    client = python_can_bus(rig.buses[1])
    try:
        frame = CanPacket.of(1, 0x1234567, extended=True, data=b"ABCDEFGH")
        publish(rig, encode_stream(rx_layout(3, options=2), 1, [frame]), cycles=3)
        msg = client.recv(0)
        assert msg is not None and msg.arbitration_id == 0x1234567 and bytes(msg.data) == b"ABCDEFGH"
        client.send(can.Message(arbitration_id=0x1234568, is_extended_id=True, data=b"12345678"))
        rig.clock.advance(0.001)
        rig.cycle(2)  # staged after the first read, read in the second
        image = _inputs(rig, tx_layout(3, options=2))
        decoded = decode_stream(image, tx_layout(3, options=2))
        assert decoded.header.payload_len == 16 and image[24 + 14:24 + 16] == b"\0\0"
    finally:
        client.shutdown()


def _with_crc(image: bytearray) -> bytes:
    n = struct.unpack_from("<H", image, 6)[0]
    struct.pack_into("<H", image, 8, crc16(image[24:24 + n]))
    return bytes(image)


def _bad_images(layout: StreamLayout) -> dict[PdoError, bytes]:
    good = bytearray(encode_stream(layout, 5, [CanPacket.of(0, 0x123, data=b"12345678")]))
    out: dict[PdoError, bytes] = {}
    img = bytearray(good)
    img[24] = 0x00 | (9 << 3)  # classic frame with DLC 9
    out[PdoError.INVALID_DLC] = _with_crc(img)
    img = bytearray(good)
    img[24] = (img[24] & ~0x07) | 5  # channel 5
    out[PdoError.INVALID_CHANNEL] = _with_crc(img)
    img = bytearray(good)
    img[25] |= 2 << 5  # KIND 2
    out[PdoError.UNKNOWN_KIND] = _with_crc(img)
    img = bytearray(good)
    img[27] |= 0x40  # StdIdField bit 14 reserved
    out[PdoError.RESERVED_BIT] = _with_crc(img)
    img = bytearray(good)
    img[0] = 0x15
    out[PdoError.BAD_HEADER] = bytes(img)
    img = bytearray(good)
    img[30] ^= 0xFF
    out[PdoError.BAD_CRC] = bytes(img)
    img = bytearray(good)
    struct.pack_into("<H", img, 6, 10)  # payload_len cuts the packet
    out[PdoError.TRUNCATED] = _with_crc(img)
    img = bytearray(good)
    struct.pack_into("<H", img, 6, layout.frame_area_bytes + 1)
    out[PdoError.PACKET_OVERRUN] = bytes(img)
    img = bytearray(good)
    struct.pack_into("<H", img, 10, 0x1234)  # layout_id of another profile
    out[PdoError.ACTIVE_AREA] = bytes(img)
    sched = bytearray(encode_stream(layout, 5, [CanPacket.of(0, 0x123, data=b"1", tsf=Tsf.FULL64, scheduled=True,
                                                          offset_ns=100_000)]))
    sched[28] = 2  # format 2
    out[PdoError.BAD_SCHEDULE] = _with_crc(sched)
    img = bytearray(good)
    img[25] |= 1 << 3  # TSF delta16 in the RxPDO
    n = 12 + 2
    struct.pack_into("<H", img, 6, n)
    out[PdoError.INVALID_TSF] = _with_crc(img)
    return out


@pytest.mark.parametrize("code", [PdoError.INVALID_DLC, PdoError.INVALID_CHANNEL, PdoError.UNKNOWN_KIND,
                                  PdoError.RESERVED_BIT, PdoError.BAD_HEADER, PdoError.BAD_CRC, PdoError.TRUNCATED,
                                  PdoError.PACKET_OVERRUN, PdoError.ACTIVE_AREA, PdoError.BAD_SCHEDULE,
                                  PdoError.INVALID_TSF])
def test_each_last_pdo_error_counts_and_sends_nothing(rig: Rig, code: PdoError) -> None:
    """13.2 LastPDOError table, 16.2: a rejected RxPDO image sets 0x8011:14 to its code, counts in :15,
    sets Status 7, and not one of its frames reaches the bus; the same image again is not counted twice."""
    bring_up(rig, n=3)
    client = python_can_bus(rig.buses[0])
    try:
        image = _bad_images(rx_layout(3))[code]
        publish(rig, image, cycles=4)
        assert client.recv(0) is None
        m = rig.master
        assert m.sdo_upload16(0, 0x8011, 14) == code
        assert m.sdo_upload32(0, 0x8011, 15) == 1
        assert m.sdo_upload8(0, 0x8011, 2) == ProfileStatus.ENCAPSULATION_ERROR
        m.sdo_download8(0, 0x8011, 8, 0x02)  # clear errors
        assert m.sdo_upload16(0, 0x8011, 14) == 0 and m.sdo_upload32(0, 0x8011, 15) == 0
        publish(rig, encode_stream(rx_layout(3), 6, [CanPacket.of(0, 0x321, data=b"ok")]), cycles=3)
        msg = client.recv(0)
        assert msg is not None and msg.arbitration_id == 0x321
    finally:
        client.shutdown()


def test_duplicate_sequence_with_other_content_is_error_10(rig: Rig) -> None:
    """13.2 code 10 / 13.8: the exact same image again is a no-op; the same sequence with other
    contents is 'duplicate sequence' and is not sent."""
    bring_up(rig, n=1)
    client = python_can_bus(rig.buses[0])
    try:
        publish(rig, encode_stream(rx_layout(1), 9, [CanPacket.of(0, 0x1, data=b"a")]), cycles=3)
        publish(rig, encode_stream(rx_layout(1), 9, [CanPacket.of(0, 0x1, data=b"a")]), cycles=3)
        publish(rig, encode_stream(rx_layout(1), 9, [CanPacket.of(0, 0x2, data=b"b")]), cycles=3)
        assert [msg.arbitration_id for msg in iter(lambda: client.recv(0), None)] == [0x1]
        assert rig.master.sdo_upload16(0, 0x8011, 14) == PdoError.DUPLICATE_SEQUENCE
        assert rig.master.sdo_upload32(0, 0x8011, 15) == 1
    finally:
        client.shutdown()


def test_torn_image_is_ignored(rig: Rig) -> None:
    """6.1 step 2: seq_begin != seq_end means half written: ignored, not an error, nothing sent."""
    bring_up(rig, n=1)
    client = python_can_bus(rig.buses[0])
    try:
        image = bytearray(encode_stream(rx_layout(1), 3, [CanPacket.of(0, 0x7, data=b"x")]))
        struct.pack_into("<H", image, 4, 2)
        publish(rig, bytes(image), cycles=3)
        assert client.recv(0) is None and rig.master.sdo_upload32(0, 0x8011, 15) == 0
    finally:
        client.shutdown()


def test_overflow_under_a_burst_truncates_and_counts(rig: Rig) -> None:
    """Chapter 12 / 6: more received frames than one N=1 frame area holds: STREAM_TRUNCATED and
    overflow_sat in the header, 0x8010:16 counts, no frame is split and all arrive in order later."""
    bring_up(rig, n=1)
    m = rig.master
    m.sdo_download8(0, 0x8021, 6, 2)   # 13.2.2: RX budget policy 'performance' (drain all it can)
    m.sdo_download8(0, 0x8021, 7, 32)  # RX cache depth 32
    m.sdo_download8(0, 0x8021, 2, 1)
    assert m.sdo_upload8(0, 0x8021, 3) == 0
    client = python_can_bus(rig.buses[0])
    try:
        for i in range(30):
            client.send(can.Message(arbitration_id=0x100 + i, data=bytes([i]) * 8, is_extended_id=False))
        rig.clock.advance(0.01)
        got: list[int] = []
        flags: list[int] = []
        for _ in range(12):
            rig.master.exchange_process_data()
            rig.clock.advance(CYCLE)
            d = decode_stream(_inputs(rig, tx_layout(1)), tx_layout(1))
            flags.append(d.header.header_flags)
            if d.header.header_flags & HeaderFlags.STREAM_TRUNCATED:
                assert d.header.overflow_sat > 0
            got += [p.can_id for p in d.packets if isinstance(p, CanPacket)]
        assert got == [0x100 + i for i in range(30)]
        assert any(f & HeaderFlags.STREAM_TRUNCATED for f in flags)
        assert rig.master.sdo_upload32(0, 0x8010, 16) > 0
    finally:
        client.shutdown()


def test_state_rules_of_14_2(rig: Rig) -> None:
    """14 / 14.2 / 13.2: apply in OP answers status 1 and keeps the profile; an assignment count that
    differs from the multiplier answers 5 and keeps the old profile; reserved option bits 10; N 25
    answers 2; SAFEOP -> OP is refused when SM2/SM3 lengths disagree with the active profile."""
    m = rig.master
    bring_up(rig, n=3)
    m.sdo_download8(0, 0x8011, 3, 8)
    assert m.sdo_upload8(0, 0x8011, 2) == ProfileStatus.PENDING_APPLY
    m.sdo_download8(0, 0x8011, 1, 1)
    assert m.sdo_upload8(0, 0x8011, 2) == ProfileStatus.INVALID_STATE
    assert m.sdo_upload16(0, 0x8011, 9) == 384
    m.set_state(AlState.PREOP)
    m.sdo_download8(0, 0x8011, 1, 1)  # 8 requested, 3 assigned
    assert m.sdo_upload8(0, 0x8011, 2) == ProfileStatus.MAPPING_RELOAD_REQUIRED and m.sdo_upload16(0, 0x8011, 9) == 384
    m.sdo_download8(0, 0x8011, 3, 3)
    m.sdo_download8(0, 0x8011, 7, 0x20)
    m.sdo_download8(0, 0x8011, 1, 1)
    assert m.sdo_upload8(0, 0x8011, 2) == ProfileStatus.UNSUPPORTED_OPTION
    m.sdo_download8(0, 0x8011, 7, 0)
    m.sdo_download8(0, 0x8011, 3, 25)
    m.sdo_download8(0, 0x8011, 1, 1)
    assert m.sdo_upload8(0, 0x8011, 2) == ProfileStatus.INVALID_MULTIPLIER
    # assignment of 4 chunks, profile still 3: SAFEOP is fine, OP is refused (16.1)
    for assign, base in ((0x1C12, 0x1600), (0x1C13, 0x1A00)):
        m.sdo_download8(0, assign, 0, 0)
        for i in range(4):
            m.sdo_download16(0, assign, i + 1, base + i)
        m.sdo_download8(0, assign, 0, 4)
    m.config_map()
    m.set_state(AlState.SAFEOP)
    with pytest.raises(AlStatusError):
        m.request_state(0, AlState.OP)
    assert m.al_status(0)[1] in (AlStatusCode.INVALID_OUTPUT_CONFIG, AlStatusCode.INVALID_INPUT_CONFIG)


def test_scheduled_transmit_on_sync0(rig: Rig) -> None:
    """8.4 / 13.8: TSF_FULL64 format 1 queues the frame for offset_ns after the next SYNC0; a target
    phase beyond the SYNC0 cycle is dropped and counted (0xB000:06 SCHED_LATE_DROP); without SYNC0
    the image is refused with LastPDOError 16."""
    bring_up(rig, n=1)
    m = rig.master
    client = python_can_bus(rig.buses[0])
    seen: list[tuple[int, float]] = []
    rig.buses[0].add_monitor(lambda f, t: seen.append((f.can_id, t)))
    try:
        publish(rig, encode_stream(rx_layout(1), 1, [CanPacket.of(0, 0x55, data=b"s", tsf=Tsf.FULL64, scheduled=True,
                                                               offset_ns=100_000)]))
        assert m.sdo_upload16(0, 0x8011, 14) == PdoError.BAD_SCHEDULE and not seen
        m.configure_sync0(0, 0.001, start_delay=0.0005)
        rig.cycle(2)
        sync = rig.device.app._last_sync0
        publish(rig, encode_stream(rx_layout(1), 2, [CanPacket.of(0, 0x66, data=b"s", tsf=Tsf.FULL64, scheduled=True,
                                                               offset_ns=300_000),
                                                     CanPacket.of(0, 0x77, data=b"l", tsf=Tsf.FULL64, scheduled=True,
                                                               offset_ns=2_000_000)]), cycles=3)
        assert sync is not None
        sent = [(i, t) for i, t in seen if i == 0x66]
        assert len(sent) == 1
        t_sync = rig.device.app._last_sync0
        assert t_sync is not None
        # the frame started 300 us after a SYNC0 pulse (and completes one frame time later)
        starts = [s for s in _sync_times(sync, 0.001, 5) if s + 0.0003 <= sent[0][1] < s + 0.0003 + 0.0002]
        assert starts
        assert not [i for i, _ in seen if i == 0x77]
        assert rig.device.app.sched_late_drops == 1
        assert m.sdo_upload16(0, 0xB000, 6) & 0x40  # SCHED_LATE_DROP
    finally:
        client.shutdown()


def _sync_times(first: float, cycle: float, n: int) -> list[float]:
    return [first + i * cycle for i in range(-1, n)]


def test_cycle_diagnostics_0x9011(rig: Rig) -> None:
    """13.2.4: PDI and Sync0 interrupt counts move with the cycle; Clear command 1 zeroes them."""
    bring_up(rig, n=1)
    m = rig.master
    m.configure_sync0(0, 0.001, start_delay=0.0005)
    rig.cycle(10)
    assert m.sdo_upload32(0, 0x9011, 1) >= 10 and m.sdo_upload32(0, 0x9011, 2) >= 8
    m.sdo_download8(0, 0x9011, 14, 1)
    assert m.sdo_upload32(0, 0x9011, 1) == 0 and m.sdo_upload32(0, 0x9011, 2) == 0


def test_n24_runs_3072_bytes_each_way(tmp_path: Path) -> None:
    """5.2: N=24 is 3072 B per direction (frame area 3048); 30 FD frames of 64 B go out in one image."""
    rig = make_rig(tmp_path)
    bring_up(rig, n=24)
    client = python_can_bus(rig.buses[3])
    try:
        packets = [CanPacket.of(3, 0x400 + i, fd=True, brs=True, data=bytes([i]) * 64) for i in range(30)]
        publish(rig, encode_stream(rx_layout(24), 1, packets), cycles=10)
        ids = [msg.arbitration_id for msg in iter(lambda: client.recv(0), None)]
        assert ids == [0x400 + i for i in range(30)]
        assert rig.cycle(1) == rig.master.expected_wkc
    finally:
        client.shutdown()
