"""Data types, entries and codecs of the one object dictionary (CiA 301 7.1 / 7.4, ETG.1000.6).

An :class:`Entry` is one row (index, subindex) without its value: data type, access, PDO
mappability, limits, default. :func:`encode` / :func:`decode` turn typed Python values (int,
float, bool, str, bytes) into the little-endian wire form and back, checking length and range
with the SDO abort codes every protocol shares (:mod:`.aborts`).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Hashable
from dataclasses import dataclass, field
from enum import Enum, IntEnum
from typing import Any

from gatewaylab.common.errors import ConfigError
from gatewaylab.od.aborts import SdoAbort, SdoAbortCode


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
        """An SDO upload may read it."""
        return self is not Access.WO

    @property
    def writable(self) -> bool:
        """An SDO download may write it (subject to the protocol's state policy)."""
        return self in (Access.RW, Access.WO, Access.RWR, Access.RWW)

    @property
    def rx_mappable(self) -> bool:
        """Direction rule for a PDO-mappable entry: master -> device (RPDO / CoE RxPDO)."""
        return self in (Access.RW, Access.WO, Access.RWW)

    @property
    def tx_mappable(self) -> bool:
        """Direction rule for a PDO-mappable entry: device -> master (TPDO / CoE TxPDO)."""
        return self in (Access.RO, Access.CONST, Access.RW, Access.RWR)


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
#: Types whose objects have a maximum length in bytes (:attr:`Entry.max_length`): the strings.
#: DOMAIN stays unbounded (files, programs); TIME_OF_DAY / TIME_DIFFERENCE have a fixed size.
SIZED_TYPES = frozenset({DataType.VISIBLE_STRING, DataType.OCTET_STRING, DataType.UNICODE_STRING})
#: The maximum length of a string object that declares none and whose default is empty (an EDS
#: declares no string sizes): a device's usual name / text buffer.
UNDECLARED_STRING_LENGTH = 255

#: ETG.2000 (ESI) names of the data types.
ESI_TYPE_NAMES: dict[DataType, str] = {
    DataType.BOOLEAN: "BOOL", DataType.INTEGER8: "SINT", DataType.INTEGER16: "INT",
    DataType.INTEGER32: "DINT", DataType.UNSIGNED8: "USINT", DataType.UNSIGNED16: "UINT",
    DataType.UNSIGNED32: "UDINT", DataType.REAL32: "REAL", DataType.VISIBLE_STRING: "STRING",
    DataType.OCTET_STRING: "OCTET_STRING", DataType.UNICODE_STRING: "UNICODE_STRING",
    DataType.DOMAIN: "DOMAIN", DataType.REAL64: "LREAL", DataType.INTEGER64: "LINT",
    DataType.UNSIGNED64: "ULINT",
}


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
    """The zero value of a type (empty string, zero bytes, 0, 0.0, False)."""
    if data_type in STRING_TYPES:
        return ""
    if data_type in BYTES_TYPES:
        return bytes(_FIXED_SIZE.get(data_type, 0))
    if data_type in FLOAT_TYPES:
        return 0.0
    if data_type is DataType.BOOLEAN:
        return False
    return 0


#: An entry's key ``(index, subindex)`` as the one tuple object the dictionary stores its value
#: under (:attr:`Entry.key`, :func:`key_object`); index ``ObjectDictionary.values`` with it
#: through a ``dict[Any, Any]``.
KeyObject = Hashable

#: One tuple object per ``(index, subindex)``, shared by every dictionary (see :func:`key_object`).
_KEY_OBJECTS: dict[KeyObject, KeyObject] = {}


def key_object(index: int, subindex: int) -> KeyObject:
    """The one ``(index, subindex)`` tuple object every :class:`Entry` of that address uses as its
    key: a dict finds an identical key without comparing tuples, so a hot path that reads
    ``values[key_object(...)]`` through a constant it made once gets the fastest lookup, and
    compiled code (which makes a new tuple of every ``tuple[int, int]`` it boxes) keeps it."""
    key: KeyObject = (index, subindex)     # boxed once (compiled)
    return _KEY_OBJECTS.setdefault(key, key)


@dataclass(frozen=True, slots=True)
class Entry:
    """One addressable variable (index, sub-index) of the dictionary, without its value.

    ``nodeid_offset``: the default is ``default + node_id`` (EDS ``$NODEID+...``), e.g. COB-IDs.
    ``preop_only``: writable via SDO only in the protocol's configuration state: outside NMT
    Operational on CANopen (abort 0x0F00FFC0), in PREOP only on CoE (abort 0x08000022).
    ``max_length``: the most bytes a string object (:data:`SIZED_TYPES`) holds, as its ESI
    ``STRING(n)`` / BitSize declares it; None derives it from the default (its length, or
    :data:`UNDECLARED_STRING_LENGTH` for an empty one). A longer write aborts 0x06070012.
    """

    index: int
    subindex: int
    name: str
    data_type: DataType
    access: Access = Access.RW
    pdo_mappable: bool = False
    default: Any = None
    low: int | float | None = None
    high: int | float | None = None
    nodeid_offset: bool = False
    preop_only: bool = False
    #: Not compared: an EDS (CiA 306) has no key for it, so a row read back from one is the same row.
    max_length: int | None = field(default=None, compare=False)
    #: Derived once (hashing an IntEnum runs Python code, too slow for the 1 kHz paths).
    size: int | None = field(init=False, compare=False, repr=False)
    codec: struct.Struct | None = field(init=False, compare=False, repr=False)
    limited: bool = field(init=False, compare=False, repr=False)
    #: Python type family: 0 bool, 1 int, 2 float, 3 str, 4 bytes; and the integer range.
    kind: int = field(init=False, compare=False, repr=False)
    int_range: tuple[int, int] | None = field(init=False, compare=False, repr=False)
    #: ``(index, subindex)``, built once: the dictionary stores values under this very tuple,
    #: and a dict finds an identical key without comparing tuples (PDO and SDO hot paths).
    #: Typed :data:`KeyObject`, not ``tuple[int, int]``: compiled (mypyc), a ``tuple[int, int]``
    #: is held unboxed and boxed into a new tuple at every use (a new hash and a tuple
    #: comparison in every lookup); an ``object`` stays this one tuple.
    key: KeyObject = field(init=False, compare=False, repr=False)

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
        object.__setattr__(self, "key", key_object(self.index, self.subindex))
        if dt in SIZED_TYPES:
            if self.max_length is None:
                object.__setattr__(self, "max_length", _declared_length(self))
        elif self.max_length is not None:
            object.__setattr__(self, "max_length", None)   # only strings have one

    @property
    def declared_bits(self) -> int:
        """Bits of the object as its description declares them (ESI BitSize, SDO information):
        the type's size, a string's maximum length, 0 for a DOMAIN."""
        size = self.size
        if size is not None:
            return 8 * size
        return 8 * self.max_length if self.max_length is not None else 0

    @property
    def bit_length(self) -> int:
        """Length in bits as written into a PDO mapping entry (0 for variable-size types)."""
        size = self.size
        return 8 * size if size is not None else 0

    @property
    def rx_pdo(self) -> bool:
        """Mappable into an RPDO / CoE RxPDO (outputs of the master)."""
        return self.pdo_mappable and self.access.rx_mappable

    @property
    def tx_pdo(self) -> bool:
        """Mappable into a TPDO / CoE TxPDO (inputs of the master)."""
        return self.pdo_mappable and self.access.tx_mappable

    def default_for(self, node_id: int | None) -> Any:
        """The power-on value (``$NODEID`` defaults follow ``node_id``)."""
        value = type_default(self.data_type) if self.default is None else self.default
        if self.nodeid_offset and node_id is not None:
            value = value + node_id
        return value


def _declared_length(entry: Entry) -> int:
    """A string's maximum length when it declares none: its default's, else the undeclared one."""
    default = entry.default
    if default is None:
        return UNDECLARED_STRING_LENGTH
    if entry.data_type is DataType.UNICODE_STRING:
        n = 2 * len(str(default))
    elif entry.data_type is DataType.VISIBLE_STRING:
        n = len(str(default))
    else:
        n = len(default) if isinstance(default, (bytes, bytearray)) else 0
    return n if n else UNDECLARED_STRING_LENGTH


def _too_long(entry: Entry, n: int) -> SdoAbort:
    return SdoAbort(SdoAbortCode.LENGTH_TOO_HIGH,
                    f"0x{entry.index:04X}:{entry.subindex:02X} holds at most {entry.max_length} bytes, got {n}")


@dataclass(slots=True)
class OdObject:
    """An index of the dictionary: a VAR (sub-index 0 only), an ARRAY or a RECORD."""

    index: int
    name: str
    object_code: ObjectCode
    entries: dict[int, Entry]

    def __getitem__(self, subindex: int) -> Entry:
        return self.entries[subindex]

    @property
    def max_subindex(self) -> int:
        """Highest subindex that exists (ETG.1000.6 SDO information 'max subindex')."""
        return max(self.entries) if self.entries else 0


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
        raise SdoAbort(SdoAbortCode.LENGTH_TOO_LOW if len(data) < size else SdoAbortCode.LENGTH_MISMATCH,
                       f"0x{entry.index:04X}:{entry.subindex:02X} takes {size} bytes, got {len(data)}")
    st = entry.codec
    if st is not None:
        value: Any = st.unpack(data)[0]
        if entry.limited:
            check_limits(entry, value)
        return value
    dt = entry.data_type
    if dt is DataType.BOOLEAN:
        if data[0] > 1:
            raise SdoAbort(SdoAbortCode.VALUE_RANGE_EXCEEDED, "BOOLEAN is 0 or 1")
        return bool(data[0])
    elif dt in _INT_TYPES:
        value = int.from_bytes(data, "little", signed=_INT_TYPES[dt][1])
    else:
        limit = entry.max_length
        if limit is not None and len(data) > limit:
            raise _too_long(entry, len(data))
        if dt is DataType.VISIBLE_STRING:
            return data.decode("latin-1")
        if dt is DataType.UNICODE_STRING:
            if len(data) % 2:
                raise SdoAbort(SdoAbortCode.LENGTH_MISMATCH, "UNICODE_STRING has an even length")
            return data.decode("utf-16-le", "replace")
        return bytes(data)
    check_limits(entry, value)
    return value


def check_length(entry: Entry, size: int) -> None:
    """Raise SdoAbortCode.LENGTH_TOO_HIGH when ``size`` bytes exceed a string's maximum length (a
    transfer announcing its size is refused before its data arrives, CiA 301 7.2.4.3.3)."""
    limit = entry.max_length
    if limit is not None and size > limit:
        raise _too_long(entry, size)


def check_limits(entry: Entry, value: Any) -> None:
    """Raise SdoAbortCode.VALUE_RANGE_EXCEEDED when ``value`` is outside the entry's limits."""
    low, high = entry.low, entry.high
    if isinstance(value, float) and math.isnan(value) and (low is not None or high is not None):
        raise SdoAbort(SdoAbortCode.VALUE_RANGE_EXCEEDED, "NaN")
    if (low is not None and value < low) or (high is not None and value > high):
        raise SdoAbort(SdoAbortCode.VALUE_RANGE_EXCEEDED,
                       f"0x{entry.index:04X}:{entry.subindex:02X} = {value} outside [{low}, {high}]")


def coerce(entry: Entry, value: Any) -> Any:
    """Bring a locally supplied value to the entry's Python type (typed local access)."""
    kind = entry.kind
    if kind == 1:
        v = int(value)
        rng = entry.int_range
        assert rng is not None
        if not rng[0] <= v <= rng[1]:
            raise ConfigError(f"0x{entry.index:04X}:{entry.subindex:02X}: {v} does not fit {entry.data_type.name}")
        return v
    if kind == 0:
        return bool(value)
    if kind == 2:
        return float(value)
    if kind == 3:
        return str(value)
    return bytes(value)


