"""The SII of every EtherCAT device kind as KickCAT 2.5 reads it (``Bus::fetchEeprom``): a read command
{0x0100, word address, 0} to 0x0502, 0x0502 polled until not busy, 4 bytes from 0x0508, two words further
each time, until a 4-byte read after the first 128 bytes holds 0xFFFF. Three frames with a deadline (the
link timeout) and one whole link timeout per 4 bytes: the ECAN-Lite's SII of 3978 bytes (all 48 chunk
PDOs listed) took 995 reads and a Python slave on a loaded machine missed a deadline on the way ("Error
while fetching eeprom data" / "Timeout"). ETG.2010 layout; ET1100 data sheet for 0x0502."""

from __future__ import annotations

import dataclasses
import struct
import xml.etree.ElementTree as ET
from collections.abc import Callable
from pathlib import Path

import pytest

from gatewaylab.bus import VirtualBus
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.ecanlite.device import EcanLiteDevice
from gatewaylab.devices.ecanlite.image import ecanlite_description
from gatewaylab.devices.esd_can_ethercat.device import EsdGateway
from gatewaylab.devices.ethercat_drive import EthercatDrive
from gatewaylab.devices.ethercat_io.device import create_io_slave
from gatewaylab.ethercat.esi import export_esi
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.sii import Category, parse_sii
from gatewaylab.ethercat.slave import Slave
from gatewaylab.hosts.ethercat.master import Master

END = 0xFFFF
#: A 16 kbit EEPROM (ETG.2010 word 0x3E = 15), the smallest an ESC loads: at most 512 KickCAT reads.
SMALL_EEPROM = 2048


def _ecanlite(clock: SimulatedClock, tmp: Path) -> Slave:
    buses = [VirtualBus(clock, f"can{i}", 1_000_000, 5_000_000) for i in range(4)]
    return EcanLiteDevice(clock, [b.attach(f"mcan{i}") for i, b in enumerate(buses)], flash_path=tmp / "f").slave


KINDS: dict[str, Callable[[SimulatedClock, Path], Slave]] = {
    "ecanlite": _ecanlite,
    "ethercat_io": lambda clock, _tmp: create_io_slave(clock),
    "ethercat_drive": lambda clock, _tmp: EthercatDrive(clock, "GL-Drive CiA402").slave,
    "esd_can_ethercat": lambda clock, _tmp: EsdGateway(clock, VirtualBus(clock, "can0", 1_000_000)).slave,
}


def kickcat_fetch(master: Master, station: int) -> tuple[bytes, list[int]]:
    """The SII bytes KickCAT collects, and 0x0502 as it read it after each command."""
    dwords: list[int] = []
    control: list[int] = []
    word = 0
    while True:
        master.fpwr(station, 0x0502, struct.pack("<HHH", 0x0100, word, 0))
        control.append(struct.unpack("<H", master.fprd(station, 0x0502, 2))[0])
        dwords.append(struct.unpack("<I", master.fprd(station, 0x0508, 4))[0])
        word += 2
        last = dwords[-1]
        if (last >> 16 == END or last & 0xFFFF == END) and len(dwords) > 32:
            return struct.pack(f"<{len(dwords)}I", *dwords), control


def categories(img: bytes) -> tuple[list[tuple[int, int]], int]:
    """(kind, byte offset) of every category and the offset of the End marker."""
    out = []
    pos = 0x80
    while True:
        kind, words = struct.unpack_from("<HH", img, pos)
        if kind == END:
            return out, pos
        out.append((kind, pos))
        pos += 4 + 2 * words


def pdo_bits(img: bytes, offset: int) -> list[tuple[int, int, int]]:
    """(PDO index, SyncM, bits) of every PDO of the category at ``offset`` (ETG.2010 Table 14)."""
    words = struct.unpack_from("<H", img, offset + 2)[0]
    data = img[offset + 4:offset + 4 + 2 * words]
    out = []
    p = 0
    while p + 8 <= len(data):
        index, n, sm = struct.unpack_from("<HBB", data, p)
        p += 8
        bits = sum(data[p + 8 * k + 5] for k in range(n))
        p += 8 * n
        out.append((index, sm, bits))
    return out


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_kickcat_reads_the_whole_sii_quickly_and_exactly(kind: str, tmp_path: Path) -> None:
    """ETG.2010: KickCAT's 4-byte scan of the SII stops at the End category (no 0xFFFF word inside a
    category cuts it short), within a 16 kbit EEPROM (<= 512 reads, word 0x3E = 15), and parses as the
    whole image does; the ESC answers every read not busy, without error, with 0x0502 bits 5..7 left as
    the hardware sets them (8-byte reads, one address byte) although the master writes them as 0. The PDO
    categories list the PDOs assigned at power-on, each on SM2/SM3, adding up to the default process
    image (what KickCAT without CoE, or IgH's SII defaults, would map)."""
    clock = SimulatedClock()
    slave = KINDS[kind](clock, tmp_path)
    master = Master(clock, Segment([slave]))
    master.scan()
    station = master.slaves[0].station
    image = bytes(slave.sii)
    read, control = kickcat_fetch(master, station)

    cats, end = categories(image)
    assert len(read) == (end // 4 + 1) * 4, "the scan stops exactly at the End category"
    assert read == image[:len(read)]
    assert len(read) <= SMALL_EEPROM and len(image) == SMALL_EEPROM
    assert struct.unpack_from("<H", image, 0x7C)[0] == SMALL_EEPROM * 8 // 1024 - 1
    assert all(c == 0x0040 for c in control), [hex(c) for c in control if c != 0x0040][:3]
    whole, got = parse_sii(image), parse_sii(read)
    assert got == whole and got.name == slave.desc.name
    assert [k for k, _ in cats] == [Category.STRINGS, Category.GENERAL, Category.FMMU, Category.SYNC_MANAGER,
                                    Category.TXPDO, Category.RXPDO]

    desc = slave.desc
    offsets = dict(cats)
    tx, rx = pdo_bits(image, offsets[Category.TXPDO]), pdo_bits(image, offsets[Category.RXPDO])
    assert [p[0] for p in tx] == [p.index for p in desc.assigned_tx_pdos]
    assert [p[0] for p in rx] == [p.index for p in desc.assigned_rx_pdos]
    assert {p[1] for p in tx} == {3} and {p[1] for p in rx} == {2}
    assert sum(p[2] for p in tx) == 8 * desc.input_bytes and sum(p[2] for p in rx) == 8 * desc.output_bytes


def test_sii_control_configuration_bits_are_read_only() -> None:
    """ET1100 0x0502 bits 5..7 are configuration, read-only: a slave whose SII needs more than 16 kbit
    (all 24 ECAN-Lite chunks assigned) shows 'two address bytes' (bit 7) and 8-byte reads (bit 6), and
    still does after a master wrote the control word with those bits 0 (KickCAT's read command 0x0100)."""
    clock = SimulatedClock()
    desc = dataclasses.replace(ecanlite_description(), rx_assign=tuple(range(0x1600, 0x1618)),
                               tx_assign=tuple(range(0x1A00, 0x1A18)))
    slave = Slave(clock, desc)
    assert len(slave.sii) > SMALL_EEPROM
    master = Master(clock, Segment([slave]))
    master.scan()
    station = master.slaves[0].station
    for word in (0, 0x40, len(slave.sii) // 2 - 2):
        master.fpwr(station, 0x0502, struct.pack("<HHH", 0x0100, word, 0))
        assert struct.unpack("<H", master.fprd(station, 0x0502, 2))[0] == 0x00C0
        assert master.fprd(station, 0x0508, 4) == bytes(slave.sii[2 * word:2 * word + 4])


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_esi_of_every_kind_is_well_formed(kind: str, tmp_path: Path) -> None:
    """ETG.2000: the ESI is XML 1.0 (no NUL in a DefaultString: empty STRING(16) units go out as hex
    DefaultData), and its Eeprom element gives the SII's size and configuration area."""
    slave = KINDS[kind](SimulatedClock(), tmp_path)
    root = ET.fromstring(export_esi(slave.desc, slave.od))
    assert root.findtext("Descriptions/Devices/Device/Eeprom/ByteSize") == str(len(slave.sii))
    assert root.findtext("Descriptions/Devices/Device/Eeprom/ConfigData") == bytes(slave.sii[:14]).hex().upper()
