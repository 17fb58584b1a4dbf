"""ECAN-Lite's EtherCAT face as data: identity, SyncManagers (5.3, 15.7), chunk maps (5.1) and the
objects of 0x8010/0x8011 (13.2) and 0x9011 (13.2.4).

One :class:`~gatewaylab.ethercat.description.DeviceDescription` feeds the SII, the ESI and the
dictionary. The process image is 24 RxPDO / TxPDO chunk maps of 8 STRING(16) units each; the
master assigns the first N of them (0x1C12 / 0x1C13) and gets 128 * N contiguous bytes per
direction, which the device treats as one frame-stream buffer.
"""

from __future__ import annotations

from collections.abc import Sequence

from gatewaylab.ethercat.description import DeviceDescription, ObjectDef, Pdo, PdoEntry
from gatewaylab.od import Access, DataType

__all__ = [
    "CHUNKS",
    "CHUNK_BYTES",
    "CYCLE_DIAG",
    "DEFAULT_CHUNKS",
    "DEVICE_NAME",
    "INPUTS_CONTROL",
    "INPUTS_START",
    "OUTPUTS_CONTROL",
    "OUTPUTS_START",
    "PRODUCT_CODE",
    "REVISION",
    "RX_MAP",
    "RX_PROFILE",
    "RX_UNIT",
    "SI_CYCLE_CLEAR",
    "SM_SIZE",
    "TX_MAP",
    "TX_PROFILE",
    "TX_UNIT",
    "UNITS_PER_CHUNK",
    "UNIT_BYTES",
    "VENDOR_ID",
    "cycle_object",
    "ecanlite_description",
    "profile_object",
    "unit_index",
]


#: 'GWLB', the gatewaylab vendor id of the emulated devices (not ETG-assigned, see docs/decisions.md).
VENDOR_ID = 0x47574C42
#: 'ECLT'.
PRODUCT_CODE = 0x45434C54
#: Manual V2.2.
REVISION = 0x00020002
DEVICE_NAME = "ECAN-Lite"

CHUNKS = 24
UNITS_PER_CHUNK = 8
UNIT_BYTES = 16
CHUNK_BYTES = UNITS_PER_CHUNK * UNIT_BYTES
#: SII/ESI SM2/SM3 size (5.3): the largest image; the master's assignment picks the used length.
SM_SIZE = CHUNKS * CHUNK_BYTES
OUTPUTS_START = 0x1100
INPUTS_START = 0x1D00
OUTPUTS_CONTROL = 0x66  # 1-buffer, ECAT writes, PDI interrupt, watchdog
INPUTS_CONTROL = 0x22   # 1-buffer, ECAT reads, PDI interrupt

RX_MAP = 0x1600
TX_MAP = 0x1A00
RX_UNIT = 0x7000
TX_UNIT = 0x6000
TX_PROFILE = 0x8010
RX_PROFILE = 0x8011
CYCLE_DIAG = 0x9011
DEFAULT_CHUNKS = 8

# 0x8010 / 0x8011 subindexes (13.2)
SI_APPLY, SI_STATUS, SI_MULTIPLIER, SI_MASK, SI_PROFILE, SI_BUDGET, SI_OPTIONS, SI_COMMAND = range(1, 9)
SI_ACTIVE_BYTES, SI_ACTIVE_AREA, SI_LAYOUT_CRC, SI_PROFILE_WORD, SI_SEQUENCE = range(9, 14)
SI_LAST_ERROR, SI_ERROR_COUNTER, SI_OVERFLOW_COUNTER = range(14, 17)
#: 0x9011:14 clear command.
SI_CYCLE_CLEAR = 14


def unit_index(base: int, chunk: int, unit: int) -> int:
    """Data object of mapping unit ``unit`` of chunk ``chunk`` (5.1.1: base + c * 0x80 + u * 0x10)."""
    return base + chunk * 0x80 + unit * 0x10


def _chunks(map_base: int, unit_base: int, access: Access, what: str) -> tuple[tuple[Pdo, ...], list[ObjectDef]]:
    pdos: list[Pdo] = []
    objects: list[ObjectDef] = []
    for c in range(CHUNKS):
        entries = []
        for u in range(UNITS_PER_CHUNK):
            index = unit_index(unit_base, c, u)
            name = f"{what} chunk {c} unit {u}"
            # SII string indexes are one byte: entry and PDO names repeat across chunks/directions.
            entries.append(PdoEntry(index, 1, 8 * UNIT_BYTES, f"Unit {u}", DataType.VISIBLE_STRING))
            objects.append(ObjectDef(index, name, subs=((f"{what} bytes {(c * 8 + u) * 16}..{(c * 8 + u) * 16 + 15}",
                                                         DataType.VISIBLE_STRING, "\0" * UNIT_BYTES, access),),
                                     pdo_mappable=True))
        pdos.append(Pdo(map_base + c, f"Chunk {c}", tuple(entries)))
    return tuple(pdos), objects


_U8, _U16, _U32, _I32 = DataType.UNSIGNED8, DataType.UNSIGNED16, DataType.UNSIGNED32, DataType.INTEGER32
_RW, _RO = Access.RW, Access.RO


def profile_object(index: int, name: str) -> ObjectDef:
    """0x8010 / 0x8011 PDO Profile Control (13.2); the active readback starts at the default profile
    (9.2: N 8, mask 0x0F, profile 0, Balanced, options 0), which is active at power-on."""
    return ObjectDef(index, name, subs=(
        ("Apply command", _U8, 0, _RW),
        ("Status", _U8, 0, _RO),
        ("PDO size multiplier", _U8, DEFAULT_CHUNKS, _RW),
        ("Channel mask", _U8, 0x0F, _RW),
        ("Encapsulation profile", _U8, 0, _RW),
        ("Budget policy", _U8, 0, _RW),
        ("Option flags", _U8, 0, _RW),
        ("Command", _U8, 0, _RW),
        ("Active PDO bytes", _U16, 0, _RO),
        ("Active frame area bytes", _U16, 0, _RO),
        ("Active layout CRC", _U32, 0, _RO),
        ("Active profile word", _U32, 0, _RO),
        ("Packet sequence", _U16, 0, _RO),
        ("Last PDO error", _U16, 0, _RO),
        ("PDO error counter", _U32, 0, _RO),
        ("PDO overflow counter", _U32, 0, _RO),
    ))


def cycle_object() -> ObjectDef:
    """0x9011 Cycle Performance Diagnostics (13.2.4): counts, phases and costs in CPU cycles."""
    subs: list[tuple[str, DataType, int | float | str | bytes, Access]] = [
        ("PDI IRQ count", _U32, 0, _RO), ("Sync0 IRQ count", _U32, 0, _RO), ("Sync1 IRQ count", _U32, 0, _RO),
        ("PDI to Sync0 phase min", _I32, 0, _RO), ("PDI to Sync0 phase max", _I32, 0, _RO),
        ("APPL OutputMapping max cycles", _U32, 0, _RO), ("APPL InputMapping max cycles", _U32, 0, _RO),
        ("MCAN PDO service max cycles", _U32, 0, _RO), ("TxPDO shadow max cycles", _U32, 0, _RO),
        ("RxPDO parse max cycles", _U32, 0, _RO), ("ESC read max cycles", _U32, 0, _RO),
        ("ESC write max cycles", _U32, 0, _RO), ("Schedule service max cycles", _U32, 0, _RO),
        ("Clear command", _U8, 0, _RW), ("ReservedPad", _U8, 0, _RO)]
    subs += [(f"Reserved{i}", _U32, 0, _RO) for i in range(9)]
    return ObjectDef(CYCLE_DIAG, "Cycle Performance Diagnostics", subs=tuple(subs))


def ecanlite_description(extra_objects: Sequence[ObjectDef] = (), *, name: str = DEVICE_NAME, serial: int = 0,
                         software_version: str = "1.0.0") -> DeviceDescription:
    """The ECAN-Lite slave: identity, 1-buffer SM2/SM3 of 3072 B (5.3), 24 + 24 chunk maps with the
    first 8 assigned (9.2 default), 0x8010/0x8011/0x9011 plus ``extra_objects`` (the MCAN model's)."""
    rx, rx_objs = _chunks(RX_MAP, RX_UNIT, Access.RWW, "RxPDO")
    tx, tx_objs = _chunks(TX_MAP, TX_UNIT, Access.RO, "TxPDO")
    return DeviceDescription(
        name=name, vendor_id=VENDOR_ID, product_code=PRODUCT_CODE, revision=REVISION, serial=serial,
        order_code="ECAN-LITE-4CANFD", hardware_version="HPM5E00", software_version=software_version,
        outputs_start=OUTPUTS_START, inputs_start=INPUTS_START,
        outputs_control=OUTPUTS_CONTROL, inputs_control=INPUTS_CONTROL,
        outputs_sm_size=SM_SIZE, inputs_sm_size=SM_SIZE,
        rx_pdos=rx, tx_pdos=tx,
        rx_assign=tuple(RX_MAP + c for c in range(DEFAULT_CHUNKS)),
        tx_assign=tuple(TX_MAP + c for c in range(DEFAULT_CHUNKS)),
        objects=(*tx_objs, *rx_objs, profile_object(TX_PROFILE, "TxPDO Profile Control"),
                 profile_object(RX_PROFILE, "RxPDO Profile Control"), cycle_object(), *extra_objects),
    )
