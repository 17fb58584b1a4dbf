"""The CiA 301 communication profile area (0x1000..0x1FFF) every :class:`Node` carries.

:func:`add_communication_objects` adds whatever the caller's dictionary does not define yet,
so a device (the drive) only describes its own objects and the identity values.
"""

from __future__ import annotations

from gatewaylab.od import Access, DataType, ObjectCode, ObjectDictionary

__all__ = [
    "LOAD_SIGNATURE",
    "MAX_MAPPED",
    "N_PDO",
    "SAVE_SIGNATURE",
    "STORE_CAPABILITY",
    "add_communication_objects",
    "add_mapping",
]


N_PDO = 4
MAX_MAPPED = 8
#: Value of 0x1010/0x1011 sub-indices when read: bit 0 = the device saves on command (CiA 301 7.5.2.13).
STORE_CAPABILITY = 0x00000001
SAVE_SIGNATURE = 0x65766173   # "save" little-endian
LOAD_SIGNATURE = 0x64616F6C   # "load" little-endian


def add_communication_objects(od: ObjectDictionary, *, consumer_heartbeats: int = 4,
                              error_history: int = 8) -> None:
    """Add the missing communication-profile objects (CiA 301 7.5.2) to ``od``."""
    u8, u16, u32 = DataType.UNSIGNED8, DataType.UNSIGNED16, DataType.UNSIGNED32
    RO, RW, CONST = Access.RO, Access.RW, Access.CONST

    def var(index: int, name: str, dt: DataType, access: Access, default: object = None,
            **kw: object) -> None:
        if index not in od:
            od.add_variable(index, name, dt, access, default, **kw)  # type: ignore[arg-type]

    var(0x1000, "Device type", u32, RO, 0)
    var(0x1001, "Error register", u8, RO, 0, pdo_mappable=True)
    if 0x1003 not in od:
        od.add_array(0x1003, "Pre-defined error field", u32, error_history, RO, 0,
                     sub0_access=RW, sub0_default=0,
                     sub_names=[f"Standard error field {i}" for i in range(1, error_history + 1)])
    var(0x1005, "COB-ID SYNC", u32, RW, 0x80)
    var(0x1006, "Communication cycle period", u32, RW, 0)
    var(0x1007, "Synchronous window length", u32, RW, 0)
    var(0x1008, "Manufacturer device name", DataType.VISIBLE_STRING, CONST, "")
    var(0x1009, "Manufacturer hardware version", DataType.VISIBLE_STRING, CONST, "")
    var(0x100A, "Manufacturer software version", DataType.VISIBLE_STRING, CONST, "")
    var(0x100C, "Guard time", u16, RW, 0)
    var(0x100D, "Life time factor", u8, RW, 0)
    for index, name in ((0x1010, "Store parameters"), (0x1011, "Restore default parameters")):
        if index not in od:
            od.add_array(index, name, u32, 3, RW, STORE_CAPABILITY,
                         sub_names=["All parameters", "Communication parameters", "Application parameters"])
    var(0x1014, "COB-ID EMCY", u32, RW, 0x80, nodeid_offset=True)
    var(0x1015, "Inhibit time EMCY", u16, RW, 0)
    if 0x1016 not in od:
        od.add_array(0x1016, "Consumer heartbeat time", u32, consumer_heartbeats, RW, 0)
    var(0x1017, "Producer heartbeat time", u16, RW, 0)
    if 0x1018 not in od:
        od.add_record(0x1018, "Identity object")
        od.add_sub(0x1018, 1, "Vendor-ID", u32, RO, 0)
        od.add_sub(0x1018, 2, "Product code", u32, RO, 0)
        od.add_sub(0x1018, 3, "Revision number", u32, RO, 0)
        od.add_sub(0x1018, 4, "Serial number", u32, RO, 0)
    var(0x1019, "Synchronous counter overflow value", u8, RW, 0)
    if 0x1200 not in od:
        od.add_record(0x1200, "SDO server parameter")
        od.add_sub(0x1200, 1, "COB-ID client to server (rx)", u32, RO, 0x600, nodeid_offset=True)
        od.add_sub(0x1200, 2, "COB-ID server to client (tx)", u32, RO, 0x580, nodeid_offset=True)
    for n in range(N_PDO):
        rpdo_comm, tpdo_comm = 0x1400 + n, 0x1800 + n
        if rpdo_comm not in od:
            od.add_record(rpdo_comm, f"RPDO{n + 1} communication parameter")
            od.add_sub(rpdo_comm, 1, "COB-ID used by RPDO", u32, RW, 0x200 + 0x100 * n, nodeid_offset=True)
            od.add_sub(rpdo_comm, 2, "Transmission type", u8, RW, 255)
        add_mapping(od, 0x1600 + n, f"RPDO{n + 1} mapping parameter")
        if tpdo_comm not in od:
            od.add_record(tpdo_comm, f"TPDO{n + 1} communication parameter")
            od.add_sub(tpdo_comm, 1, "COB-ID used by TPDO", u32, RW, 0x180 + 0x100 * n, nodeid_offset=True)
            od.add_sub(tpdo_comm, 2, "Transmission type", u8, RW, 255)
            od.add_sub(tpdo_comm, 3, "Inhibit time", u16, RW, 0)
            od.add_sub(tpdo_comm, 5, "Event timer", u16, RW, 0)
            od.add_sub(tpdo_comm, 6, "SYNC start value", u8, RW, 0)
        add_mapping(od, 0x1A00 + n, f"TPDO{n + 1} mapping parameter")


def add_mapping(od: ObjectDictionary, index: int, name: str,
                entries: tuple[tuple[int, int, int], ...] = ()) -> None:
    """A PDO mapping RECORD with 8 entries; ``entries`` = default (index, sub, bits) triples."""
    if index in od:
        return
    od.add_record(index, name, ObjectCode.RECORD)
    od.add_sub(index, 0, "Number of mapped objects", DataType.UNSIGNED8, Access.RW, len(entries),
               low=0, high=MAX_MAPPED)
    for i in range(1, MAX_MAPPED + 1):
        value = 0
        if i <= len(entries):
            idx, sub, bits = entries[i - 1]
            value = (idx << 16) | (sub << 8) | bits
        od.add_sub(index, i, f"Mapping entry {i}", DataType.UNSIGNED32, Access.RW, value)
