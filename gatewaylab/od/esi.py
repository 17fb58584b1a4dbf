"""ESI (ETG.2000) ``<Dictionary>`` export: data types and objects from the dictionary's own rows.

The EtherCAT device description (``ethercat/esi.py``) embeds it in the device's ``<Profile>``; the
same rows feed the CoE server and EDS export, so a configuration tool sees what the slave serves.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

from gatewaylab.od.dictionary import ObjectDictionary
from gatewaylab.od.types import ESI_TYPE_NAMES, DataType, Entry, ObjectCode, OdObject

__all__ = ["esi_dictionary", "esi_type_name"]

#: ETG.2000 names of the types ``ESI_TYPE_NAMES`` leaves out (so every type reads back as itself).
_MORE_NAMES: dict[DataType, str] = {
    DataType.INTEGER24: "INT24", DataType.UNSIGNED24: "UINT24", DataType.INTEGER40: "INT40",
    DataType.UNSIGNED40: "UINT40", DataType.INTEGER48: "INT48", DataType.UNSIGNED48: "UINT48",
    DataType.INTEGER56: "INT56", DataType.UNSIGNED56: "UINT56", DataType.TIME_OF_DAY: "TIME_OF_DAY",
    DataType.TIME_DIFFERENCE: "TIME_DIFFERENCE",
}


def esi_type_name(data_type: DataType, size: int = 1) -> str:
    """The ETG.2000 name of a type; strings carry their length in bytes (``STRING(n)``, ``OCTET_STRING(n)``)."""
    if data_type is DataType.VISIBLE_STRING:
        return f"STRING({max(1, size)})"
    if data_type in (DataType.OCTET_STRING, DataType.UNICODE_STRING):
        return f"{ESI_TYPE_NAMES[data_type]}({max(1, size)})"
    return ESI_TYPE_NAMES.get(data_type) or _MORE_NAMES.get(data_type, "USINT")


def _sub(parent: ET.Element, tag: str, text: str | None = None, **attrs: str) -> ET.Element:
    el = ET.SubElement(parent, tag, attrs)
    if text is not None:
        el.text = text
    return el


def _access(e: Entry) -> str:
    if e.access.writable and e.access.readable:
        return "rw"
    return "wo" if e.access.writable else "ro"


def _type_name(od: ObjectDictionary, e: Entry) -> str:
    # strings by their declared maximum length (what a write may store), as the BitSize says
    return esi_type_name(e.data_type, _bits(od, e) // 8)


def _bits(od: ObjectDictionary, e: Entry) -> int:
    """BitSize: the type's size, a string's maximum length (the most a write may store)."""
    return max(8, od.bit_length(e.index, e.subindex))


def _flags(parent: ET.Element, e: Entry) -> None:
    flags = _sub(parent, "Flags")
    access = _sub(flags, "Access", _access(e))
    if e.preop_only and e.access.writable:
        access.set("WriteRestrictions", "PreOP")   # ETG.2000 AccessType: writable in PREOP only
    if e.rx_pdo or e.tx_pdo:
        _sub(flags, "PdoMapping", ("R" if e.rx_pdo else "") + ("T" if e.tx_pdo else ""))


def _default(parent: ET.Element, od: ObjectDictionary, e: Entry) -> None:
    raw = od.get_bytes(e.index, e.subindex)
    # XML 1.0 has no NUL or other control characters: a string holding any (an empty STRING(16) unit
    # is 16 NULs) goes out as hex DefaultData, or the ESI would not be well-formed
    if e.data_type == DataType.VISIBLE_STRING and all(0x20 <= b < 0x7F for b in raw):
        _sub(parent, "DefaultString", raw.decode("latin-1"))
    else:
        _sub(parent, "DefaultData", raw.hex().upper())


def esi_dictionary(profile: ET.Element, od: ObjectDictionary) -> None:
    """Append ``<Dictionary>`` (DataTypes with sub-items for records/arrays, Objects) to ``profile``."""
    dictionary = _sub(profile, "Dictionary")
    types = _sub(dictionary, "DataTypes")
    objects = _sub(dictionary, "Objects")
    base_types: dict[str, int] = {}
    for obj in od:
        for e in obj.entries.values():
            base_types[_type_name(od, e)] = _bits(od, e)
    for name, bits in sorted(base_types.items()):
        dt = _sub(types, "DataType")
        _sub(dt, "Name", name)
        _sub(dt, "BitSize", str(bits))
    for obj in od:
        _object(od, types, objects, obj)


def _object(od: ObjectDictionary, types: ET.Element, objects: ET.Element, obj: OdObject) -> None:
    el = _sub(objects, "Object")
    _sub(el, "Index", f"#x{obj.index:04X}")
    _sub(el, "Name", obj.name)
    if obj.object_code is ObjectCode.VAR:
        e = obj.entries[0]
        _sub(el, "Type", _type_name(od, e))
        _sub(el, "BitSize", str(_bits(od, e)))
        _default(_sub(el, "Info"), od, e)
        _flags(el, e)
        return
    type_name = f"DT{obj.index:04X}"
    if _uniform_array(obj):
        _array(od, types, el, obj, type_name)
        return
    dt = _sub(types, "DataType")
    _sub(dt, "Name", type_name)
    offset = 0
    subitems: list[tuple[Entry, int]] = []
    for sub in sorted(obj.entries):
        e = obj.entries[sub]
        subitems.append((e, offset))
        offset += 16 if sub == 0 else _bits(od, e)
    _sub(dt, "BitSize", str(offset))
    for e, off in subitems:
        si = _sub(dt, "SubItem")
        _sub(si, "SubIdx", str(e.subindex))
        _sub(si, "Name", e.name)
        _sub(si, "Type", _type_name(od, e))
        _sub(si, "BitSize", str(_bits(od, e)))
        _sub(si, "BitOffs", str(off))
        _flags(si, e)
    _sub(el, "Type", type_name)
    _sub(el, "BitSize", str(offset))
    info = _sub(el, "Info")
    for e, _off in subitems:
        si = _sub(info, "SubItem")
        _sub(si, "Name", e.name)
        _default(_sub(si, "Info"), od, e)
    _flags(el, obj.entries[0])


def _uniform_array(obj: OdObject) -> bool:
    """An ARRAY whose elements 1..n share one type and access (ETG.2000 writes it with ``ArrayInfo``)."""
    if obj.object_code is not ObjectCode.ARRAY or 0 not in obj.entries:
        return False
    subs = sorted(s for s in obj.entries if s)
    if not subs or subs != list(range(1, len(subs) + 1)):
        return False
    first = obj.entries[1]
    return all((e.data_type, e.access, e.pdo_mappable, e.preop_only) ==
               (first.data_type, first.access, first.pdo_mappable, first.preop_only)
               for e in (obj.entries[s] for s in subs)) and first.bit_length > 0


def _array(od: ObjectDictionary, types: ET.Element, el: ET.Element, obj: OdObject, type_name: str) -> None:
    """An ARRAY as ETG.2000 gives it: an ``ArrayInfo`` type for the elements, subindex 0 and the
    elements as the object type's two sub-items, the names and defaults of every subindex in ``Info``."""
    zero, first = obj.entries[0], obj.entries[1]
    n = len(obj.entries) - 1
    bits = first.bit_length
    arr = _sub(types, "DataType")
    _sub(arr, "Name", f"{type_name}ARR")
    _sub(arr, "BaseType", _type_name(od, first))
    _sub(arr, "BitSize", str(n * bits))
    info_el = _sub(arr, "ArrayInfo")
    _sub(info_el, "LBound", "1")
    _sub(info_el, "Elements", str(n))
    dt = _sub(types, "DataType")
    _sub(dt, "Name", type_name)
    _sub(dt, "BitSize", str(16 + n * bits))
    si = _sub(dt, "SubItem")
    _sub(si, "SubIdx", "0")
    _sub(si, "Name", zero.name)
    _sub(si, "Type", "USINT")
    _sub(si, "BitSize", "8")
    _sub(si, "BitOffs", "0")
    _flags(si, zero)
    si = _sub(dt, "SubItem")
    _sub(si, "Name", "Elements")
    _sub(si, "Type", f"{type_name}ARR")
    _sub(si, "BitSize", str(n * bits))
    _sub(si, "BitOffs", "16")
    _flags(si, first)
    _sub(el, "Type", type_name)
    _sub(el, "BitSize", str(16 + n * bits))
    info = _sub(el, "Info")
    for sub in sorted(obj.entries):
        e = obj.entries[sub]
        item = _sub(info, "SubItem")
        _sub(item, "Name", e.name)
        _default(_sub(item, "Info"), od, e)
    _flags(el, zero)
