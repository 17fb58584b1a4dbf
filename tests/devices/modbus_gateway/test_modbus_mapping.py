"""The gateway's register map and codecs (docs/devices/modbus_gateway.md; Modbus Application
Protocol V1.1b3 section 7 exception codes; CiA 301 7.2.4.3.17 abort codes)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gatewaylab.common.errors import ConfigError
from gatewaylab.devices.modbus_gateway.mapping import (
    TYPES,
    MappedObject,
    ModbusError,
    ModbusException,
    RegisterKind,
    RegisterMap,
    default_cia402_map,
    exception_for_abort,
    from_registers,
    parse_map,
    to_registers,
)

H, INP = RegisterKind.HOLDING, RegisterKind.INPUT


def test_32_bit_values_take_two_registers_high_word_first() -> None:
    """Modbus registers are big-endian 16-bit words; a 32-bit object is sent high word first
    (docs/decisions.md), from CANopen's little-endian bytes: -2 (0xFFFFFFFE) -> [0xFFFF, 0xFFFE]."""
    pos = MappedObject(2, H, 0x607A, 0, "i32")
    assert to_registers(pos, (-2).to_bytes(4, "little", signed=True)) == (0xFFFF, 0xFFFE)
    assert to_registers(pos, (0x12345678).to_bytes(4, "little")) == (0x1234, 0x5678)
    assert from_registers(pos, [0x1234, 0x5678]) == bytes.fromhex("78563412")


def test_narrow_signed_objects_are_sign_extended() -> None:
    """An INTEGER8 (modes of operation 0x6060) of -1 reads as 0xFFFF and 0xFFFF writes -1; 0x0080
    (128) does not fit INTEGER8: exception 03 illegal data value (Modbus 7)."""
    mode = MappedObject(1, H, 0x6060, 0, "i8")
    assert to_registers(mode, b"\xff") == (0xFFFF,)
    assert from_registers(mode, [0xFFFF]) == b"\xff"
    with pytest.raises(ModbusError) as exc:
        from_registers(mode, [0x0080])
    assert exc.value.code == ModbusException.ILLEGAL_DATA_VALUE == 3
    with pytest.raises(ModbusError):
        from_registers(MappedObject(0, H, 0x2000, 0, "u8"), [0x100])


@given(st.sampled_from(sorted(TYPES)), st.binary(min_size=0, max_size=6))
def test_registers_round_trip_any_object_bytes(type_: str, data: bytes) -> None:
    """Whatever an SDO upload returns, its registers write back the same value (property)."""
    obj = MappedObject(0, H, 0x2000, 0, type_)
    words = to_registers(obj, data)
    assert len(words) == obj.words and all(0 <= w <= 0xFFFF for w in words)
    assert from_registers(obj, list(words)) == bytes(data[:obj.size]).ljust(obj.size, b"\x00")


@given(st.sampled_from(sorted(TYPES)), st.lists(st.integers(0, 0xFFFF), min_size=1, max_size=2))
def test_any_register_values_give_bytes_or_a_modbus_exception(type_: str, words: list[int]) -> None:
    """Any register values a client writes end in the object's bytes or a ModbusError, nothing else."""
    obj = MappedObject(0, H, 0x2000, 0, type_)
    try:
        data = from_registers(obj, words)
    except ModbusError as exc:
        assert exc.code in (ModbusException.ILLEGAL_DATA_ADDRESS, ModbusException.ILLEGAL_DATA_VALUE)
    else:
        assert len(data) == obj.size


def test_abort_codes_become_documented_exceptions() -> None:
    """docs/devices/modbus_gateway.md "Exceptions": object/subindex missing and access errors -> 02,
    value range and length -> 03, SDO timeout -> 0B, anything else -> 04."""
    assert exception_for_abort(0x06020000) == 0x02
    assert exception_for_abort(0x06090011) == 0x02
    assert exception_for_abort(0x06010002) == 0x02
    assert exception_for_abort(0x06090030) == 0x03
    assert exception_for_abort(0x06070010) == 0x03
    assert exception_for_abort(0x05040000) == 0x0B
    assert exception_for_abort(0x08000022) == 0x04
    assert exception_for_abort(0x12345678) == 0x04


def test_default_map_plans() -> None:
    """Reads may cover parts of 32-bit objects; writes must cover whole objects (Modbus 7, code 02:
    "the combination of reference number and transfer length is invalid"); gaps are unmapped (02)."""
    rmap = RegisterMap(default_cia402_map())
    assert [o.index for o in rmap.plan_read(INP, 0, 6)] == [0x6041, 0x6061, 0x6064, 0x606C]
    assert [o.index for o in rmap.plan_read(INP, 3, 1)] == [0x6064]
    plan = rmap.plan_write(0, [0x0F, 1, 0, 20000])
    assert [(o.index, data) for o, data in plan] == [(0x6040, b"\x0f\x00"), (0x6060, b"\x01"),
                                                     (0x607A, (20000).to_bytes(4, "little"))]
    for address, values in ((3, [0]), (2, [0]), (100, [1])):
        with pytest.raises(ModbusError) as exc:
            rmap.plan_write(address, values)
        assert exc.value.code == 0x02
    with pytest.raises(ModbusError) as exc:
        rmap.plan_read(INP, 5, 2)
    assert exc.value.code == 0x02


def test_map_table_rows_are_checked() -> None:
    """`map = [...]` rows: register/index/subindex ranges, kind, type, overlaps are ConfigErrors."""
    rows = parse_map([{"register": 10, "kind": "input", "index": 0x1018, "subindex": 4, "type": "u32"}])
    assert rows == (MappedObject(10, INP, 0x1018, 4, "u32"),)
    for bad, text in (({"register": 1, "index": 0x1000, "type": "f32"}, "type"),
                      ({"register": -1, "index": 0x1000, "type": "u8"}, "register"),
                      ({"register": 1, "index": 0x1000, "type": "u8", "kind": "coil"}, "kind"),
                      ({"register": 1, "index": 0x1000, "type": "u8", "size": 1}, "unknown key"),
                      ({"register": 0xFFFF, "index": 0x1000, "type": "u32"}, "past register")):
        with pytest.raises(ConfigError, match=text):
            parse_map([bad])
    with pytest.raises(ConfigError, match="overlaps"):
        RegisterMap(parse_map([{"register": 0, "index": 0x1000, "type": "u32"},
                               {"register": 1, "index": 0x1001, "type": "u8"}]))
