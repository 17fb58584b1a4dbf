"""The ECAN-Lite's ESI export checked field by field against manual 15.7 / 5.3 (SyncManagers), 5.1 (the 24 + 24
chunk maps, 8 assigned at power-on), 5.4 / 15.3.1 (CoE with SDO info, PDO assign/config, complete access;
FoE) and against the SII the device carries (ETG.2000 Eeprom element)."""

from __future__ import annotations

import struct
import xml.etree.ElementTree as ET
from pathlib import Path

from ecanlite_device_kit import make_rig

from gatewaylab.ethercat.esi import export_esi


def _int(text: str | None) -> int:
    assert text is not None
    return int(text[2:], 16) if text.startswith("#x") else int(text)


def test_esi_matches_15_7_and_the_sii(tmp_path: Path) -> None:
    """15.7: SM2 Outputs 0x1100 / 3072 / 0x66, SM3 Inputs 0x1D00 / 3072 / 0x22 (5.3), behind the 128 B
    mailbox SMs 0x1000 (0x26) / 0x1080 (0x22); 5.1: RxPDO 0x1600..0x1617 and TxPDO 0x1A00..0x1A17, eight
    STRING(16) units each mapping 0x7000 / 0x6000 + c*0x80 + u*0x10 :01, the first eight on SM2 / SM3
    (Mandatory), the others optional; CoE SdoInfo, PdoAssign, PdoConfig, CompleteAccess and FoE; identity,
    EEPROM size and configuration area equal to the SII's (ETG.2000)."""
    rig = make_rig(tmp_path)
    slave = rig.device.slave
    root = ET.fromstring(export_esi(slave.desc, slave.od))
    assert _int(root.findtext("Vendor/Id")) == struct.unpack_from("<I", slave.sii, 0x10)[0]
    device = root.find("Descriptions/Devices/Device")
    assert device is not None
    kind = device.find("Type")
    assert kind is not None
    assert (_int(kind.get("ProductCode")), _int(kind.get("RevisionNo"))) == struct.unpack_from("<II", slave.sii, 0x14)
    sms = [(sm.text, _int(sm.get("StartAddress")), _int(sm.get("DefaultSize")), _int(sm.get("ControlByte")),
            sm.get("Enable")) for sm in device.findall("Sm")]
    assert sms == [("MBoxOut", 0x1000, 128, 0x26, "1"), ("MBoxIn", 0x1080, 128, 0x22, "1"),
                   ("Outputs", 0x1100, 3072, 0x66, "1"), ("Inputs", 0x1D00, 3072, 0x22, "1")]
    assert [f.text for f in device.findall("Fmmu")] == ["Outputs", "Inputs", "MBoxState"]
    for tag, base, obj, sm in (("RxPdo", 0x1600, 0x7000, "2"), ("TxPdo", 0x1A00, 0x6000, "3")):
        pdos = device.findall(tag)
        assert [_int(p.findtext("Index")) for p in pdos] == [base + c for c in range(24)]
        for c, pdo in enumerate(pdos):
            assert (pdo.get("Sm"), pdo.get("Mandatory"), pdo.get("Fixed")) == ((sm, "1", "0") if c < 8 else
                                                                               (None, "0", "0"))
            entries = [(_int(e.findtext("Index")), _int(e.findtext("SubIndex")), _int(e.findtext("BitLen")),
                        e.findtext("DataType")) for e in pdo.findall("Entry")]
            assert entries == [(obj + c * 0x80 + u * 0x10, 1, 128, "STRING(16)") for u in range(8)]
    mailbox = device.find("Mailbox")
    assert mailbox is not None
    coe = mailbox.find("CoE")
    assert coe is not None and mailbox.find("FoE") is not None
    assert {k: coe.get(k) for k in ("SdoInfo", "PdoAssign", "PdoConfig", "CompleteAccess")} == dict.fromkeys(
        ("SdoInfo", "PdoAssign", "PdoConfig", "CompleteAccess"), "1")
    assert _int(device.findtext("Eeprom/ByteSize")) == len(slave.sii) == 2048
    assert device.findtext("Eeprom/ConfigData") == bytes(slave.sii[:14]).hex().upper()
