"""The device's PDO data-path controls through an in-process master: 0x8030 test controls (13.2.3)
and the LastPDOError codes the RxPDO header alone reveals (13.2 table: 2, 9, 11, 12)."""

from __future__ import annotations

import struct

import can
from ecanlite_device_kit import Rig, bring_up

from gatewaylab.bus import python_can_bus
from gatewaylab.devices.ecanlite.stream import (
    CanPacket,
    Direction,
    PdoError,
    ProfileStatus,
    StreamLayout,
    crc16,
    decode_stream,
    encode_stream,
    fold_layout_id,
    profile_word,
)
from gatewaylab.od import SdoAbort

KEY = 0x4543414E


def rx_layout(n: int = 3, options: int = 0) -> StreamLayout:
    return StreamLayout(multiplier=n, channel_mask=0x0F, options=options, direction=Direction.RX)


def tx_layout(n: int = 3, options: int = 0) -> StreamLayout:
    return StreamLayout(multiplier=n, channel_mask=0x0F, options=options, direction=Direction.TX)


def _inputs(rig: Rig, n: int = 3) -> bytes:
    return rig.master.pdo_read(0, 0, 128 * n)


def _publish(rig: Rig, image: bytes, cycles: int = 3) -> None:
    rig.master.pdo_write(0, 0, image)
    rig.cycle(cycles)


def _test_control(rig: Rig, sub: int, value: int) -> None:
    m = rig.master
    m.sdo_download32(0, 0x8030, 1, KEY)
    if sub in (2, 3):
        m.sdo_download32(0, 0x8030, sub, value)
    else:
        m.sdo_download8(0, 0x8030, sub, value)


def _received(client: can.BusABC) -> list[int]:
    return [msg.arbitration_id for msg in iter(lambda: client.recv(0), None)]


def _peer_sends(rig: Rig, cid: int) -> None:
    client = python_can_bus(rig.buses[0])
    try:
        client.send(can.Message(arbitration_id=cid, data=b"\x01\x02", is_extended_id=False))
    finally:
        client.shutdown()
    rig.clock.advance(0.001)


def _tx_ids(rig: Rig) -> list[int]:
    return [p.can_id for p in decode_stream(_inputs(rig), tx_layout()).packets if isinstance(p, CanPacket)]


# ------------------------------------------------------------------ LastPDOError from the header
def _with_layout_id(layout_id: int) -> bytes:
    image = bytearray(encode_stream(rx_layout(), 5, [CanPacket.of(0, 0x123, data=b"12345678")]))
    struct.pack_into("<H", image, 10, layout_id)
    return bytes(image)


def _expect_error(rig: Rig, image: bytes, code: int) -> None:
    """13.2: LastPDOError = code, PDO error counter 1, Status 7, not one frame on the bus."""
    client = python_can_bus(rig.buses[0])
    try:
        _publish(rig, image)
        assert _received(client) == []
        m = rig.master
        assert (m.sdo_upload16(0, 0x8011, 14), m.sdo_upload32(0, 0x8011, 15)) == (code, 1)
        assert m.sdo_upload8(0, 0x8011, 2) == ProfileStatus.ENCAPSULATION_ERROR
        _publish(rig, image)                                   # the same image again: no-op (13.8)
        assert m.sdo_upload32(0, 0x8011, 15) == 1
    finally:
        client.shutdown()


def test_image_for_an_unsupported_profile_is_error_9(rig: Rig) -> None:
    """13.2 LastPDOError 9 'unsupported profile: EncapsulationProfile is not in the capability mask'
    (0xF000:12 = 0x33: profiles 0, 1, 4, 5): an RxPDO whose layout_id folds profile 2 (5.4.4.1 step 3)
    is rejected with 9, counted, and nothing reaches the bus."""
    bring_up(rig, n=3)
    _expect_error(rig, _with_layout_id(fold_layout_id(profile_word(3, 0x0F, 2, 0, 0))),
                  PdoError.UNSUPPORTED_PROFILE)


def test_image_with_unsupported_option_bits_is_error_11(rig: Rig) -> None:
    """13.2 LastPDOError 11 'unsupported option: option flags contain unsupported bits' (9.1: bits
    5..7 reserved, 0xF000:15 = 0x1F): an RxPDO whose layout_id folds option 0x20 gets 11."""
    bring_up(rig, n=3)
    _expect_error(rig, _with_layout_id(fold_layout_id(profile_word(3, 0x0F, 0, 0, 0x20))),
                  PdoError.UNSUPPORTED_OPTION)


def test_image_for_another_supported_profile_is_error_12(rig: Rig) -> None:
    """13.2 LastPDOError 12 'active area: active PDO/frame area is inconsistent with the master
    mapping': a supported profile (1) that is not the active one (0) stays 12, not 9."""
    bring_up(rig, n=3)
    _expect_error(rig, _with_layout_id(fold_layout_id(profile_word(3, 0x0F, 1, 0, 0))), PdoError.ACTIVE_AREA)


def test_d64_frame_in_profile_0_is_frame_overrun_2(rig: Rig) -> None:
    """13.2 LastPDOError 2 'frame overrun: a single frame exceeds the encapsulation capability
    supported by the current profile' (9: D64 only in profiles 4/5)."""
    bring_up(rig, n=3)
    image = bytearray(encode_stream(rx_layout(), 5, [CanPacket.of(0, 0x123, data=bytes(64), fd=True)]))
    image[25] |= 0x80                                          # control word bit 15 D64
    struct.pack_into("<H", image, 8, crc16(image[24:24 + struct.unpack_from("<H", image, 6)[0]]))
    _expect_error(rig, bytes(image), PdoError.FRAME_OVERRUN)


# ------------------------------------------------------------------ 0x8030 RxPDO fine bypass
def test_rxpdo_parse_bypass_takes_the_header_not_the_frames(rig: Rig) -> None:
    """13.2.3 RxPDO bypass bit 3 'PARSE: Skip RxPDO payload parse': the image's sequence is taken
    (0x8011:13) but its frames are not parsed or sent; with the bit cleared frames flow again."""
    bring_up(rig, n=3)
    _test_control(rig, 3, 0x08)
    client = python_can_bus(rig.buses[0])
    try:
        _publish(rig, encode_stream(rx_layout(), 7, [CanPacket.of(0, 0x101, data=b"a")]))
        assert _received(client) == []
        m = rig.master
        assert m.sdo_upload16(0, 0x8011, 13) == 7 and m.sdo_upload32(0, 0x8011, 15) == 0
        m.sdo_download32(0, 0x8030, 3, 0)
        _publish(rig, encode_stream(rx_layout(), 8, [CanPacket.of(0, 0x102, data=b"b")]))
        assert _received(client) == [0x102]
    finally:
        client.shutdown()


def test_rxpdo_stage_bypass_ignores_the_image(rig: Rig) -> None:
    """13.2.3 RxPDO bypass bit 2 'STAGE: Skip RxPDO stage': the image is not taken in at all (no
    sequence, no error count even for a bad CRC, no frame); writing 0 to the key ends test mode."""
    bring_up(rig, n=3)
    _test_control(rig, 3, 0x04)
    client = python_can_bus(rig.buses[0])
    try:
        image = bytearray(encode_stream(rx_layout(), 9, [CanPacket.of(0, 0x103, data=b"c")]))
        image[30] ^= 0xFF                                      # a bad CRC would be error 15
        _publish(rig, bytes(image))
        m = rig.master
        assert _received(client) == []
        assert m.sdo_upload16(0, 0x8011, 13) == 0 and m.sdo_upload32(0, 0x8011, 15) == 0
        m.sdo_download32(0, 0x8030, 1, 0)
        assert m.sdo_upload32(0, 0x8030, 3) == 0
        _publish(rig, encode_stream(rx_layout(), 10, [CanPacket.of(0, 0x104, data=b"d")]))
        assert _received(client) == [0x104]
    finally:
        client.shutdown()


def test_app_link_bypass_rx_parses_and_sends_nothing(rig: Rig) -> None:
    """13.2.3 SI6 'App link bypass policy 2=Rx' (as 9.1 APP_BYPASS: the RxPDO does not enter the
    MCAN path): a good image is checked and its sequence taken, nothing is sent; a bad one still
    counts (the PDO layer keeps checking)."""
    bring_up(rig, n=3)
    _test_control(rig, 6, 2)
    client = python_can_bus(rig.buses[0])
    try:
        _publish(rig, encode_stream(rx_layout(), 3, [CanPacket.of(0, 0x105, data=b"e")]))
        assert _received(client) == [] and rig.master.sdo_upload16(0, 0x8011, 13) == 3
    finally:
        client.shutdown()


def test_legal_combination_rejects_app_and_fine_bypass(rig: Rig) -> None:
    """13.2.3 'Legal combination mask' / 'Last reject reason': the application bypass and a fine
    bypass in the same direction are refused (reason 4) and nothing changes."""
    bring_up(rig, n=3)
    _test_control(rig, 6, 1)
    m = rig.master
    try:
        m.sdo_download32(0, 0x8030, 2, 0x08)
    except SdoAbort:
        pass
    else:
        raise AssertionError("app bypass Tx + BUILD accepted")
    assert m.sdo_upload32(0, 0x8030, 9) == 4 and m.sdo_upload32(0, 0x8030, 2) == 0
    assert m.sdo_upload32(0, 0x8030, 8) == 0x1F


# ------------------------------------------------------------------ 0x8030 TxPDO fine bypass
def test_txpdo_build_bypass_publishes_headers_only(rig: Rig) -> None:
    """13.2.3 TxPDO bypass bit 3 'BUILD: Skip TxPDO dynamic frame build': images keep coming
    (sequence, status words) with no frame; the received frame waits in the RX cache (0x9020:01)
    and arrives once the bit is cleared."""
    bring_up(rig, n=3)
    _test_control(rig, 2, 0x08)
    _peer_sends(rig, 0x201)
    rig.cycle(3)
    decoded = decode_stream(_inputs(rig), tx_layout())
    assert decoded.packets == () and decoded.header.payload_len == 0
    assert decoded.header.channel_status[0] & 7 == 2           # run
    seq = decoded.seq
    rig.cycle(1)
    assert decode_stream(_inputs(rig), tx_layout()).seq == (seq + 1) & 0xFFFF
    assert rig.master.sdo_upload16(0, 0x9020, 1) == 1
    rig.master.sdo_download32(0, 0x8030, 2, 0)
    rig.cycle(2)
    assert _tx_ids(rig) == [0x201]


def test_txpdo_copy_bypass_keeps_the_last_published_image(rig: Rig) -> None:
    """13.2.3 TxPDO bypass bit 4 'COPY: Skip TxPDO copy/publish path': nothing new is published
    (the master reads the same image, sequence included) and nothing is consumed; the frame comes
    once the bit is cleared."""
    bring_up(rig, n=3)
    rig.cycle(2)
    before = _inputs(rig)
    _test_control(rig, 2, 0x10)
    rig.cycle(1)
    frozen = _inputs(rig)
    _peer_sends(rig, 0x202)
    rig.cycle(3)
    assert _inputs(rig) == frozen
    assert decode_stream(frozen, tx_layout()).seq in (decode_stream(before, tx_layout()).seq,
                                                      decode_stream(before, tx_layout()).seq + 1)
    rig.master.sdo_download32(0, 0x8030, 2, 0)
    rig.cycle(2)
    assert _tx_ids(rig) == [0x202]


# ------------------------------------------------------------------ 0x8030 CRC / payload-only policy
def test_crc_test_policy_force_no_crc16(rig: Rig) -> None:
    """13.2.3 SI4 'CRC test policy 2=force no CRC16': the TxPDO carries crc_alg 0 / payload_crc16 0
    (9.1 NO_CRC16 form) and the RxPDO CRC is not checked (a wrong CRC is sent, not error 15)."""
    bring_up(rig, n=3)
    _test_control(rig, 4, 2)
    client = python_can_bus(rig.buses[0])
    try:
        _peer_sends(rig, 0x203)
        rig.cycle(3)
        image = _inputs(rig)
        assert image[15] == 0 and image[8:10] == b"\0\0"
        assert _received(client) == [0x203]                     # the peer's own frame on the bus
        bad = bytearray(encode_stream(rx_layout(), 4, [CanPacket.of(0, 0x106, data=b"f")]))
        bad[8] ^= 0xFF
        _publish(rig, bytes(bad))
        assert _received(client) == [0x106] and rig.master.sdo_upload32(0, 0x8011, 15) == 0
    finally:
        client.shutdown()


def test_crc_test_policy_force_crc16_over_no_crc16_option(rig: Rig) -> None:
    """13.2.3 SI4 'CRC test policy 1=force CRC16' with 9.1 NO_CRC16_ENABLE active: the TxPDO carries
    crc_alg 1 and a good CRC-16/CCITT-FALSE; an RxPDO without a CRC is refused."""
    bring_up(rig, n=3, tx_options=0x04, rx_options=0x04)
    _test_control(rig, 4, 1)
    rig.cycle(2)
    image = _inputs(rig)
    n = struct.unpack_from("<H", image, 6)[0]
    assert image[15] == 1 and struct.unpack_from("<H", image, 8)[0] == crc16(image[24:24 + n])
    client = python_can_bus(rig.buses[0])
    try:
        _publish(rig, encode_stream(rx_layout(options=0x04), 4, [CanPacket.of(0, 0x107, data=b"g")]))
        assert _received(client) == []
        assert rig.master.sdo_upload16(0, 0x8011, 14) in (PdoError.BAD_HEADER, PdoError.BAD_CRC)
    finally:
        client.shutdown()


def test_payload_only_policy_tx_leaves_bytes_beyond_payload_len(rig: Rig) -> None:
    """13.2.3 SI5 'Payload only policy 1=Tx' (9.1 PAYLOAD_ONLY: 'update only the 24-byte header and
    valid payload; receivers must ignore bytes beyond payload_len'): after an image with a frame,
    an empty image leaves the old frame bytes behind its header."""
    bring_up(rig, n=3)
    _test_control(rig, 5, 1)
    _peer_sends(rig, 0x204)
    rig.cycle(3)
    with_frame = _inputs(rig)
    assert any(with_frame[24:40])
    rig.cycle(2)
    empty = _inputs(rig)
    assert decode_stream(empty, tx_layout()).packets == ()
    assert empty[24:40] == with_frame[24:40]


def test_cycle_runs_with_every_control_set(rig: Rig) -> None:
    """13.2.3: any legal combination keeps the cycle running with a full working counter."""
    bring_up(rig, n=3)
    _test_control(rig, 2, 0x1C)
    rig.master.sdo_download32(0, 0x8030, 3, 0x3C)
    rig.master.sdo_download8(0, 0x8030, 4, 2)
    rig.master.sdo_download8(0, 0x8030, 5, 3)
    assert rig.cycle(5) == 3
