"""The one object dictionary (issue 9 'One dictionary, one error'): change notification, hooks per
object and per index range, access policies, and one SDO abort enum for CiA 301, the IDX table
6-20 and ETG.1000.6 CoE."""

from __future__ import annotations

from typing import Any

import pytest

from gatewaylab.od import Access, DataType, Entry, ObjectDictionary, SdoAbort, SdoAbortCode


def _od() -> ObjectDictionary:
    od = ObjectDictionary()
    od.add_variable(0x2000, "Set-point", DataType.INTEGER32, Access.RW, 0, pdo_mappable=True, low=-100, high=100)
    od.add_variable(0x2001, "Status", DataType.UNSIGNED16, Access.RO, 7)
    od.add_variable(0x2002, "Apply", DataType.UNSIGNED8, Access.WO)
    od.add_record(0x3000, "Counters")
    od.add_sub(0x3000, 1, "Frames", DataType.UNSIGNED32, Access.RO)
    return od


def test_put_reports_change_and_notifies_listeners_once() -> None:
    """CiA 301 7.2.2 (event-driven TPDOs): a value change, not a write, is the event; listeners of
    other keys are not called and an unsubscribed listener is not called again."""
    od = _od()
    seen: list[tuple[tuple[int, int], Any]] = []
    unsubscribe = od.subscribe((0x2000, 0), lambda key, value: seen.append((key, value)))
    od.subscribe((0x2001, 0), lambda key, value: seen.append((key, -1)))
    assert od.put(0x2000, 0, 5) is True
    assert od.put(0x2000, 0, 5) is False
    assert od.values[(0x2000, 0)] == 5
    unsubscribe()
    assert od.put(0x2000, 0, 6) is True
    assert seen == [((0x2000, 0), 5)]


def test_put_is_the_devices_own_write() -> None:
    """CiA 301 7.4.3: access type and limits restrict SDO access, not the device; put still coerces."""
    od = _od()
    assert od.put(0x2001, 0, 9) and od.get(0x2001) == 9          # read-only for SDO, not for the device
    assert od.put(0x2000, 0, 1000) and od.get(0x2000) == 1000    # limits are for remote writes
    assert od.put(0x2000, 0, 3.0) and od.values[(0x2000, 0)] == 3 and isinstance(od.get(0x2000), int)


def test_remote_write_checks_then_notifies() -> None:
    """CiA 301 7.2.4.3.17 abort codes: read only 0x06010002, write only 0x06010001, limits
    0x06090030; a remote write that changes a value notifies the listeners like put does."""
    od = _od()
    seen: list[Any] = []
    od.subscribe((0x2000, 0), lambda key, value: seen.append(value))
    od.write(0x2000, 0, (42).to_bytes(4, "little"))
    assert seen == [42]
    with pytest.raises(SdoAbort) as err:
        od.write(0x2001, 0, b"\x01\x00")
    assert err.value.code == SdoAbortCode.READ_ONLY
    with pytest.raises(SdoAbort) as err:
        od.read(0x2002, 0)
    assert err.value.code == SdoAbortCode.WRITE_ONLY
    with pytest.raises(SdoAbort) as err:
        od.write(0x2000, 0, (101).to_bytes(4, "little"))
    assert err.value.code == SdoAbortCode.VALUE_RANGE_EXCEEDED


def test_hooks_per_object_and_per_range() -> None:
    """Issue 9 'Object hooks': read hooks refresh status objects and counters, validators refuse,
    reactions apply commands; a range hook also covers objects added after it was registered."""
    od = _od()
    reads: list[tuple[int, int]] = []
    applied: list[Any] = []

    def refresh(index: int, subindex: int) -> None:
        reads.append((index, subindex))
        od.put(index, subindex, len(reads))

    def refuse_odd(entry: Entry, value: Any) -> None:
        if value % 2:
            raise SdoAbort(SdoAbortCode.VALUE_RANGE_EXCEEDED, "odd")

    od.on_read(range(0x3000, 0x3100), refresh)
    od.add_validator(0x2000, refuse_odd)
    od.add_reaction(0x2002, lambda entry, value: applied.append(value))
    od.add_record(0x3001, "More counters")                # added after the range hook
    od.add_sub(0x3001, 1, "Errors", DataType.UNSIGNED32, Access.RO)
    assert od.read(0x3000, 1) == (1).to_bytes(4, "little")
    assert od.read(0x3001, 1) == (2).to_bytes(4, "little")
    with pytest.raises(SdoAbort):
        od.write(0x2000, 0, (3).to_bytes(4, "little"))
    assert od.get(0x2000) == 0
    od.write(0x2002, 0, b"\x01")
    assert applied == [1]


def test_one_abort_enum_covers_the_three_tables() -> None:
    """CiA 301 table 22, IDX guide table 6-20, ETG.1000.6 CoE abort codes: one enum, one exception
    whose first argument is the code."""
    assert SdoAbortCode.COMPLETE_ACCESS_NOT_SUPPORTED == 0x06010004          # CoE only
    assert SdoAbortCode.WRONG_NMT_STATE.idx_name == "Wrong NMT state error"    # IDX table 6-20
    assert SdoAbortCode.INVALID_BLOCK_SIZE.idx_name is None                  # CiA 301 only
    exc = SdoAbort(0x06020000, "0x1234")
    assert exc.code == SdoAbortCode.OBJECT_DOES_NOT_EXIST and "0x06020000" in str(exc)
    assert SdoAbortCode.known(0x08000022) and not SdoAbortCode.known(0x12345678)
