"""The object dictionary as data: typed entries (CiA 301 7.4) bound to typed storage.

An :class:`ObjectDictionary` is a table of :class:`Entry` rows, one per (index, sub-index),
grouped into :class:`OdObject` (VAR, ARRAY, RECORD), plus a dict of current values. Values are
kept as Python values (int, float, bool, str, bytes); :func:`encode` / :func:`decode` turn them
into the little-endian wire form and back, checking length and value range with the SDO abort
codes of the IDX guide chapter 6. EDS/DCF export and import live in :mod:`.eds` and are reachable
as :meth:`ObjectDictionary.to_eds` and :meth:`ObjectDictionary.from_eds`.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from enum import Enum, IntEnum
from typing import Any

from ..common.errors import ConfigError
from .errors import (
    LENGTH_MISMATCH,
    LENGTH_TOO_LOW,
    OBJECT_DOES_NOT_EXIST,
    SUBINDEX_DOES_NOT_EXIST,
    VALUE_RANGE_EXCEEDED,
    SdoAbort,
)


class DataType(IntEnum):
    """Static data types of CiA 301 table 44 (their index in the OD is the code)."""

    BOOLEAN = 0x01
    INTEGER8 = 0x02
    INTEGER16 = 0x03
    INTEGER32 = 0x04
    UNSIGNED8 = 0x05
    UNSIGNED16 = 0x06
    UNSIGNED32 = 0x07
    REAL32 = 0x08
    VISIBLE_STRING = 0x09
    OCTET_STRING = 0x0A
    UNICODE_STRING = 0x0B
    TIME_OF_DAY = 0x0C
    TIME_DIFFERENCE = 0x0D
    DOMAIN = 0x0F
    INTEGER24 = 0x10
    REAL64 = 0x11
    INTEGER40 = 0x12
    INTEGER48 = 0x13
    INTEGER56 = 0x14
    INTEGER64 = 0x15
    UNSIGNED24 = 0x16
    UNSIGNED40 = 0x18
    UNSIGNED48 = 0x19
    UNSIGNED56 = 0x1A
    UNSIGNED64 = 0x1B


class Access(Enum):
    """Access attribute of an entry (CiA 301 table 43; CiA 306 ``AccessType``)."""

    RO = "ro"
    WO = "wo"
    RW = "rw"
    RWR = "rwr"   # rw, mapped to a TPDO by preference
    RWW = "rww"   # rw, mapped to an RPDO by preference
    CONST = "const"

    @property
    def readable(self) -> bool:
        return self is not Access.WO

    @property
    def writable(self) -> bool:
        return self in (Access.RW, Access.WO, Access.RWR, Access.RWW)


class ObjectCode(IntEnum):
    """Object codes of CiA 301 table 42 (CiA 306 ``ObjectType``)."""

    NULL = 0x0
    DOMAIN = 0x2
    DEFTYPE = 0x5
    DEFSTRUCT = 0x6
    VAR = 0x7
    ARRAY = 0x8
    RECORD = 0x9


#: Fixed-size numeric types: data type -> (size in bytes, signed, struct format or None for int.from_bytes).
_INT_TYPES: dict[DataType, tuple[int, bool]] = {
    DataType.INTEGER8: (1, True), DataType.INTEGER16: (2, True), DataType.INTEGER24: (3, True),
    DataType.INTEGER32: (4, True), DataType.INTEGER40: (5, True), DataType.INTEGER48: (6, True),
    DataType.INTEGER56: (7, True), DataType.INTEGER64: (8, True),
    DataType.UNSIGNED8: (1, False), DataType.UNSIGNED16: (2, False), DataType.UNSIGNED24: (3, False),
    DataType.UNSIGNED32: (4, False), DataType.UNSIGNED40: (5, False), DataType.UNSIGNED48: (6, False),
    DataType.UNSIGNED56: (7, False), DataType.UNSIGNED64: (8, False),
}
_STRUCTS: dict[DataType, struct.Struct] = {
    DataType.INTEGER8: struct.Struct("<b"), DataType.INTEGER16: struct.Struct("<h"),
    DataType.INTEGER32: struct.Struct("<i"), DataType.INTEGER64: struct.Struct("<q"),
    DataType.UNSIGNED8: struct.Struct("<B"), DataType.UNSIGNED16: struct.Struct("<H"),
    DataType.UNSIGNED32: struct.Struct("<I"), DataType.UNSIGNED64: struct.Struct("<Q"),
    DataType.REAL32: struct.Struct("<f"), DataType.REAL64: struct.Struct("<d"),
}
_FIXED_SIZE: dict[DataType, int] = {
    **{t: s for t, (s, _) in _INT_TYPES.items()},
    DataType.BOOLEAN: 1, DataType.REAL32: 4, DataType.REAL64: 8,
    DataType.TIME_OF_DAY: 6, DataType.TIME_DIFFERENCE: 6,
}
STRING_TYPES = frozenset({DataType.VISIBLE_STRING, DataType.UNICODE_STRING})
BYTES_TYPES = frozenset({DataType.OCTET_STRING, DataType.DOMAIN, DataType.TIME_OF_DAY,
                         DataType.TIME_DIFFERENCE})
FLOAT_TYPES = frozenset({DataType.REAL32, DataType.REAL64})
INT_TYPES = frozenset(_INT_TYPES)


def type_size(data_type: DataType) -> int | None:
    """Bytes of a fixed-size type, None for strings and domains."""
    return _FIXED_SIZE.get(data_type)


def type_range(data_type: DataType) -> tuple[int, int] | None:
    """Natural value range of an integer type."""
    info = _INT_TYPES.get(data_type)
    if info is None:
        return (0, 1) if data_type is DataType.BOOLEAN else None
    size, signed = info
    bits = 8 * size
    return (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else (0, (1 << bits) - 1)


def type_default(data_type: DataType) -> Any:
    if data_type in STRING_TYPES:
        return ""
    if data_type in BYTES_TYPES:
        return bytes(_FIXED_SIZE.get(data_type, 0))
    if data_type in FLOAT_TYPES:
        return 0.0
    if data_type is DataType.BOOLEAN:
        return False
    return 0


@dataclass(frozen=True, slots=True)
class Entry:
    """One addressable variable (index, sub-index) of the dictionary, without its value.

    ``nodeid_offset``: the default is ``default + node_id`` (EDS ``$NODEID+...``), e.g. COB-IDs.
    ``preop_only``: writable via SDO only outside NMT Operational (abort 0x0F00FFC0 otherwise).
    """

    index: int
    sub: int
    name: str
    data_type: DataType
    access: Access = Access.RW
    pdo_mappable: bool = False
    default: Any = None
    low: int | float | None = None
    high: int | float | None = None
    nodeid_offset: bool = False
    preop_only: bool = False
    #: Derived once (hashing an IntEnum runs Python code, too slow for the 1 kHz paths).
    size: int | None = field(init=False, compare=False, repr=False)
    codec: struct.Struct | None = field(init=False, compare=False, repr=False)
    limited: bool = field(init=False, compare=False, repr=False)
    #: Python type family: 0 bool, 1 int, 2 float, 3 str, 4 bytes; and the integer range.
    kind: int = field(init=False, compare=False, repr=False)
    int_range: tuple[int, int] | None = field(init=False, compare=False, repr=False)

    def __post_init__(self) -> None:
        dt = DataType(self.data_type)
        object.__setattr__(self, "data_type", dt)
        object.__setattr__(self, "size", _FIXED_SIZE.get(dt))
        object.__setattr__(self, "codec", _STRUCTS.get(dt))
        object.__setattr__(self, "limited", self.low is not None or self.high is not None)
        kind = (0 if dt is DataType.BOOLEAN else 1 if dt in _INT_TYPES else 2 if dt in FLOAT_TYPES
                else 3 if dt in STRING_TYPES else 4)
        object.__setattr__(self, "kind", kind)
        object.__setattr__(self, "int_range", type_range(dt) if kind == 1 else None)

    @property
    def bit_length(self) -> int:
        """Length in bits as written into a PDO mapping entry (0 for variable-size types)."""
        size = self.size
        return 8 * size if size is not None else 0

    def default_for(self, node_id: int | None) -> Any:
        value = type_default(self.data_type) if self.default is None else self.default
        if self.nodeid_offset and node_id is not None:
            value = value + node_id
        return value


@dataclass(slots=True)
class OdObject:
    """An index of the dictionary: a VAR (sub-index 0 only), an ARRAY or a RECORD."""

    index: int
    name: str
    object_code: ObjectCode
    entries: dict[int, Entry]

    def __getitem__(self, sub: int) -> Entry:
        return self.entries[sub]


def encode(entry: Entry, value: Any) -> bytes:
    """The wire form of ``value`` for ``entry`` (little-endian, CiA 301 7.1)."""
    st = entry.codec
    if st is not None:
        return st.pack(value)
    dt = entry.data_type
    if dt is DataType.BOOLEAN:
        return b"\x01" if value else b"\x00"
    info = _INT_TYPES.get(dt)
    if info is not None:
        return int(value).to_bytes(info[0], "little", signed=info[1])
    if dt is DataType.VISIBLE_STRING:
        return str(value).encode("latin-1", "replace")
    if dt is DataType.UNICODE_STRING:
        return str(value).encode("utf-16-le")
    return bytes(value)


def decode(entry: Entry, data: bytes) -> Any:
    """Value of ``data`` for ``entry``; raises SdoAbort on a wrong length or a value out of range."""
    size = entry.size
    if size is not None and len(data) != size:
        # The IDX lists 0x06070010 (length does not match) and 0x06070013 (too low) only.
        raise SdoAbort(LENGTH_TOO_LOW if len(data) < size else LENGTH_MISMATCH,
                       f"0x{entry.index:04X}:{entry.sub:02X} takes {size} bytes, got {len(data)}")
    st = entry.codec
    if st is not None:
        value: Any = st.unpack(data)[0]
        if entry.limited:
            check_limits(entry, value)
        return value
    dt = entry.data_type
    if dt is DataType.BOOLEAN:
        if data[0] > 1:
            raise SdoAbort(VALUE_RANGE_EXCEEDED, "BOOLEAN is 0 or 1")
        return bool(data[0])
    elif dt in _INT_TYPES:
        value = int.from_bytes(data, "little", signed=_INT_TYPES[dt][1])
    elif dt is DataType.VISIBLE_STRING:
        return data.decode("latin-1")
    elif dt is DataType.UNICODE_STRING:
        if len(data) % 2:
            raise SdoAbort(LENGTH_MISMATCH, "UNICODE_STRING has an even length")
        return data.decode("utf-16-le", "replace")
    else:
        return bytes(data)
    check_limits(entry, value)
    return value


def check_limits(entry: Entry, value: Any) -> None:
    """Raise VALUE_RANGE_EXCEEDED when ``value`` is outside the entry's limits."""
    low, high = entry.low, entry.high
    if isinstance(value, float) and math.isnan(value) and (low is not None or high is not None):
        raise SdoAbort(VALUE_RANGE_EXCEEDED, "NaN")
    if (low is not None and value < low) or (high is not None and value > high):
        raise SdoAbort(VALUE_RANGE_EXCEEDED,
                       f"0x{entry.index:04X}:{entry.sub:02X} = {value} outside [{low}, {high}]")


def coerce(entry: Entry, value: Any) -> Any:
    """Bring a locally supplied value to the entry's Python type (typed local access)."""
    kind = entry.kind
    if kind == 1:
        v = int(value)
        rng = entry.int_range
        assert rng is not None
        if not rng[0] <= v <= rng[1]:
            raise ConfigError(f"0x{entry.index:04X}:{entry.sub:02X}: {v} does not fit {entry.data_type.name}")
        return v
    if kind == 0:
        return bool(value)
    if kind == 2:
        return float(value)
    if kind == 3:
        return str(value)
    return bytes(value)


#: ``listener((index, subindex), value)`` after :meth:`ObjectDictionary.put` changed that value.
Listener = Callable[[tuple[int, int], Any], None]


class ObjectDictionary:
    """Rows of :class:`Entry` grouped in :class:`OdObject`, plus the current values."""

    def __init__(self, node_id: int | None = None) -> None:
        self.objects: dict[int, OdObject] = {}
        self.entries: dict[tuple[int, int], Entry] = {}
        self.values: dict[tuple[int, int], Any] = {}
        #: Node-id used to resolve ``$NODEID`` defaults when values are (re)initialised.
        self.node_id = node_id
        #: Free-form [DeviceInfo] fields for EDS export (VendorName, ProductName, ...).
        self.device_info: dict[str, str] = {}
        self._listeners: dict[tuple[int, int], list[Listener]] = {}

    # -- building ------------------------------------------------------------------------------
    def _add_entry(self, obj: OdObject, entry: Entry) -> Entry:
        obj.entries[entry.sub] = entry
        key = (entry.index, entry.sub)
        self.entries[key] = entry
        self.values[key] = coerce(entry, entry.default_for(self.node_id))
        return entry

    def _new_object(self, index: int, name: str, code: ObjectCode) -> OdObject:
        if not 0 < index <= 0xFFFF:
            raise ConfigError(f"index 0x{index:X} out of range")
        if index in self.objects:
            raise ConfigError(f"object 0x{index:04X} already exists")
        obj = OdObject(index, name, code, {})
        self.objects[index] = obj
        return obj

    def add_variable(self, index: int, name: str, data_type: DataType, access: Access = Access.RW,
                     default: Any = None, *, pdo_mappable: bool = False, low: float | None = None,
                     high: float | None = None, nodeid_offset: bool = False,
                     preop_only: bool = False) -> Entry:
        """Add a VAR object (sub-index 0)."""
        obj = self._new_object(index, name, ObjectCode.VAR)
        return self._add_entry(obj, Entry(index, 0, name, DataType(data_type), access, pdo_mappable,
                                          default, low, high, nodeid_offset, preop_only))

    def add_record(self, index: int, name: str, code: ObjectCode = ObjectCode.RECORD) -> OdObject:
        """Add an empty RECORD (or ARRAY); fill it with :meth:`add_sub`. Sub 0 is added for you."""
        return self._new_object(index, name, code)

    def add_sub(self, index: int, sub: int, name: str, data_type: DataType, access: Access = Access.RW,
                default: Any = None, *, pdo_mappable: bool = False, low: float | None = None,
                high: float | None = None, nodeid_offset: bool = False,
                preop_only: bool = False) -> Entry:
        """Add a sub-index to a RECORD/ARRAY; sub-index 0 'highest sub-index supported' follows."""
        obj = self.objects[index]
        entry = self._add_entry(obj, Entry(index, sub, name, DataType(data_type), access, pdo_mappable,
                                           default, low, high, nodeid_offset, preop_only))
        if sub != 0:
            sub0 = obj.entries.get(0)
            highest = max(s for s in obj.entries if s != 0)
            if sub0 is None:
                self._add_entry(obj, Entry(index, 0, "Highest sub-index supported", DataType.UNSIGNED8,
                                           Access.RO, False, highest))
            elif sub0.access is Access.RO or sub0.access is Access.CONST:
                new0 = replace(sub0, default=highest)
                obj.entries[0] = new0
                self.entries[(index, 0)] = new0
                self.values[(index, 0)] = highest
        return entry

    def add_array(self, index: int, name: str, data_type: DataType, count: int,
                  access: Access = Access.RW, default: Any = None, *, pdo_mappable: bool = False,
                  low: float | None = None, high: float | None = None,
                  sub0_access: Access = Access.RO, sub0_default: int | None = None,
                  sub_names: list[str] | None = None) -> OdObject:
        """Add an ARRAY with ``count`` elements of one type."""
        obj = self._new_object(index, name, ObjectCode.ARRAY)
        self._add_entry(obj, Entry(index, 0, "Highest sub-index supported", DataType.UNSIGNED8,
                                   sub0_access, False, count if sub0_default is None else sub0_default,
                                   0, count if sub0_access.writable else None))
        for i in range(1, count + 1):
            label = sub_names[i - 1] if sub_names else f"{name} {i}"
            self._add_entry(obj, Entry(index, i, label, DataType(data_type), access, pdo_mappable,
                                       default, low, high))
        return obj

    def replace_entry(self, entry: Entry) -> None:
        """Swap the description of an existing entry (keeps its value when still valid)."""
        obj = self.objects[entry.index]
        obj.entries[entry.sub] = entry
        self.entries[(entry.index, entry.sub)] = entry

    # -- lookup ----------------------------------------------------------------------------------
    def entry(self, index: int, sub: int) -> Entry:
        """The entry at (index, sub), or SdoAbort 0x06020000 / 0x06090011 as CiA 301 says."""
        e = self.entries.get((index, sub))
        if e is not None:
            return e
        if index in self.objects:
            raise SdoAbort(SUBINDEX_DOES_NOT_EXIST, f"0x{index:04X}:{sub:02X}")
        raise SdoAbort(OBJECT_DOES_NOT_EXIST, f"0x{index:04X}")

    def __contains__(self, key: object) -> bool:
        if isinstance(key, tuple):
            return key in self.entries
        return key in self.objects

    def __iter__(self) -> Iterator[OdObject]:
        for index in sorted(self.objects):
            yield self.objects[index]

    def __len__(self) -> int:
        return len(self.objects)

    # -- typed values ----------------------------------------------------------------------------
    def get(self, index: int, sub: int = 0) -> Any:
        try:
            return self.values[(index, sub)]
        except KeyError:
            self.entry(index, sub)
            raise

    def set(self, index: int, sub: int, value: Any) -> None:
        self.values[(index, sub)] = coerce(self.entry(index, sub), value)

    # -- change notification (temporary: the shared gatewaylab.od package replaces this) -----
    def put(self, index: int, subindex: int, value: Any) -> bool:
        """The device's own write (no access check, no coercion): store ``value``; when it
        differs from the stored one, tell every listener of that key. True if it changed."""
        key = (index, subindex)
        values = self.values
        try:
            if values[key] == value:
                return False
        except KeyError:
            self.entry(index, subindex)     # SdoAbort for an object that does not exist
            raise
        values[key] = value
        if key in self._listeners:
            for listener in tuple(self._listeners[key]):
                listener(key, value)
        return True

    def subscribe(self, key: tuple[int, int], listener: Listener) -> Callable[[], None]:
        """Call ``listener(key, value)`` on every change :meth:`put` makes to ``key``; returns
        the function that ends the subscription (PDO managers re-subscribe on a remap)."""
        self._listeners.setdefault(key, []).append(listener)

        def unsubscribe() -> None:
            listeners = self._listeners.get(key)
            if listeners is not None and listener in listeners:
                listeners.remove(listener)
                if not listeners:
                    del self._listeners[key]
        return unsubscribe

    def get_bytes(self, index: int, sub: int = 0) -> bytes:
        entry = self.entry(index, sub)
        return encode(entry, self.values[(index, sub)])

    def reset_values(self, indices: range | None = None) -> None:
        """Put the defaults back (all, or the objects whose index is in ``indices``)."""
        for key, entry in self.entries.items():
            if indices is None or key[0] in indices:
                self.values[key] = coerce(entry, entry.default_for(self.node_id))

    def copy(self) -> ObjectDictionary:
        """An independent dictionary with the same rows and values (entries are immutable)."""
        new = ObjectDictionary(self.node_id)
        for index, obj in self.objects.items():
            new.objects[index] = OdObject(obj.index, obj.name, obj.object_code, dict(obj.entries))
        new.entries = dict(self.entries)
        new.values = dict(self.values)
        new.device_info = dict(self.device_info)
        return new

    # -- EDS -------------------------------------------------------------------------------------
    def to_eds(self, *, dcf: bool = False, node_id: int | None = None) -> str:
        """CiA 306 EDS text (or DCF with ``ParameterValue`` lines when ``dcf``)."""
        from .eds import export_eds

        return export_eds(self, dcf=dcf, node_id=node_id)

    @classmethod
    def from_eds(cls, text: str, node_id: int | None = None) -> ObjectDictionary:
        """Build a dictionary from EDS or DCF text (DCF ``ParameterValue`` become the values)."""
        from .eds import import_eds

        return import_eds(text, node_id)
