"""Issue-10 bullets that had no device-level test: what a master sees in the TxPDO header (chapter 6,
7), timestamps (8.4), profiles 4/5 (9), budget policies (12), SDO information and complete access
(EtherCAT face). In-process master on a simulated clock."""

from __future__ import annotations

import can
from ecanlite_device_kit import CYCLE, Rig, bring_up

from gatewaylab.bus import python_can_bus
from gatewaylab.devices.ecanlite.stream import (
    CanPacket,
    DecodedStream,
    Direction,
    HeaderFlags,
    StreamLayout,
    Tsf,
    decode_stream,
    encode_stream,
)


def _layout(n: int, direction: Direction, profile: int = 0, budget: int = 0) -> StreamLayout:
    return StreamLayout(multiplier=n, channel_mask=0x0F, profile=profile, budget_policy=budget, direction=direction)


def _read(rig: Rig, layout: StreamLayout) -> DecodedStream:
    """One cycle, then the TxPDO image the master read in it."""
    rig.master.exchange_process_data()
    rig.clock.advance(CYCLE)
    return decode_stream(rig.master.pdo_read(0, 0, layout.pdo_bytes), layout)


def _send(rig: Rig, k: int, msgs: list[can.Message]) -> None:
    client = python_can_bus(rig.buses[k])
    try:
        for msg in msgs:
            client.send(msg)
    finally:
        client.shutdown()


def test_status_words_and_header_flags_follow_the_controllers(rig: Rig) -> None:
    """Chapter 7 status words and chapter 6 header_flags from the real controller state: four FD
    channels in run (state 2, fd_enabled); a bus-off on CAN1 shows state 3 + bus_off in word 1,
    STATUS_CHANGED once (the image where it changes) and ANY_CHANNEL_ERROR while it lasts."""
    bring_up(rig, n=3)
    tx = _layout(3, Direction.TX)
    rig.master.sdo_download8(0, 0x8022, 14, 0)        # 13.2.2: manual bus-off recovery on MCAN1
    rig.master.sdo_download8(0, 0x8022, 2, 1)
    rig.cycle(2)
    d = _read(rig, tx)
    assert [w & 0x0F for w in d.header.channel_status] == [0x0A] * 4
    assert not d.header.header_flags & (HeaderFlags.ANY_CHANNEL_ERROR | HeaderFlags.STATUS_CHANGED)
    ctrl = rig.device.controllers[1]
    assert ctrl is not None
    rig.buses[1].force_bus_off(ctrl)
    images = [_read(rig, tx) for _ in range(3)]
    changed = [i for i, img in enumerate(images) if img.header.header_flags & HeaderFlags.STATUS_CHANGED]
    assert len(changed) == 1
    last = images[-1].header
    assert last.channel_status[1] & 7 == 3 and last.channel_status[1] >> 5 & 1
    assert last.header_flags & HeaderFlags.ANY_CHANNEL_ERROR
    assert [w & 7 for w in (last.channel_status[0], *last.channel_status[2:])] == [2, 2, 2]
    assert rig.master.sdo_upload32(0, 0x9001, 15) == 1


def test_seq_wrap_flag_on_the_image_after_0xffff(rig: Rig) -> None:
    """Chapter 6 header_flags bit 4 SEQ_WRAP 'seq_begin wraparound this cycle': set on the image whose
    sequence wrapped to 0 and on no other. (The sequence is advanced in the device to spare 65,000
    cycles.)"""
    bring_up(rig, n=1)
    tx = _layout(1, Direction.TX)
    rig.cycle(2)
    app = rig.device.app
    app.tx.seq = 0xFFFC
    if app._staged is not None:
        app._staged.seq = 0xFFFC
    seen = {}
    for _ in range(6):
        d = _read(rig, tx)
        seen[d.seq] = bool(d.header.header_flags & HeaderFlags.SEQ_WRAP)
    assert seen.get(0) is True
    assert not any(flag for seq, flag in seen.items() if seq != 0)
    assert 0xFFFF in seen and 1 in seen


def test_profile_1_delta16_timestamps_from_the_bus_receive_instant(rig: Rig) -> None:
    """8.4 / 9 profile 1 'allow delta16 timestamp': TxPDO frames carry TSF delta16 in 1 us ticks of
    the bus receive instant (docs/decisions.md): two frames in one image differ by exactly the time
    between their receive instants on the bus (as a bus monitor sees them), in microseconds."""
    bring_up(rig, n=3, tx_profile=1)
    tx = _layout(3, Direction.TX, profile=1)
    rig.master.sdo_download8(0, 0x8021, 6, 2)          # drain everything per cycle
    rig.master.sdo_download8(0, 0x8021, 2, 1)
    rig.cycle(2)
    instants: dict[int, float] = {}
    rig.buses[0].add_monitor(lambda f, t: instants.setdefault(f.can_id, t))
    client = python_can_bus(rig.buses[0])
    try:
        client.send(can.Message(arbitration_id=0x301, data=b"\x01", is_extended_id=False))
        rig.clock.advance(0.0003)
        client.send(can.Message(arbitration_id=0x302, data=b"\x02", is_extended_id=False))
        rig.clock.advance(0.0003)
    finally:
        client.shutdown()
    packets: list[CanPacket] = []
    for _ in range(3):
        packets += [p for p in _read(rig, tx).packets if isinstance(p, CanPacket)]
    assert [p.can_id for p in packets] == [0x301, 0x302]
    assert all(p.tsf == Tsf.DELTA16 for p in packets)
    apart = round((instants[0x302] - instants[0x301]) * 1e6)
    assert apart >= 300 and (packets[1].timestamp - packets[0].timestamp) & 0xFFFF == apart


def test_profile_4_d64_frame_reaches_the_bus(rig: Rig) -> None:
    """9 profile 4 'compact inline, D64 allowed': an RxPDO CAN FD frame in a 64-byte D64 window goes
    to the bus with its own DLC and data."""
    bring_up(rig, n=3, rx_profile=4)
    rx = _layout(3, Direction.RX, profile=4)
    client = python_can_bus(rig.buses[2])
    try:
        frame = CanPacket.of(2, 0x1AB, data=bytes(range(12)), fd=True, brs=True, d64=True)
        rig.master.pdo_write(0, 0, encode_stream(rx, 1, [frame]))
        rig.cycle(3)
        msg = client.recv(0)
        assert msg is not None and msg.arbitration_id == 0x1AB and bytes(msg.data) == bytes(range(12))
        assert msg.is_fd and msg.bitrate_switch
        assert rig.master.sdo_upload32(0, 0x8011, 15) == 0
    finally:
        client.shutdown()


def _per_image_counts(rig: Rig, budget: int) -> list[int]:
    bring_up(rig, n=1, budget=budget)
    tx = _layout(1, Direction.TX, budget=budget)
    rig.master.sdo_download8(0, 0x8021, 6, 2)          # MCAN0 drains everything it has per cycle
    rig.master.sdo_download8(0, 0x8021, 2, 1)
    rig.cycle(2)
    _send(rig, 0, [can.Message(arbitration_id=0x100 + i, data=bytes(8), is_extended_id=False) for i in range(6)])
    rig.clock.advance(0.002)
    counts = []
    for _ in range(4):
        counts.append(sum(isinstance(p, CanPacket) for p in _read(rig, tx).packets))
    return counts


def test_shared_only_budget_lets_one_channel_fill_the_area(rig: Rig) -> None:
    """12 'SharedOnly: No channel reservation, all frames share contention': N=1 (104 B area), six
    12-byte frames of CAN0 alone travel in one image."""
    assert _per_image_counts(rig, 1)[:2] in ([6, 0], [0, 6])


def test_deterministic_budget_does_not_borrow(rig: Rig) -> None:
    """12 'Deterministic: Allocate the budget evenly according to the enabled channels, and do not
    borrow between channels': four enabled channels share 104 B as 26 B each, so CAN0 sends two
    12-byte frames per image even though the others are idle."""
    counts = [c for c in _per_image_counts(rig, 2) if c]
    assert counts[:3] == [2, 2, 2]


def test_sdo_information_and_complete_access(rig: Rig) -> None:
    """EtherCAT face 'CoE with SDO Info and complete access' (a master browsing the device without
    an ESI): the object list holds the 13.1 objects; 0x8010 describes itself; a complete-access
    upload of 0xF000 returns subindex 0 and the 13.8 values in order."""
    bring_up(rig, n=1)
    m = rig.master
    indexes = set(m.od_list(0))
    assert {0x1008, 0x100A, 0x1C12, 0x1C13, 0x8000, 0x8010, 0x8011, 0x8030, 0x9011, 0xA000, 0xB000,
            0xF000} <= indexes
    assert m.object_description(0, 0x8010).name
    assert m.entry_description(0, 0xF000, 13).bit_length == 16
    raw = m.sdo_upload(0, 0xF000, 0, complete=True)
    # SI0 = 32 as 16 bits (ETG.1000.6 complete access), then :01 device type 0, :02 4 channels,
    # :03 capability version 1, :04 hardware revision, :05 firmware 0x0103, :06 build 0x2100
    assert raw[:4] == bytes([32, 0, 0, 4])
    assert int.from_bytes(raw[4:6], "little") == 1
    assert int.from_bytes(raw[10:12], "little") == 0x0103 and int.from_bytes(raw[12:14], "little") == 0x2100
