"""ESI (ETG.2000) ``<Dictionary>`` export: data types and objects from the dictionary's own rows.

The EtherCAT device description (``ethercat/esi.py``) embeds it in the device's ``<Profile>``; the
same rows feed the CoE server and EDS export, so a configuration tool sees what the slave serves.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

from gatewaylab.od.dictionary import ObjectDictionary
from gatewaylab.od.types import ESI_TYPE_NAMES, DataType, Entry, ObjectCode, OdObject

__all__ = ["esi_dictionary"]


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
    if e.data_type in (DataType.VISIBLE_STRING, DataType.OCTET_STRING, DataType.UNICODE_STRING):
        return f"STRING({_bits(od, e) // 8})"
    return ESI_TYPE_NAMES.get(e.data_type, "USINT")


def _bits(od: ObjectDictionary, e: Entry) -> int:
    """BitSize: the type's size, a string's maximum length (the most a write may store)."""
    return max(8, od.bit_length(e.index, e.subindex))


def _flags(parent: ET.Element, e: Entry) -> None:
    flags = _sub(parent, "Flags")
    _sub(flags, "Access", _access(e))
    if e.rx_pdo:
        _sub(flags, "PdoMapping", "R")
    elif e.tx_pdo:
        _sub(flags, "PdoMapping", "T")


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
