"""A small typed CoE object dictionary: rows bound to typed storage, with SDO access rules.

The data types are CiA 301's (``gatewaylab.canopen.od.DataType``). The table itself differs from
``gatewaylab.canopen.od`` where CoE differs from CANopen: access rights per EtherCAT state and
per-entry read/write hooks; merging the two tables is a known follow-up. Values are stored encoded (little endian, as on
the wire); typed ``get``/``set`` convert. Access is per EtherCAT state (ETG.1000.6 object access
word: read/write in PREOP, SAFEOP, OP; RxPDO/TxPDO mappable).
"""

from __future__ import annotations

import enum
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

from ..canopen.od import DataType
from .errors import EtherCATConfigError, SdoAbortCode, SdoAbortError

# The CoE basic data types (QEC master manual appendix A.6) are CiA 301's, codes and all.
__all__ = ["Access", "DataType", "Entry", "ObjectCode", "ObjectDictionary", "decode", "encode", "type_size"]


_FIXED: dict[DataType, struct.Struct] = {
    DataType.BOOLEAN: struct.Struct("<B"),
    DataType.INTEGER8: struct.Struct("<b"),
    DataType.INTEGER16: struct.Struct("<h"),
    DataType.INTEGER32: struct.Struct("<i"),
    DataType.UNSIGNED8: struct.Struct("<B"),
    DataType.UNSIGNED16: struct.Struct("<H"),
    DataType.UNSIGNED32: struct.Struct("<I"),
    DataType.REAL32: struct.Struct("<f"),
    DataType.REAL64: struct.Struct("<d"),
    DataType.INTEGER64: struct.Struct("<q"),
    DataType.UNSIGNED64: struct.Struct("<Q"),
}

#: ESI names of the data types.
TYPE_NAMES: dict[DataType, str] = {
    DataType.BOOLEAN: "BOOL", DataType.INTEGER8: "SINT", DataType.INTEGER16: "INT",
    DataType.INTEGER32: "DINT", DataType.UNSIGNED8: "USINT", DataType.UNSIGNED16: "UINT",
    DataType.UNSIGNED32: "UDINT", DataType.REAL32: "REAL", DataType.VISIBLE_STRING: "STRING",
    DataType.OCTET_STRING: "OCTET_STRING", DataType.UNICODE_STRING: "UNICODE_STRING",
    DataType.DOMAIN: "DOMAIN", DataType.REAL64: "LREAL", DataType.INTEGER64: "LINT",
    DataType.UNSIGNED64: "ULINT",
}


class Access(enum.IntFlag):
    """ETG.1000.6 object access bits (SDO Information entry description)."""

    READ_PREOP = 0x0001
    READ_SAFEOP = 0x0002
    READ_OP = 0x0004
    WRITE_PREOP = 0x0008
    WRITE_SAFEOP = 0x0010
    WRITE_OP = 0x0020
    RXPDO = 0x0040
    TXPDO = 0x0080
    RO = 0x0007
    RW = 0x003F
    RW_PREOP = 0x000F
    WO = 0x0038


class ObjectCode(enum.IntEnum):
    VAR = 7
    ARRAY = 8
    RECORD = 9


Value = int | float | str | bytes
ReadHook = Callable[["Entry"], bytes]
WriteHook = Callable[["Entry", bytes], None]


def encode(data_type: DataType, value: Value) -> bytes:
    """Typed value -> wire bytes (raises SdoAbortError 0x06090030 when it does not fit)."""
    st = _FIXED.get(data_type)
    if st is not None:
        try:
            return st.pack(value)
        except (struct.error, TypeError):
            raise SdoAbortError(f"{value!r} does not fit {data_type.name}", SdoAbortCode.VALUE_RANGE) from None
    if isinstance(value, str):
        return value.encode("utf-16-le" if data_type == DataType.UNICODE_STRING else "latin-1")
    if isinstance(value, bytes):
        return value
    raise SdoAbortError(f"{value!r} is not a {data_type.name}", SdoAbortCode.LENGTH_MISMATCH)


def decode(data_type: DataType, raw: bytes) -> Value:
    st = _FIXED.get(data_type)
    if st is not None:
        return st.unpack(raw[:st.size])[0]  # type: ignore[no-any-return]
    if data_type == DataType.VISIBLE_STRING:
        return raw.decode("latin-1")
    if data_type == DataType.UNICODE_STRING:
        return raw.decode("utf-16-le")
    return raw


def type_size(data_type: DataType) -> int | None:
    """Size in bytes of a fixed-size type, None for strings/domains."""
    st = _FIXED.get(data_type)
    return st.size if st is not None else None


@dataclass(slots=True, eq=False)
class Entry:
    """One sub-index: typed storage plus optional hooks the device uses to act on access."""

    index: int
    subindex: int
    name: str
    data_type: DataType
    raw: bytes
    access: Access = Access.RO
    bit_length: int | None = None
    on_read: ReadHook | None = None
    on_write: WriteHook | None = None
    default: bytes = b""

    @property
    def bits(self) -> int:
        if self.bit_length is not None:
            return self.bit_length
        size = type_size(self.data_type)
        return 8 * (size if size is not None else len(self.raw))

    @property
    def value(self) -> Value:
        return decode(self.data_type, self.read_raw())

    def read_raw(self) -> bytes:
        return self.on_read(self) if self.on_read is not None else self.raw


@dataclass(slots=True, eq=False)
class OdObject:
    index: int
    name: str
    code: ObjectCode
    entries: dict[int, Entry] = field(default_factory=dict)

    @property
    def max_subindex(self) -> int:
        return max(self.entries) if self.entries else 0


_STATE_READ = {0x02: Access.READ_PREOP, 0x04: Access.READ_SAFEOP, 0x08: Access.READ_OP}
_STATE_WRITE = {0x02: Access.WRITE_PREOP, 0x04: Access.WRITE_SAFEOP, 0x08: Access.WRITE_OP}


class ObjectDictionary:
    """Objects by index; ``read``/``write`` apply the SDO rules and raise SdoAbortError."""

    def __init__(self) -> None:
        self.objects: dict[int, OdObject] = {}

    def __contains__(self, index: object) -> bool:
        return index in self.objects

    def __iter__(self) -> Iterator[OdObject]:
        return iter(sorted(self.objects.values(), key=lambda o: o.index))

    # -- building -----------------------------------------------------------------------------
    def add_var(self, index: int, name: str, data_type: DataType, value: Value,
                access: Access = Access.RO, **hooks: ReadHook | WriteHook | None) -> Entry:
        obj = OdObject(index, name, ObjectCode.VAR)
        entry = self._entry(index, 0, name, data_type, value, access, hooks)
        obj.entries[0] = entry
        self._add(obj)
        return entry

    def add_record(self, index: int, name: str,
                   entries: list[tuple[str, DataType, Value, Access]],
                   code: ObjectCode = ObjectCode.RECORD, sub0_access: Access = Access.RO) -> OdObject:
        """A RECORD/ARRAY with sub 0 = number of entries (U8), then entries 1..n."""
        obj = OdObject(index, name, code)
        obj.entries[0] = self._entry(index, 0, "SubIndex 000", DataType.UNSIGNED8, len(entries),
                                     sub0_access, {})
        for i, (ename, dtype, value, access) in enumerate(entries, start=1):
            obj.entries[i] = self._entry(index, i, ename, dtype, value, access, {})
        self._add(obj)
        return obj

    def add_array(self, index: int, name: str, data_type: DataType, values: list[Value],
                  access: Access = Access.RO, sub0_access: Access = Access.RO,
                  length: int | None = None) -> OdObject:
        """An ARRAY; ``length`` subentries exist (default len(values)), sub 0 holds len(values)."""
        n = length if length is not None else len(values)
        padded = list(values) + [0] * (n - len(values))
        obj = self.add_record(index, name,
                              [(f"SubIndex {i:03d}", data_type, v, access) for i, v in enumerate(padded, 1)],
                              ObjectCode.ARRAY, sub0_access)
        obj.entries[0].raw = bytes([len(values)])
        return obj

    def _entry(self, index: int, sub: int, name: str, data_type: DataType, value: Value, access: Access,
               hooks: dict[str, ReadHook | WriteHook | None]) -> Entry:
        raw = encode(data_type, value)
        entry = Entry(index, sub, name, data_type, raw, access, default=raw)
        entry.on_read = hooks.get("on_read")  # type: ignore[assignment]
        entry.on_write = hooks.get("on_write")  # type: ignore[assignment]
        return entry

    def _add(self, obj: OdObject) -> None:
        if obj.index in self.objects:
            raise EtherCATConfigError(f"object 0x{obj.index:04X} defined twice")
        self.objects[obj.index] = obj

    # -- access -------------------------------------------------------------------------------
    def object(self, index: int) -> OdObject:
        obj = self.objects.get(index)
        if obj is None:
            raise SdoAbortError(f"no object 0x{index:04X}", SdoAbortCode.OBJECT_DOES_NOT_EXIST)
        return obj

    def entry(self, index: int, subindex: int) -> Entry:
        entry = self.object(index).entries.get(subindex)
        if entry is None:
            raise SdoAbortError(f"no sub-index 0x{index:04X}:{subindex}", SdoAbortCode.SUBINDEX_DOES_NOT_EXIST)
        return entry

    def get(self, index: int, subindex: int = 0) -> Value:
        return self.entry(index, subindex).value

    def set(self, index: int, subindex: int, value: Value) -> None:
        """Local (device-side) write: no access check, no hooks."""
        entry = self.entry(index, subindex)
        entry.raw = encode(entry.data_type, value)

    def read(self, index: int, subindex: int, state: int = 0x02) -> bytes:
        """SDO upload of one entry in the given EtherCAT state."""
        entry = self.entry(index, subindex)
        if not entry.access & _STATE_READ.get(state & 0x0F, Access.READ_PREOP):
            if entry.access & (Access.READ_PREOP | Access.READ_SAFEOP | Access.READ_OP):
                raise SdoAbortError("not readable in this state", SdoAbortCode.CANNOT_STORE_STATE)
            raise SdoAbortError("write-only object", SdoAbortCode.WRITE_ONLY)
        return entry.read_raw()

    def write(self, index: int, subindex: int, data: bytes, state: int = 0x02) -> None:
        """SDO download of one entry: access, length and type checks, then the device's hook."""
        entry = self.entry(index, subindex)
        if not entry.access & _STATE_WRITE.get(state & 0x0F, Access.WRITE_PREOP):
            if entry.access & Access.WO:
                raise SdoAbortError("not writable in this state", SdoAbortCode.CANNOT_STORE_STATE)
            raise SdoAbortError("read-only object", SdoAbortCode.READ_ONLY)
        size = type_size(entry.data_type)
        if size is not None:
            if len(data) > size:
                raise SdoAbortError("too long", SdoAbortCode.LENGTH_TOO_HIGH)
            if len(data) < size:
                raise SdoAbortError("too short", SdoAbortCode.LENGTH_TOO_LOW)
        elif entry.bit_length is not None and len(data) * 8 > entry.bit_length:
            raise SdoAbortError("too long", SdoAbortCode.LENGTH_TOO_HIGH)
        obj = self.objects[index]
        if subindex == 0 and obj.code != ObjectCode.VAR and data[0] > obj.max_subindex:
            raise SdoAbortError("more entries than exist", SdoAbortCode.VALUE_TOO_HIGH)
        if entry.on_write is not None:
            entry.on_write(entry, bytes(data))
        entry.raw = bytes(data)

    def read_complete(self, index: int, first_sub: int, state: int = 0x02) -> bytes:
        """Complete access upload: sub 0 is padded to 16 bits (ETG.1000.6 complete access)."""
        obj = self.object(index)
        if obj.code == ObjectCode.VAR:
            raise SdoAbortError("complete access to a VAR", SdoAbortCode.UNSUPPORTED_ACCESS)
        n = int(obj.entries[0].read_raw()[0])
        parts: list[bytes] = []
        if first_sub == 0:
            parts.append(self.read(index, 0, state) + b"\x00")
        for sub in range(1, n + 1):
            if sub in obj.entries:
                parts.append(self.read(index, sub, state))
        return b"".join(parts)

    def write_complete(self, index: int, first_sub: int, data: bytes, state: int = 0x02) -> None:
        obj = self.object(index)
        if obj.code == ObjectCode.VAR:
            raise SdoAbortError("complete access to a VAR", SdoAbortCode.UNSUPPORTED_ACCESS)
        pos = 0
        n = obj.max_subindex
        if first_sub == 0:
            if len(data) < 2:
                raise SdoAbortError("too short", SdoAbortCode.LENGTH_TOO_LOW)
            n = data[0]
            pos = 2
        writes: list[tuple[int, bytes]] = []
        for sub in range(1, n + 1):
            entry = self.entry(index, sub)
            size = type_size(entry.data_type) or len(entry.raw)
            if pos + size > len(data):
                raise SdoAbortError("too short", SdoAbortCode.LENGTH_TOO_LOW)
            writes.append((sub, data[pos:pos + size]))
            pos += size
        if pos != len(data):
            raise SdoAbortError("too long", SdoAbortCode.LENGTH_TOO_HIGH)
        if first_sub == 0:
            self.write(index, 0, b"\x00", state)
        for sub, raw in writes:
            self.write(index, sub, raw, state)
        if first_sub == 0:
            self.write(index, 0, bytes([n]), state)
