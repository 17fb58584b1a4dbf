"""EDS / DCF (CiA 306) export and import of an :class:`~gatewaylab.od.ObjectDictionary`.

Export writes every object with ParameterName, ObjectType, DataType, AccessType, PDOMapping,
limits and DefaultValue (COB-IDs that follow the node-id as ``$NODEID+0x...``); a DCF adds
``ParameterValue`` with the present values and a [DeviceComissioning] section. Import reads VAR,
DOMAIN, ARRAY (also ``CompactSubObj``) and RECORD objects; a DCF's ParameterValue becomes the
value (the default stays the default).
"""

from __future__ import annotations

import configparser
import re
from typing import Any

from gatewaylab.common.errors import ConfigError
from gatewaylab.od.dictionary import ObjectDictionary
from gatewaylab.od.types import (
    BYTES_TYPES,
    FLOAT_TYPES,
    SIZED_TYPES,
    STRING_TYPES,
    UNDECLARED_STRING_LENGTH,
    Access,
    DataType,
    Entry,
    ObjectCode,
    coerce,
    type_range,
)

_NODEID = re.compile(r"\$NODEID", re.IGNORECASE)


def _fmt(entry: Entry, value: Any, *, relative: bool = False) -> str:
    dt = entry.data_type
    if dt in STRING_TYPES:
        return str(value)
    if dt in BYTES_TYPES:
        return bytes(value).hex().upper()
    if dt in FLOAT_TYPES:
        return repr(float(value))
    if dt is DataType.BOOLEAN:
        return "1" if value else "0"
    v = int(value)
    text = f"0x{v:X}" if v >= 0 else str(v)
    return f"$NODEID+{text}" if relative else text


def _export_entry(lines: list[str], section: str, entry: Entry, od: ObjectDictionary, dcf: bool) -> None:
    lines.append(f"[{section}]")
    lines.append(f"ParameterName={entry.name}")
    lines.append("ObjectType=0x7")
    lines.append(f"DataType=0x{int(entry.data_type):04X}")
    lines.append(f"AccessType={entry.access.value}")
    default = entry.default_for(None)
    lines.append(f"DefaultValue={_fmt(entry, coerce(entry, default), relative=entry.nodeid_offset)}")
    lines.append(f"PDOMapping={1 if entry.pdo_mappable else 0}")
    if entry.low is not None:
        lines.append(f"LowLimit={_fmt(entry, entry.low)}")
    if entry.high is not None:
        lines.append(f"HighLimit={_fmt(entry, entry.high)}")
    if entry.preop_only:
        lines.append("GatewaylabPreOpOnly=1")     # not in CiA 306; other tools ignore unknown keys
    if dcf:
        lines.append(f"ParameterValue={_fmt(entry, od.values[(entry.index, entry.subindex)])}")
    lines.append("")


def export_eds(od: ObjectDictionary, *, dcf: bool = False, node_id: int | None = None) -> str:
    """CiA 306 text for ``od``."""
    info = od.device_info
    ident = {sub: od.values.get((0x1018, sub), 0) for sub in (1, 2, 3)}
    lines = ["[FileInfo]", f"FileName={info.get('FileName', 'gatewaylab.' + ('dcf' if dcf else 'eds'))}",
             "FileVersion=1", "FileRevision=1", "EDSVersion=4.0",
             f"Description={info.get('Description', 'exported by gatewaylab')}",
             f"CreatedBy={info.get('CreatedBy', 'gatewaylab')}", "",
             "[DeviceInfo]", f"VendorName={info.get('VendorName', '')}",
             f"VendorNumber=0x{ident[1]:08X}", f"ProductName={info.get('ProductName', '')}",
             f"ProductNumber=0x{ident[2]:08X}", f"RevisionNumber=0x{ident[3]:08X}",
             f"OrderCode={info.get('OrderCode', '')}"]
    for rate in (10, 20, 50, 125, 250, 500, 800, 1000):
        lines.append(f"BaudRate_{rate}=1")
    n_rx = sum(1 for i in range(0x1400, 0x1600) if i in od.objects)
    n_tx = sum(1 for i in range(0x1800, 0x1A00) if i in od.objects)
    lines += ["SimpleBootUpMaster=0", "SimpleBootUpSlave=1", "Granularity=8",
              "DynamicChannelsSupported=0", "GroupMessaging=0", f"NrOfRXPDO={n_rx}", f"NrOfTXPDO={n_tx}",
              f"LSS_Supported={info.get('LSS_Supported', '1')}", ""]
    if dcf:
        lines += ["[DeviceComissioning]", f"NodeID={node_id if node_id is not None else 0xFF}",
                  f"NodeName={info.get('NodeName', '')}", "Baudrate=1000", ""]
    lines += ["[DummyUsage]"] + [f"Dummy{i:04X}={1 if i >= 2 else 0}" for i in range(1, 8)] + [""]
    mandatory = [i for i in (0x1000, 0x1001, 0x1018) if i in od.objects]
    # data type objects (PDO dummies) are declared by [DummyUsage] above, not listed as objects
    optional = [i for i in sorted(od.objects) if i not in mandatory and i >= 0x1000 and not 0x2000 <= i < 0x6000]
    manufacturer = [i for i in sorted(od.objects) if 0x2000 <= i < 0x6000]
    for title, group in (("MandatoryObjects", mandatory), ("OptionalObjects", optional),
                         ("ManufacturerObjects", manufacturer)):
        lines.append(f"[{title}]")
        lines.append(f"SupportedObjects={len(group)}")
        lines += [f"{n}=0x{index:04X}" for n, index in enumerate(group, 1)]
        lines.append("")
    for obj in od:
        if obj.index < 0x1000:
            continue
        if obj.object_code is ObjectCode.VAR or obj.object_code is ObjectCode.DOMAIN:
            _export_entry(lines, f"{obj.index:04X}", obj.entries[0], od, dcf)
            continue
        lines += [f"[{obj.index:04X}]", f"ParameterName={obj.name}",
                  f"ObjectType=0x{int(obj.object_code):X}", f"SubNumber={len(obj.entries)}", ""]
        for sub in sorted(obj.entries):
            _export_entry(lines, f"{obj.index:04X}sub{sub:X}", obj.entries[sub], od, dcf)
    return "\n".join(lines) + "\n"


def _parse_value(dt: DataType, text: str) -> tuple[Any, bool]:
    """(value, relative-to-node-id) of an EDS value string."""
    text = text.strip()
    if dt in STRING_TYPES:
        return text, False
    if dt in BYTES_TYPES:
        return bytes.fromhex(text.replace(" ", "")) if text else b"", False
    if not text:
        return None, False
    if dt in FLOAT_TYPES:
        return float(text), False
    compact = text.replace(" ", "")
    relative = bool(_NODEID.search(compact))
    if relative:
        compact = _NODEID.sub("", compact).strip("+") or "0"
    value = int(compact, 0)
    rng = type_range(dt)
    if rng is not None and rng[0] < 0 and value > rng[1]:
        value -= 1 << (8 * ((rng[1].bit_length() + 1) // 8))   # two's complement hex of a signed limit
    return value, relative


def import_eds(text: str, node_id: int | None = None) -> ObjectDictionary:
    """An ObjectDictionary from EDS/DCF text; ConfigError when the text is not a usable EDS."""
    return read_eds(text, node_id)[0]


def read_eds(text: str, node_id: int | None = None, *,
             parameter_values: bool = True) -> tuple[ObjectDictionary, list[str]]:
    """:func:`import_eds` and what it had to read leniently, one line each, as python canopen does: a
    DataType that names no basic type (a complex or manufacturer type, CiA 301 7.4.7.1 0x0040-0x025F,
    defined nowhere in the file) becomes DOMAIN; a DefaultValue that does not parse is left out. A
    DataType that is no number at all, or missing, is a ConfigError. ``parameter_values=False`` reads an
    EDS: its ParameterValues (configured values, CiA 306 DCF) are not the device's power-on values.
    [DummyUsage] entries set to 1 become readable data type objects 0x0001..0x0007 (their length in
    bits, CiA 301 7.4.7.1), mappable as PDO dummy entries."""
    warnings: list[str] = []
    cp = configparser.RawConfigParser(inline_comment_prefixes=(";",), strict=False)
    cp.optionxform = str  # type: ignore[assignment,method-assign]
    try:
        cp.read_string(text)
    except configparser.Error as exc:
        raise ConfigError(f"not an EDS/DCF: {' '.join(str(exc).split())}") from exc
    commissioning = next((sec for sec in ("DeviceComissioning", "DeviceCommissioning") if cp.has_section(sec)), None)
    if node_id is None and commissioning is not None:
        raw = cp.get(commissioning, "NodeID", fallback="")
        if raw.strip():
            nid = int(raw, 0)
            node_id = nid if 1 <= nid <= 127 else None
    od = ObjectDictionary(node_id)
    if cp.has_section("DeviceInfo"):
        for key in ("VendorName", "ProductName", "OrderCode", "LSS_Supported"):
            if cp.has_option("DeviceInfo", key):
                od.device_info[key] = cp.get("DeviceInfo", key)
    sections = {s.upper(): s for s in cp.sections()}
    configured: list[tuple[int, int, str]] = []

    def _data_type(section: str, code: int) -> DataType:
        try:
            return DataType(code)
        except ValueError:
            pass
        # CANFestival writes a type with limits as a definition object [00A0] whose sub 1 names the type
        definition = sections.get(f"{code:X}SUB1") or sections.get(f"{code:04X}SUB1")
        if definition is not None:
            try:
                return DataType(int(cp.get(definition, "DefaultValue"), 0))
            except (configparser.Error, ValueError):
                pass
        warnings.append(f"[{section}]: DataType 0x{code:04X} is no basic type and is defined nowhere in the file: "
                        "read as DOMAIN (bytes)")
        return DataType.DOMAIN

    def entry_args(section: str) -> tuple[dict[str, Any], str | None]:
        get = cp.get
        if not cp.has_option(section, "DataType") and \
                int(get(section, "ObjectType", fallback="0x7") or "0x7", 0) == ObjectCode.DOMAIN:
            cp.set(section, "DataType", "0x000F")       # CiA 306: a DOMAIN object may omit it
        try:
            code = int(get(section, "DataType"), 0)
        except (configparser.Error, ValueError) as exc:
            raise ConfigError(f"[{section}]: bad or missing DataType") from exc
        dt = _data_type(section, code)
        access_text = get(section, "AccessType", fallback="rw").strip().lower()
        try:
            access = Access(access_text)
        except ValueError:
            raise ConfigError(f"[{section}]: unknown AccessType {access_text!r}") from None
        try:
            default, relative = _parse_value(dt, get(section, "DefaultValue", fallback=""))
        except ValueError:
            warnings.append(f"[{section}]: DefaultValue {get(section, 'DefaultValue')!r} is no "
                            f"{dt.name} value: left out")
            default, relative = None, False
        low = high = None
        if dt not in STRING_TYPES and dt not in BYTES_TYPES:
            low = _parse_value(dt, get(section, "LowLimit", fallback=""))[0]
            high = _parse_value(dt, get(section, "HighLimit", fallback=""))[0]
        max_length = None
        if dt in SIZED_TYPES:
            # CiA 306 has no key for a string's size: a default's length is no limit a device would have
            size = len(default.encode("utf-16-le") if dt is DataType.UNICODE_STRING else default.encode()) \
                if isinstance(default, str) else len(default or b"")
            max_length = max(size, UNDECLARED_STRING_LENGTH)
        args = {"data_type": dt, "access": access, "default": default, "max_length": max_length,
                "pdo_mappable": bool(int(get(section, "PDOMapping", fallback="0") or "0", 0)),
                "low": low, "high": high, "nodeid_offset": relative,
                "preop_only": get(section, "GatewaylabPreOpOnly", fallback="0").strip() == "1"}
        return args, (get(section, "ParameterValue") if cp.has_option(section, "ParameterValue") else None)

    for upper, section in sorted(sections.items()):
        if not re.fullmatch(r"[0-9A-F]{4}", upper):
            continue
        index = int(upper, 16)
        if index < 0x1000 and index != 0:
            continue    # data type definitions
        name = cp.get(section, "ParameterName", fallback=f"Object {index:04X}")
        code = ObjectCode(int(cp.get(section, "ObjectType", fallback="0x7") or "0x7", 0))
        try:
            if code in (ObjectCode.VAR, ObjectCode.DOMAIN):
                args, pv = entry_args(section)
                od.add_variable(index, name, **args)
                if pv is not None and parameter_values:
                    configured.append((index, 0, pv))
            elif code in (ObjectCode.ARRAY, ObjectCode.RECORD):
                compact = int(cp.get(section, "CompactSubObj", fallback="0") or "0", 0)
                od.add_record(index, name, code)
                if compact:
                    args, _ = entry_args(section)
                    od.add_sub(index, 0, "Highest sub-index supported", DataType.UNSIGNED8, Access.RO, compact)
                    names = f"{index:04X}NAME"
                    for sub in range(1, compact + 1):
                        label = cp.get(sections[names], str(sub), fallback=f"{name} {sub}") \
                            if names in sections else f"{name} {sub}"
                        od.add_sub(index, sub, label, **args)
                    continue
                pattern = re.compile(rf"{upper}SUB([0-9A-F]+)")
                subs = sorted((int(m.group(1), 16), s) for u, s in sections.items() if (m := pattern.fullmatch(u)))
                for sub, subsection in subs:
                    args, pv = entry_args(subsection)
                    od.add_sub(index, sub, cp.get(subsection, "ParameterName", fallback=f"Sub {sub}"), **args)
                    if pv is not None and parameter_values:
                        configured.append((index, sub, pv))
        except (ValueError, KeyError, TypeError) as exc:
            raise ConfigError(f"[{section}]: {exc}") from exc
    if cp.has_section("DummyUsage"):
        for index in range(1, 8):
            raw_flag = cp.get("DummyUsage", f"Dummy{index:04X}", fallback="0").strip()
            if raw_flag == "1" and index not in od:
                bits = 1 if index == 1 else 8 * (1 << ((index - 2) % 3))
                od.add_variable(index, f"Dummy{index:04X}", DataType.UNSIGNED32, Access.CONST, bits)
    for index, sub, raw in configured:
        entry = od.entries[(index, sub)]
        try:
            value, relative = _parse_value(entry.data_type, raw)
        except ValueError:
            warnings.append(f"0x{index:04X}:{sub:02X}: ParameterValue {raw!r} is no {entry.data_type.name} value: "
                            "the default stays")
            continue
        if value is None:
            continue
        if relative and node_id is not None:
            value += node_id
        try:
            od.values[(index, sub)] = coerce(entry, value)
        except ConfigError:
            pass
    return od, warnings
