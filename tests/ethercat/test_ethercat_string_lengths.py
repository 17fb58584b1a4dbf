"""CoE: string objects have a maximum length, and SDO information answers for every object fit the mailbox.

ETG.1000.6 5.6.2 (SDO download expedited / normal / segmented, complete access) with abort 0x06070012
"Data type does not match, length of service parameter too high"; the maximum is the object's ESI
``STRING(n)`` / BitSize (``ethercat_io`` 0x8000:01 "Description": STRING(512)).

ETG.1000.6 5.6.3 SDO information: an answer longer than the mailbox goes out in fragments, every one
but the last with the Incomplete flag (opcode bit 7) and each counting the fragments left (5.6.3.2);
the entry description's BitLength is UNSIGNED16 (5.6.3.6), so an object of more than 65,535 bits
gets an SDO information error (0x06040047, docs/decisions.md) instead of a wrapped value.
"""

from __future__ import annotations

import struct
from dataclasses import replace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.ethercat_io.device import DESCRIPTION_LENGTH, IoApplication, io_description
from gatewaylab.ethercat.coe import CoeServer, CoeService, InfoOpcode, coe_header
from gatewaylab.ethercat.description import ObjectDef
from gatewaylab.ethercat.errors import SdoAbort, SdoAbortCode
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.slave import Slave, build_od
from gatewaylab.hosts.ethercat.master import Master
from gatewaylab.od import Access, DataType, ObjectDictionary

MAILBOX = 128
TOO_HIGH = SdoAbortCode.LENGTH_TOO_HIGH
ORIGINAL = "generic loop-back I/O test box"


def _master(clock: SimulatedClock, *extra: ObjectDef) -> tuple[Master, Slave]:
    desc = io_description()
    desc = replace(desc, objects=desc.objects + extra)
    slave = Slave(clock, desc, IoApplication())
    m = Master(clock, Segment([slave]))
    m.scan()
    m.request_state(0, AlState.PREOP)
    return m, slave


def _abort(call: object) -> int:
    with pytest.raises(SdoAbort) as err:
        call()  # type: ignore[operator]
    assert err.value.code is not None
    return int(err.value.code)


def test_io_description_string_takes_512_bytes_and_no_more(clock: SimulatedClock) -> None:
    """The issue's case: a 1,000,000-byte write of 0x8000:01 is aborted at once (normal initiate with
    the size), 513 bytes too; 512 are stored; the value keeps its last good content."""
    m, slave = _master(clock)
    assert _abort(lambda: m.sdo_download(0, 0x8000, 1, b"x" * 1_000_000)) == TOO_HIGH
    assert _abort(lambda: m.sdo_download(0, 0x8000, 1, b"x" * (DESCRIPTION_LENGTH + 1))) == TOO_HIGH
    assert slave.od.get(0x8000, 1) == ORIGINAL
    text = bytes(range(32, 127)) * 5 + b"ab" * 18 + b"!"
    assert len(text) == DESCRIPTION_LENGTH
    m.sdo_download(0, 0x8000, 1, text)
    assert m.sdo_upload(0, 0x8000, 1) == text


def test_shorter_write_is_stored_as_written(clock: SimulatedClock) -> None:
    """A shorter string is the new value, read back with its own length (docs/decisions.md)."""
    m, _ = _master(clock)
    m.sdo_download(0, 0x8000, 1, b"io")
    assert m.sdo_upload(0, 0x8000, 1) == b"io"


def test_expedited_and_normal_writes_of_a_short_string(clock: SimulatedClock) -> None:
    """A 2-character string (its declared size: the default's length) refuses an expedited 3-byte write
    and a normal 5-byte one with 0x06070012; an OCTET_STRING of 4 bytes refuses 5."""
    tag = ObjectDef(0x2000, "Tag", DataType.VISIBLE_STRING, "ab", Access.RW)
    raw = ObjectDef(0x2001, "Raw", DataType.OCTET_STRING, b"\x01\x02\x03\x04", Access.RW)
    m, slave = _master(clock, tag, raw)
    assert _abort(lambda: m.sdo_download(0, 0x2000, 0, b"abc")) == TOO_HIGH
    assert _abort(lambda: m.sdo_download(0, 0x2000, 0, b"abcde")) == TOO_HIGH
    assert _abort(lambda: m.sdo_download(0, 0x2001, 0, b"\0" * 5)) == TOO_HIGH
    m.sdo_download(0, 0x2000, 0, b"xy")
    m.sdo_download(0, 0x2001, 0, b"\x09")
    assert (slave.od.get(0x2000), slave.od.get(0x2001)) == ("xy", b"\x09")


def test_complete_access_cannot_overfill_a_string(clock: SimulatedClock) -> None:
    """Complete access to 0x8000 (sub 0 padded to 16 bits, the description, the scale): one more byte
    than the record holds is 0x06070012, the record is unchanged."""
    m, slave = _master(clock)
    good = m.sdo_upload(0, 0x8000, 0, complete=True)
    assert _abort(lambda: m.sdo_download(0, 0x8000, 0, good + b"\0", complete=True)) == TOO_HIGH
    assert slave.od.get(0x8000, 1) == ORIGINAL


def test_esi_and_sdo_information_show_the_declared_size(clock: SimulatedClock) -> None:
    """The ESI's STRING(512) and the entry description's BitLength 4096 agree, whatever the value's length."""
    m, _ = _master(clock)
    m.sdo_download(0, 0x8000, 1, b"io")
    entry = m.entry_description(0, 0x8000, 1)
    assert (entry.data_type, entry.bit_length, entry.name) == (DataType.VISIBLE_STRING, 8 * DESCRIPTION_LENGTH,
                                                               "Description")


# ---------------------------------------------------------------------------------------- SDO information
def _server(od: ObjectDictionary) -> CoeServer:
    return CoeServer(od, MAILBOX, lambda: int(AlState.PREOP))


def _ed_request(index: int, sub: int) -> bytes:
    return coe_header(CoeService.SDO_INFO) + struct.pack("<BBHHBB", InfoOpcode.ED_REQ, 0, 0, index, sub, 0)


def _joined(replies: list[bytes], opcode: int) -> bytes:
    """The payload of a fragmented answer, checking the Incomplete flag and the fragments left."""
    out = b""
    for i, r in enumerate(replies):
        assert len(r) <= MAILBOX - 6
        op, _, left = struct.unpack_from("<BBH", r, 2)
        last = i == len(replies) - 1
        assert op == opcode | (0 if last else 0x80) and left == len(replies) - 1 - i
        out += r[6:]
    return out


def test_entry_description_golden_bytes(clock: SimulatedClock) -> None:
    """ethercat_io 0x8000:01: CoE header service 8, opcode 6, fragments left 0, index, subindex, value
    info 0, data type 0x0009, BitLength 0x1000 (512 bytes), access 0x003F (read and write in
    PREOP/SAFEOP/OP), name."""
    od = build_od(io_description())
    [reply] = _server(od).handle(_ed_request(0x8000, 1))
    assert reply == (b"\x00\x80" + b"\x06\x00\x00\x00" + b"\x00\x80\x01\x00" + b"\x09\x00" + b"\x00\x10"
                     + b"\x3f\x00" + b"Description")


def _string_od(size: int, name: str = "Text") -> ObjectDictionary:
    od = ObjectDictionary()
    od.add_variable(0x2000, name, DataType.VISIBLE_STRING, Access.RW, "x", max_length=size)
    return od


@settings(max_examples=60, deadline=None)
@given(size=st.integers(min_value=1, max_value=20_000), name_length=st.integers(min_value=0, max_value=600))
def test_entry_description_of_any_string_size(size: int, name_length: int) -> None:
    """Up to 8,191 bytes the BitLength is 8 x the size; from 8,192 bytes (65,536 bits) on the answer is
    the SDO information error 0x06040047; a long name is fragmented to the mailbox."""
    name = "n" * name_length
    replies = _server(_string_od(size, name)).handle(_ed_request(0x2000, 0))
    if 8 * size <= 0xFFFF:
        payload = _joined(replies, InfoOpcode.ED_RESP)
        assert struct.unpack_from("<HBBHH", payload, 0) == (0x2000, 0, 0, DataType.VISIBLE_STRING, 8 * size)
        assert payload[10:] == name.encode()
    else:
        [reply] = replies
        assert reply[2] == InfoOpcode.ERROR
        assert struct.unpack_from("<I", reply, 6)[0] == SdoAbortCode.GENERAL_INTERNAL_INCOMPATIBILITY


def test_long_object_name_is_fragmented(clock: SimulatedClock) -> None:
    """An object description longer than the mailbox comes in fragments (5.6.3.2)."""
    od = _string_od(4)
    od.objects[0x2000].name = "N" * 300
    replies = _server(od).handle(coe_header(CoeService.SDO_INFO) + struct.pack("<BBHH", InfoOpcode.OD_REQ, 0, 0,
                                                                                0x2000))
    assert len(replies) == 3
    assert _joined(replies, InfoOpcode.OD_RESP)[6:] == b"N" * 300


def _any_od() -> ObjectDictionary:
    od = build_od(io_description())
    for i, size in enumerate((8191, 8192, 70_000)):
        od.add_variable(0x2000 + i, "Big", DataType.OCTET_STRING, Access.RW, b"", max_length=size)
    od.add_variable(0x2010, "Näme ☃", DataType.UNICODE_STRING, Access.RW, "ab")
    return od


_ANY = _server(_any_od())


@settings(max_examples=300, deadline=None)
@given(body=st.binary(min_size=4, max_size=40), index=st.sampled_from([0x2000, 0x2001, 0x2002, 0x2010, 0x8000]),
       sub=st.integers(min_value=0, max_value=255), opcode=st.integers(min_value=0, max_value=255))
def test_no_sdo_information_request_raises(body: bytes, index: int, sub: int, opcode: int) -> None:
    """Whatever an SDO information request holds (any opcode, list type, index, subindex, trailing
    bytes), the server answers (an answer or an SDO information error) in replies that fit the
    mailbox; it never raises."""
    for req in (body, bytes([opcode]) + body[1:], struct.pack("<BBHHBB", opcode, 0, 0, index, sub, 0) + body,
                struct.pack("<BBHH", InfoOpcode.OD_LIST_REQ, 0, 0, index & 7)):
        replies = _ANY.handle(coe_header(CoeService.SDO_INFO) + req)
        assert replies and all(6 <= len(r) <= MAILBOX - 6 for r in replies)
        assert all(r[1] >> 4 == CoeService.SDO_INFO for r in replies)


def test_in_process_master_joins_fragmented_descriptions(clock: SimulatedClock) -> None:
    """The project's own master reads an object description that came in fragments whole (5.6.3.2)."""
    long_name = "A rather long object name, " * 8
    m, _ = _master(clock, ObjectDef(0x2000, long_name, DataType.UNSIGNED8, 0, Access.RW))
    assert m.object_description(0, 0x2000).name == long_name
