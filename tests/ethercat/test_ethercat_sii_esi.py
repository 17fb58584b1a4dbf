"""SII image and ESI export built from one device description, and the pcap writer."""

from __future__ import annotations

import io
import shutil
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from gatewaylab.devices.ethercat_io.device import PRODUCT_CODE, VENDOR_ID, io_description
from gatewaylab.ethercat.esc import sii_checksum
from gatewaylab.ethercat.esi import export_esi
from gatewaylab.ethercat.sii import Category, build_sii, parse_sii
from gatewaylab.ethercat.wire_pcap import PcapWriter, read_pcap


def test_sii_layout_identity_mailbox_and_categories() -> None:
    """SII words 0x08..0x0F identity, 0x18..0x1C mailbox offsets/sizes/protocols, categories Strings,
    General, FMMU, SyncManager, TxPDO, RxPDO (shared notes 'SII EEPROM content SOEM needs')."""
    desc = io_description("GL-IO test", serial=77)
    img = build_sii(desc, alias=0x0042)
    assert img[14] == sii_checksum(img[:14])
    info = parse_sii(img)
    assert (info.vendor_id, info.product_code, info.serial, info.alias) == (VENDOR_ID, PRODUCT_CODE, 77, 0x42)
    assert info.mailbox_out == (0x1000, 128) and info.mailbox_in == (0x1080, 128)
    assert info.mailbox_protocols == 0x0C  # CoE + FoE
    assert info.name == "GL-IO test"
    assert list(info.categories) == [Category.STRINGS, Category.GENERAL, Category.FMMU, Category.SYNC_MANAGER,
                                     Category.TXPDO, Category.RXPDO]
    assert [sm[4] for sm in info.sync_managers] == [1, 2, 3, 4]
    assert info.sync_managers[2][:2] == (0x1100, 5) and info.sync_managers[3][:2] == (0x1400, 9)
    assert info.coe_details & 0x01 and info.coe_details & 0x20 and info.foe_details == 1


def test_esi_export_is_wellformed_and_matches_the_sii() -> None:
    """ESI (ETG.2000): vendor, device type with product code and revision, SMs, PDOs, mailbox, dictionary."""
    desc = io_description()
    root = ET.fromstring(export_esi(desc))
    assert root.tag == "EtherCATInfo"
    assert root.findtext("Vendor/Id") == f"#x{VENDOR_ID:08X}"
    dev = root.find("Descriptions/Devices/Device")
    assert dev is not None
    t = dev.find("Type")
    assert t is not None and t.get("ProductCode") == f"#x{PRODUCT_CODE:08X}" and t.get("RevisionNo") == "#x00000001"
    sms = dev.findall("Sm")
    assert [sm.text for sm in sms] == ["MBoxOut", "MBoxIn", "Outputs", "Inputs"]
    assert [sm.get("ControlByte") for sm in sms] == ["#x26", "#x22", "#x64", "#x20"]
    rx = dev.find("RxPdo")
    assert rx is not None and rx.findtext("Index") == "#x1600" and len(rx.findall("Entry")) == 3
    assert dev.find("Mailbox/CoE") is not None and dev.find("Mailbox/FoE") is not None
    objects = {o.findtext("Index"): o for o in dev.findall("Profile/Dictionary/Objects/Object")}
    assert {"#x1000", "#x1018", "#x1C12", "#x1C13", "#x1600", "#x1A00", "#x7010"} <= set(objects)
    assert objects["#x1018"].findtext("Type") == "DT1018"
    config = dev.findtext("Eeprom/ConfigData")
    assert config is not None and bytes.fromhex(config) == build_sii(desc)[:14]


def test_pcap_writer_global_header_and_records() -> None:
    """pcap: magic 0xA1B2C3D4, version 2.4, link type 1 (Ethernet); one record per frame."""
    out = io.BytesIO()
    w = PcapWriter(out)
    w.write(1.5, b"\xff" * 6 + b"\x02" * 6 + b"\x88\xa4" + bytes(46))
    w.write(2.25, b"\x01" * 60)
    w.flush()
    raw = out.getvalue()
    assert raw[:4] == bytes.fromhex("d4c3b2a1") and raw[20:24] == b"\x01\0\0\0"
    frames = read_pcap(raw)
    assert [t for t, _ in frames] == [1.5, 2.25] and len(frames[0][1]) == 60


def test_wireshark_dissects_captures_as_ethercat(tmp_path: Path) -> None:
    """Captures open in Wireshark's EtherCAT dissector: every frame is ECAT, the mailbox traffic of an
    in-process session decodes as CoE SDO and FoE, nothing is malformed (checked with tshark)."""
    tshark = shutil.which("tshark")
    if tshark is None:
        pytest.skip("tshark (Wireshark) is not installed")
    from gatewaylab.common.clock import SimulatedClock
    from gatewaylab.devices.ethercat_io.device import create_io_slave
    from gatewaylab.ethercat.esc import AlState
    from gatewaylab.ethercat.segment import Segment
    from gatewaylab.hosts.ethercat.master import Master

    path = tmp_path / "inprocess.pcap"
    pcap = PcapWriter(str(path))
    clock = SimulatedClock(start=1_700_000_000.0)
    m = Master(clock, Segment([create_io_slave(clock)]), capture=pcap.write)
    m.bring_up()
    m.set_state(AlState.PREOP)
    m.sdo_upload_str(0, 0x1008)
    m.foe_write(0, "a.bin", b"x" * 10)
    pcap.close()

    def fields(*names: str, display: str = "") -> list[str]:
        cmd = [tshark, "-r", str(path), "-T", "fields"] + [arg for n in names for arg in ("-e", n)]
        if display:
            cmd += ["-Y", display]
        return subprocess.run(cmd, capture_output=True, text=True, check=True).stdout.splitlines()

    frames = fields("frame.protocols")
    assert len(frames) == 2 * m.frames and all("ecat" in f for f in frames)
    assert fields("frame.number", display="_ws.malformed") == []
    assert fields("frame.number", display="ecat_mailbox.coe")
    assert fields("frame.number", display="ecat_mailbox.foe")
