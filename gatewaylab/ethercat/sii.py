"""SII EEPROM image built from a device description, and a parser for it (ETG.2010 layout).

Words 0..7 are the ESC configuration area (checksum in word 7), 8..0x0F the identity,
0x14..0x1C the mailbox configuration, 0x3E/0x3F size and version; categories start at word
0x40: Strings (10), General (30), FMMU (40), SyncManager (41), TxPDO (50), RxPDO (51), end 0xFFFF.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass

from gatewaylab.ethercat.description import DeviceDescription, Pdo
from gatewaylab.ethercat.errors import FrameFormatError
from gatewaylab.ethercat.esc import sii_checksum

__all__ = [
    "CATEGORY_HEADER",
    "EEPROM_BYTES",
    "GENERAL",
    "MAX_EEPROM_BYTES",
    "PDO_ENTRY",
    "PDO_HEADER",
    "SM_ENTRY",
    "U16",
    "U32",
    "Category",
    "SiiInfo",
    "SmType",
    "build_sii",
    "parse_sii",
]


U16 = struct.Struct("<H")
U32 = struct.Struct("<I")
CATEGORY_HEADER = struct.Struct("<HH")
GENERAL = struct.Struct("<BBBBBBBBBBBBhBBHH12x")
SM_ENTRY = struct.Struct("<HHBBBB")
PDO_HEADER = struct.Struct("<HBBBBH")
PDO_ENTRY = struct.Struct("<HBBBBH")
EEPROM_BYTES = 2048
MAX_EEPROM_BYTES = 65536


class Category(enum.IntEnum):
    """SII category types after the fixed words (ETG.1000.6 table 'Category Types')."""

    STRINGS = 10
    DATA_TYPES = 20
    GENERAL = 30
    FMMU = 40
    SYNC_MANAGER = 41
    TXPDO = 50
    RXPDO = 51
    DC = 60
    END = 0xFFFF


class SmType(enum.IntEnum):
    """What a SyncManager is for, in the SII SyncManager category (ETG.1000.6 'Sync Manager')."""

    UNUSED = 0
    MAILBOX_OUT = 1
    MAILBOX_IN = 2
    OUTPUTS = 3
    INPUTS = 4


class _Strings:
    def __init__(self) -> None:
        self.items: list[bytes] = []

    def add(self, text: str) -> int:
        """1-based string index; 0 means 'no string'."""
        if not text:
            return 0
        raw = text.encode("latin-1", "replace")[:255]
        if raw in self.items:
            return self.items.index(raw) + 1
        self.items.append(raw)
        return len(self.items)

    def encode(self) -> bytes:
        out = bytearray([len(self.items)])
        for s in self.items:
            out.append(len(s))
            out.extend(s)
        return bytes(out)


def _category(kind: int, data: bytes) -> bytes:
    if len(data) % 2:
        data += b"\x00"
    return CATEGORY_HEADER.pack(kind, len(data) // 2) + data


def _pdos(assigned: tuple[Pdo, ...], sm: int, strings: _Strings) -> bytes:
    """PDO category: the PDOs assigned at power-on, the default a master without CoE uses. The
    alternatives a CoE master may assign are in the ESI only: masters read the SII 4 bytes per
    round trip (KickCAT), so every listed PDO lengthens their scan (docs/decisions.md)."""
    out = bytearray()
    for pdo in assigned:
        out += PDO_HEADER.pack(pdo.index, len(pdo.entries), sm, 0, strings.add(pdo.name), 0)
        for e in pdo.entries:
            out += PDO_ENTRY.pack(e.index, e.subindex, strings.add(e.name) if e.index else 0,
                                  int(e.data_type) if e.index else 0, e.bit_length, 0)
    return bytes(out)


def _given_image(desc: DeviceDescription, alias: int) -> bytes:
    """``desc.sii_image`` as given, with the alias (word 4, checksum again) and a serial set by the rig."""
    assert desc.sii_image is not None
    img = bytearray(desc.sii_image)
    if alias:
        U16.pack_into(img, 8, alias)
        img[14] = sii_checksum(bytes(img[:14]))
    if desc.serial:
        U32.pack_into(img, 0x1C, desc.serial)
    return bytes(img)


def build_sii(desc: DeviceDescription, alias: int = 0) -> bytes:
    """The EEPROM content a real slave of this description would carry."""
    if desc.sii_image is not None:
        return _given_image(desc, alias)
    img = bytearray(b"\xff" * 0x80)
    cfg = bytearray(16)
    if desc.sii_config is not None:
        cfg[:14] = desc.sii_config[:14].ljust(14, b"\0")
    else:
        U16.pack_into(cfg, 0, 0x0C08)  # PDI control: 16-bit uC async PDI, ESC config 0x0C (enhanced link)
    if desc.sii_config is None or alias:
        U16.pack_into(cfg, 8, alias)
    cfg[14] = sii_checksum(bytes(cfg[:14]))
    img[0:16] = cfg
    body = bytearray(0x80 - 0x10)
    U32.pack_into(body, 0x00, desc.vendor_id)
    U32.pack_into(body, 0x04, desc.product_code)
    U32.pack_into(body, 0x08, desc.revision)
    U32.pack_into(body, 0x0C, desc.serial)
    if desc.bootstrap:
        bo, bos, bi, bis = desc.bootstrap_mailbox
        struct.pack_into("<HHHH", body, 0x28 - 0x10, bo, bos, bi, bis)
    if desc.has_mailbox:
        struct.pack_into("<HHHHH", body, 0x30 - 0x10,
                         desc.mailbox_out[0], desc.mailbox_out[1],
                         desc.mailbox_in[0], desc.mailbox_in[1], desc.mailbox_protocols)
    size_at = 0x7C - 0x10
    U16.pack_into(body, 0x7E - 0x10, 1)
    img[0x10:0x80] = body

    strings = _Strings()
    name_idx = strings.add(desc.name)
    group_idx = strings.add(desc.group)
    order_idx = strings.add(desc.order_code or desc.name)
    coe_details = 0
    if desc.coe:  # SDO, SDO info, PDO assign/config, CA unless the description says otherwise
        coe_details = (0x01 | 0x02 | 0x04 | 0x08 | 0x20) if desc.coe_details is None else desc.coe_details
    general = GENERAL.pack(group_idx, 0, order_idx, name_idx, 0, coe_details, 1 if desc.foe else 0,
                           0, 0, 0, 0, 0, 0, group_idx, 0, 0x0011, 0)
    has_mbx = desc.has_mailbox
    fmmu = bytes([1, 2, 3 if has_mbx else 0, 0])
    sms = bytearray()
    if has_mbx:
        sms += SM_ENTRY.pack(desc.mailbox_out[0], desc.mailbox_out[1], DeviceDescription.SM0_CONTROL, 0, 1,
                             SmType.MAILBOX_OUT)
        sms += SM_ENTRY.pack(desc.mailbox_in[0], desc.mailbox_in[1], DeviceDescription.SM1_CONTROL, 0, 1,
                             SmType.MAILBOX_IN)
    if not desc.inputs_first or has_mbx:
        sms += SM_ENTRY.pack(desc.outputs_start, desc.outputs_sii_size, desc.outputs_control, 0,
                             1 if desc.outputs_sii_size else 0, SmType.OUTPUTS)
    sms += SM_ENTRY.pack(desc.inputs_start, desc.inputs_sii_size, desc.inputs_control, 0,
                         1 if desc.inputs_sii_size else 0, SmType.INPUTS)
    sm_out, sm_in = desc.sm_numbers
    txpdo = _pdos(desc.assigned_tx_pdos, sm_in, strings)
    rxpdo = _pdos(desc.assigned_rx_pdos, sm_out, strings)
    cats = bytearray()
    cats += _category(Category.STRINGS, strings.encode())
    cats += _category(Category.GENERAL, general)
    cats += _category(Category.FMMU, fmmu)
    cats += _category(Category.SYNC_MANAGER, bytes(sms))
    if txpdo:
        cats += _category(Category.TXPDO, txpdo)
    if rxpdo:
        cats += _category(Category.RXPDO, rxpdo)
    for kind, data in desc.sii_categories:
        cats += _category(kind, data)
    cats += U16.pack(Category.END)
    size = EEPROM_BYTES if desc.eeprom_bytes is None else max(128, desc.eeprom_bytes)
    while size < 0x80 + len(cats):
        size *= 2  # the smallest EEPROM (2 KB = 16 kbit and up) that holds the categories
    if size > MAX_EEPROM_BYTES:
        raise FrameFormatError(f"SII of {desc.name} needs {0x80 + len(cats)} bytes, more than any EEPROM")
    U16.pack_into(body, size_at, size * 8 // 1024 - 1)
    img[0x10:0x80] = body
    img += cats
    img += b"\xff" * (size - len(img))
    return bytes(img)


@dataclass(frozen=True, slots=True)
class SiiInfo:
    """What a master reads back from an SII image."""

    vendor_id: int
    product_code: int
    revision: int
    serial: int
    alias: int
    mailbox_out: tuple[int, int]
    mailbox_in: tuple[int, int]
    mailbox_protocols: int
    strings: tuple[str, ...]
    name: str
    categories: tuple[int, ...]
    sync_managers: tuple[tuple[int, int, int, int, int], ...]
    coe_details: int
    foe_details: int
    bootstrap_mailbox: tuple[int, int, int, int] = (0, 0, 0, 0)


def parse_sii(img: bytes) -> SiiInfo:
    """Decode identity, mailbox and categories (raises FrameFormatError on a broken image)."""
    if len(img) < 0x82:
        raise FrameFormatError("SII image shorter than its fixed header")
    vendor, product, revision, serial = struct.unpack_from("<IIII", img, 0x10)
    mo, mos, mi, mis, proto = struct.unpack_from("<HHHHH", img, 0x30)
    boot = struct.unpack_from("<HHHH", img, 0x28)
    pos = 0x80
    strings: list[str] = []
    cats: list[int] = []
    sms: list[tuple[int, int, int, int, int]] = []
    name = ""
    coe = foe = 0
    general: bytes | None = None
    while pos + 4 <= len(img):
        kind, words = CATEGORY_HEADER.unpack_from(img, pos)
        if kind == Category.END:
            break
        data = img[pos + 4:pos + 4 + 2 * words]
        if len(data) < 2 * words:
            raise FrameFormatError("SII category runs past the image")
        cats.append(kind)
        if kind == Category.STRINGS:
            n = data[0]
            p = 1
            for _ in range(n):
                ln = data[p]
                strings.append(bytes(data[p + 1:p + 1 + ln]).decode("latin-1"))
                p += 1 + ln
        elif kind == Category.GENERAL:
            general = bytes(data)
        elif kind == Category.SYNC_MANAGER:
            for p in range(0, len(data) - 7, 8):
                start, length, ctrl, _st, enable, smtype = SM_ENTRY.unpack_from(data, p)
                sms.append((start, length, ctrl, enable, smtype))
        pos += 4 + 2 * words
    if general is not None:
        name_idx = general[3]
        coe, foe = general[5], general[6]
        if 0 < name_idx <= len(strings):
            name = strings[name_idx - 1]
    return SiiInfo(vendor, product, revision, serial, U16.unpack_from(img, 8)[0], (mo, mos), (mi, mis), proto,
                   tuple(strings), name, tuple(cats), tuple(sms), coe, foe,
                   boot if boot[1] not in (0, 0xFFFF) else (0, 0, 0, 0))
