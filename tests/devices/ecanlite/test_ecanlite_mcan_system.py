"""System, test-control, register-service, maintenance and capability objects (ECAN-Lite manual
13.2.1, 13.2.3, 13.3, 13.6, 13.7, 13.8)."""

from __future__ import annotations

import pytest
from ecanlite_mcan_kit import Rig, make_rig

from gatewaylab.bus import CanFrame
from gatewaylab.devices.ecanlite.system import TEST_KEY
from gatewaylab.od import SdoAbort, SdoAbortCode


def test_capability_defaults() -> None:
    """13.8: every 0xF000 default (phase A of 5.4.3 reads :02, :10, :11, :12, :15, :17, :18)."""
    rig = make_rig()
    want = {1: 0, 2: 4, 3: 0x0001, 9: 0x0002, 10: 1, 11: 24, 12: 0x33, 13: 3072, 14: 4, 15: 0x1F,
            16: 0x00001F3B, 17: 128, 18: 24, 19: 0x15, 20: 1, 21: 1, 22: 1, 23: 0, 24: 0x1F, 25: 0x1F,
            26: 0, 27: 0, 28: 32, 29: 64, 30: 1000, 31: 0, 32: 0}
    assert {s: rig.r(0xF000, s) for s in want} == want
    assert rig.r(0xF000, 5) == 0x0103 and rig.r(0xF000, 6) == 0x2100   # firmware V1.3 build 0x2100
    with pytest.raises(SdoAbort) as exc:
        rig.w(0xF000, 11, 8)
    assert exc.value.code == SdoAbortCode.READ_ONLY


def test_object_overview_types() -> None:
    """13.1 / 13.4 tables: names and types as the manual lists them; 0x8001 has no subindex 35 and
    0x8000 no subindex 2."""
    rig = make_rig()
    od = rig.od
    assert od.entry(0x8001, 19).name == "Nominal bitrate" and od.entry(0x8001, 19).bit_length == 32
    assert od.entry(0x8004, 87).name == "Timeout period" and od.entry(0x8004, 87).bit_length == 16
    assert od.objects[0x8001].name == "MCAN0 Channel Config"
    for index, sub in ((0x8001, 35), (0x8000, 2)):
        with pytest.raises(SdoAbort) as exc:
            od.read(index, sub)
        assert exc.value.code == SdoAbortCode.SUBINDEX_DOES_NOT_EXIST
    assert od.read(0x8001, 0) == bytes([87])
    indexes = {o.index for o in rig.model.object_defs()}
    want = ({0x8000, 0x8020, 0x8030, 0xB000, 0xF000} | set(range(0x8001, 0x8005)) | set(range(0x8021, 0x8025))
            | set(range(0x9000, 0x9004)) | set(range(0x9020, 0x9024)) | set(range(0xA000, 0xA004)))
    assert indexes == want


def test_system_config() -> None:
    """13.3: clocks RO (CPU 400 MHz, bus 200 MHz, MCAN 80 MHz), pin rotation within the mask
    0x0F takes effect (:13 active, :15 status 0), an unsupported one reports status 1; reboot."""
    rig = make_rig()
    assert [rig.r(0x8000, s) for s in (3, 4, 5, 6, 9, 14)] == [1275, 400_000_000, 200_000_000, 80_000_000,
                                                             80_000_000, 0x0F]
    rig.w(0x8000, 12, 2)
    assert (rig.r(0x8000, 13), rig.r(0x8000, 15)) == (2, 0)
    rig.w(0x8000, 12, 7)
    assert (rig.r(0x8000, 13), rig.r(0x8000, 15), rig.r(0x8000, 11)) == (2, 1, 1)
    rig.w(0x8000, 1, 1)
    rig.run(0.001)
    assert rig.reboots


def test_fine_bypass_of_the_mcan_path() -> None:
    """13.2.3 TxPDO bit 2 MCAN_READ 'Skip reading real frames from MCAN/RX cache', RxPDO bit 5
    MCAN_WRITE 'Skip real MCAN transmit': frames stay in the cache / never reach the bus, the
    transmit still reports OK."""
    rig = make_rig()
    assert rig.configure(0) == 0
    ch = rig.model.channels[0]
    rig.w(0x8030, 1, TEST_KEY)
    rig.w(0x8030, 2, 0x04)
    rig.w(0x8030, 3, 0x20)
    rig.peers[0].send(CanFrame(0x10, b""))
    assert ch.submit(CanFrame(0x20, b""), "b") == 0
    rig.run()
    assert ch.peek(8) == () and ch.pending_rx() == 1
    assert ch.take_tx_results() == [("b", 0)] and rig.recorders[0].frames == []
    rig.w(0x8030, 1, 0)
    assert len(ch.peek(8)) == 1


def test_pin_rotation_moves_channels() -> None:
    """13.3 SI12 'Rotation of logical CAN channel to fixed pin group': with rotation 1 CAN0 drives
    the second pin group's bus and CAN3 the first's; rotation 0 restores the wiring."""
    rig = make_rig(channels=2)
    assert rig.configure(0) == 0 and rig.configure(3) == 0
    rig.w(0x8000, 12, 1)
    ch0, ch3 = rig.model.channels[0], rig.model.channels[3]
    assert ch0.controller is rig.model.pins[1] and ch3.controller is rig.model.pins[0]
    assert rig.model.channels[1].controller is None
    assert ch0.submit(CanFrame(0x111, b"\x01"), None) == 0
    rig.peers[0].send(CanFrame(0x222, b"\x02"))
    rig.run()
    assert [f.can_id for f, _ in rig.recorders[1].frames] == [0x111]
    assert [r.frame.can_id for r in ch3.peek(8)] == [0x222]
    rig.w(0x8000, 12, 0)
    assert ch0.controller is rig.model.pins[0]


def test_global_control_apply() -> None:
    """13.2.1: runtime/diagnostic option flags must stay 0 (capability mask 0), budget 0..1000."""
    rig = make_rig()
    assert rig.r(0x8020, 1) == 1 and rig.r(0x8020, 4) == 3 and rig.r(0x8020, 7) == 1000
    rig.w(0x8020, 7, 500)
    rig.w(0x8020, 2, 1)
    assert rig.r(0x8020, 3) == 0
    rig.w(0x8020, 5, 1)
    rig.w(0x8020, 2, 1)
    assert rig.r(0x8020, 3) == 1
    assert rig.model.system.global_control[7] == 500


def test_test_controls_key() -> None:
    """13.2.3: test controls only behind 0x4543414E; legal combination mask 0x1F; illegal values
    or combinations are refused and 0x8030:09 says why; key 0 turns everything off."""
    rig = make_rig()
    assert rig.r(0x8030, 8) == 0x1F
    with pytest.raises(SdoAbort) as exc:
        rig.w(0x8030, 3, 0x04)
    assert exc.value.code == SdoAbortCode.DATA_CANNOT_BE_STORED_DEVICE_STATE
    assert rig.r(0x8030, 9) == 1
    with pytest.raises(SdoAbort):
        rig.w(0x8030, 1, 0x1234)
    assert rig.r(0x8030, 9) == 5
    rig.w(0x8030, 1, TEST_KEY)
    rig.w(0x8030, 3, 0x3C)                          # STAGE | PARSE | TX_RING | MCAN_WRITE
    assert rig.model.system.test.rx_bypass == 0x3C and rig.r(0x8030, 9) == 0
    with pytest.raises(SdoAbort):
        rig.w(0x8030, 2, 0x02)                      # bit 1 is not a TxPDO bypass bit
    assert rig.r(0x8030, 9) == 2
    with pytest.raises(SdoAbort):
        rig.w(0x8030, 4, 3)
    assert rig.r(0x8030, 9) == 3
    with pytest.raises(SdoAbort):
        rig.w(0x8030, 6, 2)                         # app bypass Rx together with fine Rx bypass
    assert rig.r(0x8030, 9) == 4
    assert rig.r(0x8030, 6) == 0
    rig.w(0x8030, 1, 0)
    assert rig.r(0x8030, 3) == 0 and rig.model.system.test.rx_bypass == 0


def _reg(rig: Rig, k: int, cmd: int, offset: int, value: int = 0) -> int:
    rig.w(0xA000 + k, 1, offset)
    rig.w(0xA000 + k, 4, value)
    rig.w(0xA000 + k, 2, cmd)
    return rig.r(0xA000 + k, 3)


def test_register_service() -> None:
    """13.6: offset 0x0004..0x0404, 32-bit aligned (else 1), write whitelist (else 2), writes only
    with debug access (else 4); reads return the MCAN registers 0x9000 reports."""
    rig = make_rig()
    assert rig.configure(0) == 0
    assert _reg(rig, 0, 1, 0x0000) == 1
    assert _reg(rig, 0, 1, 0x0406) == 1
    assert _reg(rig, 0, 1, 0x0042) == 1
    assert _reg(rig, 0, 1, 0x001C) == 0
    assert rig.r(0xA000, 5) == (9 << 25) | (0 << 16) | (68 << 8) | 9      # NBTP of 1M @ 87.5 %
    assert _reg(rig, 0, 1, 0x0040) == 0 and rig.r(0xA000, 5) == rig.r(0x9000, 1)
    assert _reg(rig, 0, 2, 0x0040, 1) == 2         # ECR is not writable
    assert _reg(rig, 0, 2, 0x0050, 0xFFFFFFFF) == 4  # run mode: access denied
    rig.w(0xB000, 1, 1)                              # engineering
    assert _reg(rig, 0, 2, 0x0050, 0xFFFFFFFF) == 0
    assert _reg(rig, 0, 2, 0x0054, 0x1234) == 0
    assert _reg(rig, 0, 1, 0x0054) == 0 and rig.r(0xA000, 5) == 0x1234
    rig.run(0.5)
    assert _reg(rig, 0, 1, 0x0044) == 0
    ns = rig.r(0xA000, 6) | rig.r(0xA000, 7) << 32   # command timestamp (ns of the device clock)
    assert ns == int(rig.clock.now() * 1e9) and ns >= 500_000_000
    with pytest.raises(SdoAbort):
        rig.w(0xA000, 2, 3)


def test_register_ir_write_one_to_clear() -> None:
    """13.6 whitelist 'IR Interrupt flags, write 1 to clear'."""
    rig = make_rig()
    assert rig.configure(0) == 0
    rig.w(0xB000, 1, 1)
    rig.peers[0].send(CanFrame(0x1, b""))
    rig.run()
    assert rig.r(0x9000, 3) & 1                     # RF0N
    assert _reg(rig, 0, 2, 0x0050, 1) == 0
    assert rig.r(0x9000, 3) & 1 == 0


def test_access_mode_timeout() -> None:
    """13.7 SI1..3: engineering mode falls back to run after 'Access timeout s' (injected clock)."""
    rig = make_rig()
    rig.w(0xB000, 3, 10)
    rig.w(0xB000, 1, 1)
    assert rig.r(0xB000, 2) == 1
    rig.run(9.0)
    assert rig.r(0xB000, 2) == 1
    rig.run(1.5)
    assert rig.r(0xB000, 2) == 0
    with pytest.raises(SdoAbort):
        rig.w(0xB000, 1, 3)


def test_maintenance_commands() -> None:
    """13.7 SI4 bit mask: bit5/bit6 must be written alone (else refused); the sequence increments
    after every command; factory reset needs engineering/factory access (status 2 denied)."""
    rig = make_rig()
    seq = rig.r(0xB000, 12)
    for bad in (0x21, 0x60, 0x41, 0x80):
        with pytest.raises(SdoAbort):
            rig.w(0xB000, 4, bad)
    assert rig.r(0xB000, 12) == seq
    rig.w(0xB000, 4, 0x04)
    assert (rig.r(0xB000, 5), rig.r(0xB000, 12)) == (2, seq + 1)
    rig.w(0xB000, 1, 2)                              # factory access
    rig.w(0x8001, 19, 250_000)
    rig.w(0xB000, 4, 0x04)
    assert (rig.r(0xB000, 5), rig.r(0xB000, 12)) == (0, seq + 2)
    assert rig.r(0x8001, 19) == 500_000
    rig.w(0xB000, 4, 0x20)                           # clear diagnostics alone
    assert rig.r(0xB000, 5) == 0
    rig.w(0xB000, 4, 0x40)                           # EEPROM rebuild + reboot alone
    rig.run(0.001)
    assert rig.reboots and rig.r(0xB000, 12) == seq + 4


def test_clear_diagnostics() -> None:
    """13.7 bit5 'Clear runtime diagnostics and legacy diagnostic flags': 0x9020 counters to 0."""
    rig = make_rig()
    assert rig.configure(0) == 0
    for i in range(20):
        rig.peers[0].send(CanFrame(0x100 + i, b""))
    rig.run()
    assert rig.r(0x9020, 5) == 4
    rig.w(0xB000, 4, 0x20)
    assert rig.r(0x9020, 5) == 0 and rig.r(0x9000, 13) == 0


def test_objects_in_esi() -> None:
    """13.1: the objects reach the ESI dictionary a master imports (names, subindexes with the gap
    at 0x8001:35, access)."""
    import xml.etree.ElementTree as ET

    from gatewaylab.ethercat.description import DeviceDescription
    from gatewaylab.ethercat.esi import export_esi

    rig = make_rig()
    desc = DeviceDescription(name="ECAN-Lite", vendor_id=1, product_code=1, objects=rig.model.object_defs())
    root = ET.fromstring(export_esi(desc, rig.od))
    objects = {o.findtext("Index"): o for o in root.iter("Object")}
    assert objects["#x8001"].findtext("Name") == "MCAN0 Channel Config"
    assert objects["#xF000"].findtext("Name") == "Device Objects"
    subs = [int(s.findtext("SubIdx") or "-1") for dt in root.iter("DataType")
            if dt.findtext("Name") == objects["#x8001"].findtext("Type") for s in dt.iter("SubItem")]
    assert 87 in subs and 35 not in subs and 34 in subs
