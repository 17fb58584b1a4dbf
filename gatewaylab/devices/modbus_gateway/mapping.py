"""Register map of the Modbus TCP to CANopen gateway: which register is which object, and the codecs.

Pure data and pure functions (sans-I/O): a :class:`RegisterMap` of :class:`MappedObject` rows
(register, holding/input, index, subindex, type), the conversion of an object's bytes to 16-bit
registers and back, and the Modbus exception code for every way a request can fail
(:func:`exception_for_abort`). 8- and 16-bit objects take one register (signed ones two's
complement, sign-extended to 16 bits); 32-bit objects take two, **high word first** (the Modbus
convention for 32-bit values, "big-endian word order"; docs/decisions.md).
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from enum import Enum, IntEnum
from typing import Any

from gatewaylab.common.errors import ConfigError, RemoteError
from gatewaylab.od import SdoAbortCode

__all__ = [
    "ABORT_EXCEPTIONS",
    "MAP_ROW_KEYS",
    "TYPES",
    "MappedObject",
    "ModbusError",
    "ModbusException",
    "RegisterKind",
    "RegisterMap",
    "default_cia402_map",
    "exception_for_abort",
    "from_registers",
    "parse_map",
    "to_registers",
]


class ModbusException(IntEnum):
    """Modbus Application Protocol V1.1b3 section 7 exception codes the gateway answers with."""

    ILLEGAL_FUNCTION = 0x01
    ILLEGAL_DATA_ADDRESS = 0x02
    ILLEGAL_DATA_VALUE = 0x03
    SERVER_DEVICE_FAILURE = 0x04
    GATEWAY_PATH_UNAVAILABLE = 0x0A
    GATEWAY_TARGET_FAILED_TO_RESPOND = 0x0B


class ModbusError(RemoteError):
    """A request the gateway answers with a Modbus exception (``code``)."""

    def __init__(self, code: ModbusException, message: str = "") -> None:
        self.exception = code
        super().__init__(f"Modbus exception 0x{int(code):02X} {code.name}{': ' + message if message else ''}",
                         int(code))


#: SDO abort codes (CiA 301 7.2.4.3.17) and the Modbus exception each becomes; any other -> 04.
ABORT_EXCEPTIONS: Mapping[int, ModbusException] = {
    SdoAbortCode.OBJECT_DOES_NOT_EXIST: ModbusException.ILLEGAL_DATA_ADDRESS,
    SdoAbortCode.SUBINDEX_DOES_NOT_EXIST: ModbusException.ILLEGAL_DATA_ADDRESS,
    SdoAbortCode.UNSUPPORTED_ACCESS: ModbusException.ILLEGAL_DATA_ADDRESS,
    SdoAbortCode.WRITE_ONLY: ModbusException.ILLEGAL_DATA_ADDRESS,
    SdoAbortCode.READ_ONLY: ModbusException.ILLEGAL_DATA_ADDRESS,
    SdoAbortCode.LENGTH_MISMATCH: ModbusException.ILLEGAL_DATA_VALUE,
    SdoAbortCode.LENGTH_TOO_HIGH: ModbusException.ILLEGAL_DATA_VALUE,
    SdoAbortCode.LENGTH_TOO_LOW: ModbusException.ILLEGAL_DATA_VALUE,
    SdoAbortCode.VALUE_RANGE_EXCEEDED: ModbusException.ILLEGAL_DATA_VALUE,
    SdoAbortCode.VALUE_TOO_HIGH: ModbusException.ILLEGAL_DATA_VALUE,
    SdoAbortCode.VALUE_TOO_LOW: ModbusException.ILLEGAL_DATA_VALUE,
    SdoAbortCode.MAX_LESS_THAN_MIN: ModbusException.ILLEGAL_DATA_VALUE,
    SdoAbortCode.SDO_PROTOCOL_TIMED_OUT: ModbusException.GATEWAY_TARGET_FAILED_TO_RESPOND,
}


def exception_for_abort(code: int) -> ModbusException:
    """The Modbus exception of an SDO abort code (docs/devices/modbus_gateway.md "Exceptions")."""
    return ABORT_EXCEPTIONS.get(code, ModbusException.SERVER_DEVICE_FAILURE)


class RegisterKind(Enum):
    """Holding registers are read (FC 3) and written (FC 6, 16); input registers only read (FC 4)."""

    HOLDING = "holding"
    INPUT = "input"


#: type name -> (struct of the object's bytes, little-endian as in CANopen; registers it takes).
TYPES: Mapping[str, tuple[struct.Struct, int]] = {
    "u8": (struct.Struct("<B"), 1), "i8": (struct.Struct("<b"), 1),
    "u16": (struct.Struct("<H"), 1), "i16": (struct.Struct("<h"), 1),
    "u32": (struct.Struct("<I"), 2), "i32": (struct.Struct("<i"), 2),
}


@dataclass(frozen=True, slots=True)
class MappedObject:
    """One CANopen object (of every served node) at ``register`` of ``kind``."""

    register: int
    kind: RegisterKind
    index: int
    subindex: int
    type: str

    @property
    def words(self) -> int:
        """Registers the object takes (1 for 8/16 bits, 2 for 32 bits)."""
        return TYPES[self.type][1]

    @property
    def size(self) -> int:
        """The object's size in bytes (what an SDO transfer carries)."""
        return TYPES[self.type][0].size

    def __str__(self) -> str:
        return f"{self.kind.value} {self.register} = 0x{self.index:04X}:{self.subindex:02X} {self.type}"


def to_registers(obj: MappedObject, data: bytes) -> tuple[int, ...]:
    """An SDO upload's bytes as the object's registers (a short answer is zero-padded)."""
    fmt, words = TYPES[obj.type]
    value = int(fmt.unpack(bytes(data[:fmt.size]).ljust(fmt.size, b"\x00"))[0])
    if words == 1:
        return (value & 0xFFFF,)
    raw = value & 0xFFFFFFFF
    return (raw >> 16, raw & 0xFFFF)


def from_registers(obj: MappedObject, words: Sequence[int]) -> bytes:
    """The object's bytes for an SDO download of ``words``; a value outside the type is exception 03."""
    fmt, count = TYPES[obj.type]
    if len(words) != count:
        raise ModbusError(ModbusException.ILLEGAL_DATA_ADDRESS, f"{obj} needs {count} registers")
    if count == 2:
        raw = (words[0] << 16) | words[1]
        value = raw - (1 << 32) if obj.type == "i32" and raw & 0x80000000 else raw
    else:
        raw = words[0]
        value = raw - (1 << 16) if obj.type.startswith("i") and raw & 0x8000 else raw
    try:
        return fmt.pack(value)
    except struct.error:
        raise ModbusError(ModbusException.ILLEGAL_DATA_VALUE, f"{value} does not fit {obj}") from None


def default_cia402_map() -> tuple[MappedObject, ...]:
    """The map for CiA 402 drives (docs/devices/modbus_gateway.md "Default map")."""
    h, i = RegisterKind.HOLDING, RegisterKind.INPUT
    return (
        MappedObject(0, h, 0x6040, 0, "u16"),     # controlword
        MappedObject(1, h, 0x6060, 0, "i8"),      # modes of operation
        MappedObject(2, h, 0x607A, 0, "i32"),     # target position
        MappedObject(4, h, 0x60FF, 0, "i32"),     # target velocity
        MappedObject(6, h, 0x6081, 0, "u32"),     # profile velocity
        MappedObject(0, i, 0x6041, 0, "u16"),     # statusword
        MappedObject(1, i, 0x6061, 0, "i8"),      # modes of operation display
        MappedObject(2, i, 0x6064, 0, "i32"),     # position actual value
        MappedObject(4, i, 0x606C, 0, "i32"),     # velocity actual value
    )


#: The keys of one ``map = [...]`` row (checked by the rig's validator).
MAP_ROW_KEYS = ("register", "kind", "index", "subindex", "type")


def parse_map(rows: Iterable[Mapping[str, Any]], where: str = "map") -> tuple[MappedObject, ...]:
    """``map = [{register, kind, index, subindex, type}, ...]`` rows as objects; a bad row is a ConfigError."""
    out: list[MappedObject] = []
    for n, row in enumerate(rows, 1):
        here = f"{where}[{n}]"
        if not isinstance(row, Mapping):
            raise ConfigError(f"{here} must be a table {{register, kind, index, subindex, type}}")
        unknown = sorted(set(row) - set(MAP_ROW_KEYS))
        if unknown:
            raise ConfigError(f"{here}: unknown key {unknown[0]!r} (keys: {', '.join(MAP_ROW_KEYS)})")
        register, index, subindex = row.get("register"), row.get("index"), row.get("subindex", 0)
        kind, type_ = row.get("kind", "holding"), row.get("type")
        for key, value, hi in (("register", register, 0xFFFF), ("index", index, 0xFFFF), ("subindex", subindex, 0xFF)):
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= hi:
                raise ConfigError(f"{here}: {key} must be 0..{hi}, got {value!r}")
        if kind not in ("holding", "input"):
            raise ConfigError(f"{here}: kind must be 'holding' or 'input', got {kind!r}")
        if type_ not in TYPES:
            raise ConfigError(f"{here}: type must be one of {', '.join(TYPES)}, got {type_!r}")
        assert isinstance(register, int) and isinstance(index, int) and isinstance(subindex, int)
        assert isinstance(type_, str)
        obj = MappedObject(register, RegisterKind(kind), index, subindex, type_)
        if register + obj.words > 0x10000:
            raise ConfigError(f"{here}: {obj} runs past register 65535")
        out.append(obj)
    return tuple(out)


class RegisterMap:
    """Registers -> objects for one gateway (every served node has the same map)."""

    def __init__(self, objects: Iterable[MappedObject]) -> None:
        self.objects = tuple(sorted(objects, key=lambda o: (o.kind.value, o.register)))
        self._at: dict[tuple[RegisterKind, int], tuple[MappedObject, int]] = {}
        for obj in self.objects:
            for k in range(obj.words):
                key = (obj.kind, obj.register + k)
                if key in self._at:
                    raise ConfigError(f"map: {obj} overlaps {self._at[key][0]}")
                self._at[key] = (obj, k)

    def registers(self, kind: RegisterKind) -> list[tuple[int, int]]:
        """(first register, count) of every object of ``kind``."""
        return [(o.register, o.words) for o in self.objects if o.kind is kind]

    def plan_read(self, kind: RegisterKind, address: int, count: int) -> list[MappedObject]:
        """The objects a read of ``count`` registers from ``address`` touches (02 if one is unmapped);
        a read may start or end inside a 32-bit object."""
        objects: list[MappedObject] = []
        for reg in range(address, address + count):
            hit = self._at.get((kind, reg))
            if hit is None:
                raise ModbusError(ModbusException.ILLEGAL_DATA_ADDRESS, f"{kind.value} register {reg} is not mapped")
            if not objects or objects[-1] is not hit[0]:
                objects.append(hit[0])
        return objects

    def plan_write(self, address: int, values: Sequence[int]) -> list[tuple[MappedObject, bytes]]:
        """(object, bytes) for every object a write covers; each must be covered whole (02 otherwise,
        Modbus 7: "the combination of reference number and transfer length is invalid") and every
        value must fit its type (03)."""
        plan: list[tuple[MappedObject, bytes]] = []
        reg = address
        end = address + len(values)
        while reg < end:
            hit = self._at.get((RegisterKind.HOLDING, reg))
            if hit is None:
                raise ModbusError(ModbusException.ILLEGAL_DATA_ADDRESS, f"holding register {reg} is not mapped")
            obj, part = hit
            if part != 0 or reg + obj.words > end:
                raise ModbusError(ModbusException.ILLEGAL_DATA_ADDRESS,
                                  f"a write must cover all {obj.words} registers of {obj}")
            plan.append((obj, from_registers(obj, values[reg - address:reg - address + obj.words])))
            reg += obj.words
        return plan

    def slice_words(self, objects: Sequence[MappedObject], words: Sequence[tuple[int, ...]],
                    address: int, count: int) -> list[int]:
        """The ``count`` registers from ``address`` out of the read objects' registers."""
        flat: list[int] = []
        first = objects[0].register
        for w in words:
            flat.extend(w)
        return flat[address - first:address - first + count]
