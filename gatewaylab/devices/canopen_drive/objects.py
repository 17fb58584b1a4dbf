"""The object dictionary of the maxon IDX-like CiA 402 drive: identity, default PDO mapping, profile rows.

:func:`build_object_dictionary` makes the whole dictionary of the CANopen drive (identity 0x1018,
communication objects, a typical servo's default PDO mapping, the rows of
:func:`add_profile_objects`); the EtherCAT drive serves the same profile rows from its slave's
dictionary (CoE, ETG.6010). What the rows mean at run time is the drive's (:mod:`.device`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from gatewaylab.canopen.cia402 import SUPPORTED_MODES, OpMode
from gatewaylab.canopen.communication import add_communication_objects, add_mapping
from gatewaylab.devices.canopen_drive.plant import AxisParams
from gatewaylab.od import Access, DataType, ObjectDictionary

__all__ = [
    "DEVICE_NAME",
    "DEVICE_TYPE",
    "MAXON_VENDOR_ID",
    "PRODUCT_CODE",
    "REVISION",
    "RPDO_DEFAULTS",
    "TPDO_DEFAULTS",
    "PdoDefault",
    "add_profile_objects",
    "build_object_dictionary",
]


#: Vendor-ID 0x1018:01 of maxon motor ag (CiA vendor list; the IDX answers it in LSS too).
MAXON_VENDOR_ID = 0x000000FB
#: Product code of the emulated drive (the IDX guide gives none; see the decisions file).
PRODUCT_CODE = 0x61500000
REVISION = 0x00010000
#: CiA 402 device type: profile 402 (0x0192) with 'servo drive' in the additional information.
DEVICE_TYPE = 0x00020192
DEVICE_NAME = "IDX 56 M CANopen (gatewaylab)"


@dataclass(frozen=True, slots=True)
class PdoDefault:
    """One default PDO: mapped (index, sub, bits) and whether it is valid (COB-ID bit 31 = 0)."""

    entries: tuple[tuple[int, int, int], ...]
    enabled: bool = True


#: Default mapping of a typical CiA 402 servo (RPDO1 controlword + target position, TPDO1
#: statusword + position actual value, ...); all remappable per CiA 301.
RPDO_DEFAULTS: tuple[PdoDefault, ...] = (
    PdoDefault(((0x6040, 0, 16), (0x607A, 0, 32))),
    PdoDefault(((0x6040, 0, 16), (0x60FF, 0, 32))),
    PdoDefault(((0x6040, 0, 16), (0x6071, 0, 16))),
    PdoDefault(((0x6060, 0, 8),)),
)
TPDO_DEFAULTS: tuple[PdoDefault, ...] = (
    PdoDefault(((0x6041, 0, 16), (0x6064, 0, 32))),
    PdoDefault(((0x6041, 0, 16), (0x606C, 0, 32)), enabled=False),
    PdoDefault(((0x6041, 0, 16), (0x6077, 0, 16)), enabled=False),
    PdoDefault(((0x6041, 0, 16), (0x6061, 0, 8), (0x60F4, 0, 32)), enabled=False),
)


def build_object_dictionary(serial: int, node_id: int | None, device_name: str = DEVICE_NAME,
                            params: AxisParams | None = None) -> ObjectDictionary:
    """The drive's object dictionary: identity, CiA 402 and maxon objects, default PDOs."""
    p = params or AxisParams()
    od = ObjectDictionary(node_id)
    u8, u16, u32 = DataType.UNSIGNED8, DataType.UNSIGNED16, DataType.UNSIGNED32
    RO, RW, CONST = Access.RO, Access.RW, Access.CONST

    def var(index: int, name: str, dt: DataType, access: Access, default: Any = None,
            mappable: bool = False, low: float | None = None, high: float | None = None) -> None:
        od.add_variable(index, name, dt, access, default, pdo_mappable=mappable, low=low, high=high)

    var(0x1000, "Device type", u32, RO, DEVICE_TYPE)
    var(0x1008, "Manufacturer device name", DataType.VISIBLE_STRING, CONST, device_name)
    var(0x1009, "Manufacturer hardware version", DataType.VISIBLE_STRING, CONST, "6550h")
    var(0x100A, "Manufacturer software version", DataType.VISIBLE_STRING, CONST, "0170h")
    od.add_record(0x1018, "Identity object")
    od.add_sub(0x1018, 1, "Vendor-ID", u32, RO, MAXON_VENDOR_ID)
    od.add_sub(0x1018, 2, "Product code", u32, RO, PRODUCT_CODE)
    od.add_sub(0x1018, 3, "Revision number", u32, RO, REVISION)
    od.add_sub(0x1018, 4, "Serial number", u32, RO, serial)
    for n, pdo in enumerate(RPDO_DEFAULTS):
        od.add_record(0x1400 + n, f"RPDO{n + 1} communication parameter")
        od.add_sub(0x1400 + n, 1, "COB-ID used by RPDO", u32, RW,
                   (0x200 + 0x100 * n) | (0 if pdo.enabled else 0x80000000), nodeid_offset=True)
        od.add_sub(0x1400 + n, 2, "Transmission type", u8, RW, 255)
        add_mapping(od, 0x1600 + n, f"RPDO{n + 1} mapping parameter", pdo.entries)
    for n, pdo in enumerate(TPDO_DEFAULTS):
        idx = 0x1800 + n
        od.add_record(idx, f"TPDO{n + 1} communication parameter")
        od.add_sub(idx, 1, "COB-ID used by TPDO", u32, RW,
                   (0x180 + 0x100 * n) | (0 if pdo.enabled else 0x80000000), nodeid_offset=True)
        od.add_sub(idx, 2, "Transmission type", u8, RW, 255)
        od.add_sub(idx, 3, "Inhibit time", u16, RW, 0)
        od.add_sub(idx, 5, "Event timer", u16, RW, 0)
        od.add_sub(idx, 6, "SYNC start value", u8, RW, 0)
        add_mapping(od, 0x1A00 + n, f"TPDO{n + 1} mapping parameter", pdo.entries)
    add_profile_objects(od, p)
    add_communication_objects(od)
    return od


def add_profile_objects(od: ObjectDictionary, params: AxisParams | None = None) -> None:
    """The drive's own rows: the maxon objects and the CiA 402 profile (0x2006..0x6502). The
    CANopen drive adds them to its node's dictionary; the EtherCAT drive (CoE, ETG.6010) serves the
    same rows from its slave's dictionary."""
    p = params or AxisParams()
    u8, u16, u32 = DataType.UNSIGNED8, DataType.UNSIGNED16, DataType.UNSIGNED32
    i8, i16, i32 = DataType.INTEGER8, DataType.INTEGER16, DataType.INTEGER32
    RO, RW = Access.RO, Access.RW

    def var(index: int, name: str, dt: DataType, access: Access, default: Any = None,
            mappable: bool = False, low: float | None = None, high: float | None = None) -> None:
        od.add_variable(index, name, dt, access, default, pdo_mappable=mappable, low=low, high=high)

    # maxon objects later issues rely on
    var(0x2006, "USB frame timeout", u16, RW, 500)
    var(0x30B0, "Home position", i32, RW, 0, mappable=True)
    # CiA 402
    var(0x603F, "Error code", u16, RO, 0, mappable=True)
    var(0x6040, "Controlword", u16, RW, 0, mappable=True)
    var(0x6041, "Statusword", u16, RO, 0, mappable=True)
    var(0x605A, "Quick stop option code", i16, RW, 6, low=0, high=6)
    var(0x6060, "Modes of operation", i8, RW, int(OpMode.PROFILE_POSITION), mappable=True)
    var(0x6061, "Modes of operation display", i8, RO, int(OpMode.PROFILE_POSITION), mappable=True)
    var(0x6062, "Position demand value", i32, RO, 0, mappable=True)
    var(0x6064, "Position actual value", i32, RO, 0, mappable=True)
    var(0x6065, "Following error window", u32, RW, 2000, mappable=True)
    var(0x6066, "Following error time out", u16, RW, 50, mappable=True)
    var(0x6067, "Position window", u32, RW, 10, mappable=True)
    var(0x6068, "Position window time", u16, RW, 5, mappable=True)
    var(0x606B, "Velocity demand value", i32, RO, 0, mappable=True)
    var(0x606C, "Velocity actual value", i32, RO, 0, mappable=True)
    var(0x606D, "Velocity window", u16, RW, 100, mappable=True)
    var(0x606E, "Velocity window time", u16, RW, 5, mappable=True)
    var(0x6071, "Target torque", i16, RW, 0, mappable=True)
    var(0x6072, "Max torque", u16, RW, 3000, mappable=True, low=0)
    var(0x6074, "Torque demand", i16, RO, 0, mappable=True)
    var(0x6076, "Motor rated torque", u32, RO, round(p.rated_torque * 1000_000))  # uNm
    var(0x6077, "Torque actual value", i16, RO, 0, mappable=True)
    var(0x607A, "Target position", i32, RW, 0, mappable=True)
    od.add_record(0x607D, "Software position limit")
    od.add_sub(0x607D, 1, "Min position limit", i32, RW, -0x80000000, pdo_mappable=True)
    od.add_sub(0x607D, 2, "Max position limit", i32, RW, 0x7FFFFFFF, pdo_mappable=True)
    var(0x607F, "Max profile velocity", u32, RW, 409_600, mappable=True)
    var(0x6080, "Max motor speed", u32, RW, 409_600, mappable=True)
    var(0x6081, "Profile velocity", u32, RW, 40_960, mappable=True)
    var(0x6083, "Profile acceleration", u32, RW, 409_600, mappable=True, low=1)
    var(0x6084, "Profile deceleration", u32, RW, 409_600, mappable=True, low=1)
    var(0x6085, "Quick stop deceleration", u32, RW, 4_096_000, mappable=True, low=1)
    var(0x6086, "Motion profile type", i16, RW, 0, low=0, high=0)
    var(0x608F, "Position encoder resolution", u32, RO, p.increments_per_rev)
    var(0x6098, "Homing method", i8, RW, 37, mappable=True)
    od.add_record(0x6099, "Homing speeds")
    od.add_sub(0x6099, 1, "Speed for switch search", u32, RW, 20_480, pdo_mappable=True, low=1)
    od.add_sub(0x6099, 2, "Speed for zero search", u32, RW, 2_048, pdo_mappable=True, low=1)
    var(0x609A, "Homing acceleration", u32, RW, 409_600, mappable=True, low=1)
    var(0x60B0, "Position offset", i32, RW, 0, mappable=True)
    var(0x60B1, "Velocity offset", i32, RW, 0, mappable=True)
    var(0x60B2, "Torque offset", i16, RW, 0, mappable=True)
    od.add_record(0x60C2, "Interpolation time period")
    od.add_sub(0x60C2, 1, "Interpolation time period value", u8, RW, 1)
    od.add_sub(0x60C2, 2, "Interpolation time index", i8, RW, -3, low=-3, high=-3)
    var(0x60F4, "Following error actual value", i32, RO, 0, mappable=True)
    var(0x60FD, "Digital inputs", u32, RO, 0, mappable=True)
    var(0x60FF, "Target velocity", i32, RW, 0, mappable=True)
    var(0x6502, "Supported drive modes", u32, RO, SUPPORTED_MODES)
