"""Object dictionary as data: typed codecs, limits, access, and EDS/DCF round trips with python-canopen.

Manual: IDX Communication Guide 3.3.1 (object dictionary, tables 3-8/3-9), table 6-20 (length and
range codes); CiA 301 7.1/7.4 for the data types, CiA 306 for the EDS format.
"""

from __future__ import annotations

import io
import math

import canopen
import pytest
from canopen.objectdictionary import ODArray, ODRecord, ODVariable
from canopen_testkit import remote_for, sample_od
from hypothesis import given, settings
from hypothesis import strategies as st

from gatewaylab.canopen import errors as E
from gatewaylab.canopen.node import Node
from gatewaylab.common.errors import ConfigError
from gatewaylab.od import (
    Access,
    DataType,
    Entry,
    ObjectCode,
    ObjectDictionary,
    SdoAbort,
    decode,
    encode,
    type_range,
)
from gatewaylab.od.eds import export_eds, import_eds


@pytest.mark.parametrize(("dt", "value", "wire"), [
    (DataType.BOOLEAN, True, b"\x01"),
    (DataType.INTEGER8, -2, b"\xFE"),
    (DataType.INTEGER16, -2, b"\xFE\xFF"),
    (DataType.INTEGER24, -2, b"\xFE\xFF\xFF"),
    (DataType.INTEGER32, 0x01020304, b"\x04\x03\x02\x01"),
    (DataType.INTEGER40, -1, b"\xFF" * 5),
    (DataType.INTEGER48, 1 << 40, b"\x00\x00\x00\x00\x00\x01"),
    (DataType.INTEGER56, -(1 << 55), b"\x00" * 6 + b"\x80"),
    (DataType.INTEGER64, -(1 << 63), b"\x00" * 7 + b"\x80"),
    (DataType.UNSIGNED8, 0xAB, b"\xAB"),
    (DataType.UNSIGNED16, 0x1234, b"\x34\x12"),
    (DataType.UNSIGNED24, 0x123456, b"\x56\x34\x12"),
    (DataType.UNSIGNED32, 0xDEADBEEF, b"\xEF\xBE\xAD\xDE"),
    (DataType.UNSIGNED40, 0x0102030405, b"\x05\x04\x03\x02\x01"),
    (DataType.UNSIGNED48, 0xFFFFFFFFFFFF, b"\xFF" * 6),
    (DataType.UNSIGNED56, 1, b"\x01" + b"\x00" * 6),
    (DataType.UNSIGNED64, 2**64 - 1, b"\xFF" * 8),
    (DataType.REAL32, 1.5, b"\x00\x00\xC0\x3F"),
    (DataType.REAL64, -2.0, b"\x00" * 7 + b"\xC0"),
    (DataType.VISIBLE_STRING, "IDX", b"IDX"),
    (DataType.UNICODE_STRING, "Ä", b"\xC4\x00"),
    (DataType.OCTET_STRING, b"\x00\x01", b"\x00\x01"),
    (DataType.DOMAIN, b"\xFF" * 100, b"\xFF" * 100),
    (DataType.TIME_OF_DAY, b"\x01\x02\x03\x04\x05\x06", b"\x01\x02\x03\x04\x05\x06"),
])
def test_codec_golden(dt: DataType, value: object, wire: bytes) -> None:
    """CiA 301 7.1: little-endian encoding of every basic data type."""
    entry = Entry(0x2000, 0, "x", dt)
    assert encode(entry, value) == wire
    assert decode(entry, wire) == value


def test_decode_length_and_range_errors() -> None:
    """IDX table 6-20: too short -> 0x06070013, too long -> 0x06070010, out of limits -> 0x06090030."""
    entry = Entry(0x2000, 0, "x", DataType.INTEGER16, low=-10, high=10)
    with pytest.raises(SdoAbort) as info:
        decode(entry, b"\x01")
    assert info.value.code == E.LENGTH_TOO_LOW
    with pytest.raises(SdoAbort) as info:
        decode(entry, b"\x01\x00\x00")
    assert info.value.code == E.LENGTH_MISMATCH
    with pytest.raises(SdoAbort) as info:
        decode(entry, b"\x0B\x00")
    assert info.value.code == E.VALUE_RANGE_EXCEEDED
    assert decode(entry, b"\xF6\xFF") == -10
    real = Entry(0x2001, 0, "r", DataType.REAL32, low=0.0, high=1.0)
    with pytest.raises(SdoAbort):
        decode(real, encode(real, math.nan))


def test_access_and_lookup() -> None:
    """CiA 301 table 43 / IDX table 6-20: RO/CONST not writable, WO not readable; unknown index
    0x06020000, unknown sub-index 0x06090011."""
    assert Access.RO.readable and not Access.RO.writable
    assert Access.CONST.readable and not Access.CONST.writable
    assert Access.WO.writable and not Access.WO.readable
    assert Access.RWR.writable and Access.RWW.readable
    od = sample_od()
    with pytest.raises(SdoAbort) as info:
        od.entry(0x5555, 0)
    assert info.value.code == E.OBJECT_DOES_NOT_EXIST
    with pytest.raises(SdoAbort) as info:
        od.entry(0x2200, 2)
    assert info.value.code == E.SUBINDEX_DOES_NOT_EXIST
    assert od.get(0x2200, 0) == 3                      # highest sub-index supported
    assert od.objects[0x2100].object_code is ObjectCode.ARRAY
    with pytest.raises(ConfigError):
        od.set(0x2004, 0, 256)                         # does not fit UNSIGNED8
    with pytest.raises(ConfigError):
        od.add_variable(0x2000, "again", DataType.UNSIGNED8)


def _node_with_comm(node_id: int = 5) -> ObjectDictionary:
    from gatewaylab.canopen.communication import add_communication_objects

    od = sample_od()
    od.node_id = node_id
    add_communication_objects(od)
    od.reset_values()
    return od


def _canopen_view(var: ODVariable) -> tuple[object, ...]:
    return (var.index, var.subindex, var.data_type, var.access_type, bool(var.pdo_mappable),
            var.default, var.min, var.max)


def test_eds_export_loads_in_python_canopen() -> None:
    """CiA 306: our EDS is read by python-canopen's import_od with the same types, access, PDO
    mapping flags, limits and defaults ($NODEID resolved)."""
    od = _node_with_comm(5)
    text = export_eds(od)
    stream = io.StringIO(text)
    stream.name = "node.eds"
    theirs = canopen.objectdictionary.import_od(stream, node_id=5)
    assert sorted(obj.index for obj in theirs.values() if obj.index >= 0x1000) == sorted(od.objects)
    for obj in od:
        other = theirs[obj.index]
        expected_cls = {ObjectCode.VAR: ODVariable, ObjectCode.ARRAY: ODArray, ObjectCode.RECORD: ODRecord}
        assert isinstance(other, expected_cls[obj.object_code]), hex(obj.index)
        for sub, entry in obj.entries.items():
            var = other if isinstance(other, ODVariable) else other[sub]
            default = entry.default_for(5)
            if entry.data_type is DataType.BOOLEAN:
                default = int(default)
            assert _canopen_view(var) == (entry.index, sub, int(entry.data_type), entry.access.value,
                                          entry.pdo_mappable, default, entry.low, entry.high), \
                f"0x{entry.index:04X}:{sub}"
            assert var.name == entry.name
    assert theirs[0x1400][1].relative and theirs[0x1400][1].default == 0x205


def test_eds_round_trip_through_our_importer() -> None:
    """CiA 306: export -> import gives the same rows and defaults."""
    od = _node_with_comm(5)
    again = import_eds(export_eds(od), node_id=5)
    assert again.entries == od.entries
    assert again.values == od.values
    assert {i: o.object_code for i, o in again.objects.items()} == {i: o.object_code for i, o in od.objects.items()}


def test_python_canopen_export_imports_in_ours() -> None:
    """CiA 306 interop the other way: an EDS written by python-canopen builds our dictionary."""
    stream = io.StringIO(export_eds(_node_with_comm(5)))
    stream.name = "node.eds"
    theirs = canopen.objectdictionary.import_od(stream, node_id=5)
    out = io.StringIO()
    canopen.objectdictionary.export_od(theirs, out, doc_type="eds")
    ours = import_eds(out.getvalue(), node_id=5)
    for key, entry in _node_with_comm(5).entries.items():
        got = ours.entries[key]
        assert (got.data_type, got.access, got.pdo_mappable, got.low, got.high) == \
            (entry.data_type, entry.access, entry.pdo_mappable, entry.low, entry.high), key
        assert ours.values[key] == _node_with_comm(5).values[key], key


def test_dcf_carries_values_and_node_id() -> None:
    """CiA 306 DCF: ParameterValue holds the configured value, [DeviceComissioning] the node-id."""
    od = _node_with_comm(7)
    od.set(0x2000, 0, 99)
    od.set(0x1017, 0, 250)
    text = export_eds(od, dcf=True, node_id=7)
    assert "[DeviceComissioning]" in text and "NodeID=7" in text
    again = import_eds(text)
    assert again.node_id == 7
    assert again.get(0x2000) == 99 and again.get(0x1017) == 250
    assert again.entries[(0x2000, 0)].default == 0x12345678
    assert again.get(0x1800, 1) == 0x187


def test_node_built_from_eds(clock, vbus, network) -> None:
    """Issue: a Node is constructible from an EDS file; python-canopen reads it by SDO."""
    text = export_eds(_node_with_comm(5))
    node = Node.from_eds(clock, vbus, 12, text, name="from-eds")
    node.start()
    remote = remote_for(network, node)
    assert remote.sdo[0x2001].raw == "gatewaylab CANopen node"
    assert remote.sdo[0x1200][1].raw == 0x60C
    assert node.to_eds() == export_eds(node.od, node_id=12)


def test_node_built_from_eds_file(clock, vbus, tmp_path) -> None:
    """Issue: building a node from an EDS/DCF *file*; a DCF's node-id and values apply."""
    path = tmp_path / "drive.dcf"
    od = _node_with_comm(9)
    od.set(0x2000, 0, 4711)
    path.write_text(export_eds(od, dcf=True, node_id=9), encoding="latin-1")
    node = Node.from_eds(clock, vbus, 9, path)
    node.start()
    assert node.get(0x2000) == 4711 and node.get(0x1400, 1) == 0x209


def test_handwritten_eds_with_compact_sub_objects() -> None:
    """CiA 306 4.5.2: CompactSubObj arrays, $NODEID defaults, comments and signed hex limits."""
    text = """
[DeviceInfo]
VendorName=maxon
[1016]
ParameterName=Consumer heartbeat time
ObjectType=0x8
DataType=0x0007
AccessType=rw
CompactSubObj=3
DefaultValue=0
PDOMapping=0
[1016Name]
NrOfEntries=1
1=Consumer 1
[1800]
ParameterName=TPDO1
ObjectType=0x9
SubNumber=2
[1800sub0]
ParameterName=Highest
ObjectType=0x7
DataType=0x0005
AccessType=ro
DefaultValue=1
[1800sub1]
ParameterName=COB-ID
ObjectType=0x7
DataType=0x0007
AccessType=rw
DefaultValue=$NODEID+0x180 ; comment
[6064]
ParameterName=Position actual value
DataType=0x0004
AccessType=ro
PDOMapping=1
LowLimit=0x80000000
HighLimit=0x7FFFFFFF
"""
    od = import_eds(text, node_id=3)
    assert od.get(0x1016, 0) == 3 and od.entries[(0x1016, 1)].name == "Consumer 1"
    assert od.get(0x1800, 1) == 0x183 and od.entries[(0x1800, 1)].nodeid_offset
    assert od.entries[(0x6064, 0)].low == -(2**31)
    assert od.objects[0x6064].object_code is ObjectCode.VAR
    assert od.device_info["VendorName"] == "maxon"
    with pytest.raises(ConfigError):
        import_eds("[2000]\nParameterName=x\nDataType=0x0099\nAccessType=rw\n")


_INT_DTS = [dt for dt in DataType if type_range(dt) is not None and dt is not DataType.BOOLEAN]


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(_INT_DTS), st.data())
def test_integer_codec_round_trip(dt: DataType, data: st.DataObject) -> None:
    """CiA 301 7.1.4-7.1.5: every value of an integer type survives encode/decode, in size bytes."""
    low, high = type_range(dt)  # type: ignore[misc]
    value = data.draw(st.integers(low, high))
    entry = Entry(0x2000, 0, "x", dt)
    wire = encode(entry, value)
    assert len(wire) == entry.size
    assert decode(entry, wire) == value


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=12), st.sampled_from(list(DataType)))
def test_decode_never_raises_anything_but_sdo_abort(wire: bytes, dt: DataType) -> None:
    """Table 6-20: bytes of any length for any type give a value or an SdoAbort, nothing else."""
    entry = Entry(0x2000, 0, "x", dt, low=0 if dt in (DataType.INTEGER8, DataType.REAL32) else None)
    try:
        decode(entry, wire)
    except SdoAbort as exc:
        assert exc.code in (E.LENGTH_TOO_LOW, E.LENGTH_MISMATCH, E.VALUE_RANGE_EXCEEDED)


def test_dcf_spellings_and_domain_without_data_type() -> None:
    """CiA 306: [DeviceComissioning] (the standard's spelling, also accepted corrected) and a
    DOMAIN object (ObjectType 0x2) that omits DataType."""
    for section in ("DeviceComissioning", "DeviceCommissioning"):
        od = import_eds(f"[{section}]\nNodeID=0x21\n[1F50]\nParameterName=Program\n"
                                       "ObjectType=0x2\nAccessType=wo\n")
        assert od.node_id == 0x21
        assert od.entries[(0x1F50, 0)].data_type is DataType.DOMAIN
