"""ESI (ETG.2000 EtherCAT Slave Information) reader: one ``<Device>`` of a file -> a description a slave runs from.

What the ESI says becomes a :class:`~gatewaylab.ethercat.description.DeviceDescription` (identity,
mailbox SyncManagers and protocols, process data SyncManagers, RxPDOs/TxPDOs with their default
assignment, DC op modes, the EEPROM configuration area and size) plus the ``<Profile><Dictionary>``
objects, laid over the standard objects :func:`~gatewaylab.ethercat.description.build_od` makes
from the description (a device without a dictionary keeps those, with generic objects for every
mapped entry). ``<Eeprom><Data>`` (or a ``sii`` dump) is the SII byte for byte.

Every problem is one :class:`EsiError` line: the file, the element and what is wrong.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from gatewaylab.common.errors import ConfigError
from gatewaylab.ethercat.description import DeviceDescription, Pdo, PdoEntry
from gatewaylab.ethercat.esc_registers import RAM_START, SmConfig
from gatewaylab.od import Access, DataType, Entry, ObjectCode, ObjectDictionary, SdoAbort, decode
from gatewaylab.od.types import ESI_TYPE_NAMES, SIZED_TYPES

__all__ = ["EsiDevice", "EsiError", "EsiObject", "EsiSub", "apply_dictionary", "esi_device", "esi_types",
           "identity_overrides", "parse_esi", "read_esi", "read_esi_file"]


class EsiError(ConfigError):
    """An ESI file that cannot describe a slave (exit 2 on the command line)."""


#: ETG.2000 base type names -> CoE data types (the inverse of the export's, plus the other spellings).
_BASE: dict[str, DataType] = {name: dt for dt, name in ESI_TYPE_NAMES.items()}
_BASE.update({
    "BIT": DataType.BOOLEAN, "BOOLEAN": DataType.BOOLEAN, "BYTE": DataType.UNSIGNED8, "WORD": DataType.UNSIGNED16,
    "DWORD": DataType.UNSIGNED32, "LWORD": DataType.UNSIGNED64, "INT24": DataType.INTEGER24,
    "UINT24": DataType.UNSIGNED24, "INT40": DataType.INTEGER40, "UINT40": DataType.UNSIGNED40,
    "INT48": DataType.INTEGER48, "UINT48": DataType.UNSIGNED48, "INT56": DataType.INTEGER56,
    "UINT56": DataType.UNSIGNED56, "TIME_OF_DAY": DataType.TIME_OF_DAY,
    "TIME_DIFFERENCE": DataType.TIME_DIFFERENCE, "FLOAT": DataType.REAL32, "DOUBLE": DataType.REAL64,
    "VISIBLE_STRING": DataType.VISIBLE_STRING,
})
_SIZED = re.compile(r"^(STRING|OCTET_STRING|UNICODE_STRING|VISIBLE_STRING)\((\d+)\)$")
_BITN = re.compile(r"^BIT(\d+)$")


def esi_types() -> dict[str, DataType]:
    """ETG.2000 type names this reader knows (``STRING(n)`` / ``OCTET_STRING(n)`` / ``BITn`` besides)."""
    return dict(_BASE)


def _base_type(name: str) -> DataType | None:
    name = name.strip()
    if name in _BASE:
        return _BASE[name]
    m = _SIZED.match(name)
    if m:
        return {"OCTET_STRING": DataType.OCTET_STRING, "UNICODE_STRING": DataType.UNICODE_STRING}.get(
            m.group(1), DataType.VISIBLE_STRING)
    m = _BITN.match(name)
    if m:
        bits = int(m.group(1))
        return DataType.BOOLEAN if bits == 1 else DataType.UNSIGNED8 if bits <= 8 else (
            DataType.UNSIGNED16 if bits <= 16 else DataType.UNSIGNED32)
    return None


def _strip(root: ET.Element) -> None:
    """Drop XML namespaces from tags (some tools write a default namespace)."""
    for el in root.iter():
        if isinstance(el.tag, str) and "}" in el.tag:
            el.tag = el.tag.split("}", 1)[1]


@dataclass(frozen=True, slots=True)
class EsiSub:
    """One entry of a dictionary object as the ESI gives it."""

    subindex: int
    name: str
    data_type: DataType
    access: Access
    pdo_mappable: bool
    preop_only: bool
    default: Any
    #: a string's size in bytes as the ESI declares it (``STRING(n)`` or BitSize); None for other types
    max_length: int | None = None


@dataclass(frozen=True, slots=True)
class EsiObject:
    """One ``<Object>`` of ``<Dictionary>``: VAR (one sub, index 0), ARRAY or RECORD."""

    index: int
    name: str
    code: ObjectCode
    subs: tuple[EsiSub, ...]


@dataclass(frozen=True, slots=True)
class EsiDevice:
    """One device of an ESI file, ready for a :class:`~gatewaylab.ethercat.slave.Slave`."""

    source: str
    type_name: str
    desc: DeviceDescription
    #: The ``<Dictionary>`` objects; None when the device has none (the generic dictionary is used).
    objects: tuple[EsiObject, ...] | None
    #: ``<Eeprom><Data>``: the SII byte for byte; None = generated from the description.
    sii: bytes | None
    #: Mailbox protocols the ESI declares (CoE, FoE, EoE, SoE, AoE, VoE).
    protocols: tuple[str, ...]
    #: ``<Info><StateMachine><Timeout>`` in ms (PreopTimeout, SafeopOpTimeout, BackToInitTimeout, ...), and
    #: ``<Info><Mailbox><Timeout>`` (RequestTimeout, ResponseTimeout).
    timeouts: dict[str, int] = field(default_factory=dict)
    #: Max size of the process data SyncManagers (``Sm MaxSize``), None when not given.
    outputs_max: int | None = None
    inputs_max: int | None = None
    #: What the slave does differently from the file (said once in the log).
    notes: tuple[str, ...] = ()


class _Ctx:
    """Error context: the file and the element path."""

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, where: str, what: str) -> EsiError:
        return EsiError(f"{self.source}: {where}: {what}")

    def number(self, text: str | None, where: str, default: int | None = None) -> int:
        if text is None or not text.strip():
            if default is None:
                raise self.fail(where, "missing number")
            return default
        t = text.strip()
        try:
            if t.startswith("#x") or t.startswith("#X"):
                return int(t[2:], 16)
            return int(t, 0) if t.lower().startswith("0x") else int(t)
        except ValueError:
            raise self.fail(where, f"{t!r} is not a number") from None


def _text(el: ET.Element | None, tag: str, default: str = "") -> str:
    if el is None:
        return default
    found = el.find(tag)
    if found is None or found.text is None:
        return default
    return found.text.strip()


def _name(el: ET.Element) -> str:
    """The first ``<Name>`` (English, LcId 1033, when there are several)."""
    names = el.findall("Name")
    for n in names:
        if n.get("LcId", "1033") == "1033" and n.text:
            return n.text.strip()
    return (names[0].text or "").strip() if names else ""


# ------------------------------------------------------------------------------------------ reading
def read_esi_file(path: Path, type_name: str | None = None, product_code: int | None = None,
                  revision: int | None = None) -> EsiDevice:
    """Read ``path`` and pick one device (by ``<Type>`` text, or product code / revision)."""
    try:
        text = path.read_bytes()
    except OSError as exc:
        raise EsiError(f"{path}: cannot read it ({exc.strerror or exc})") from None
    return read_esi(text, path.name, type_name, product_code, revision)


def read_esi(text: bytes | str, source: str = "ESI", type_name: str | None = None,
             product_code: int | None = None, revision: int | None = None) -> EsiDevice:
    """Parse ESI text (``source`` names it in errors) and pick one device."""
    return esi_device(parse_esi(text, source), source, type_name, product_code, revision)


def parse_esi(text: bytes | str, source: str = "ESI") -> ET.Element:
    """The XML tree of an ESI file, namespaces dropped from its tags (any root element: the caller checks it).
    Nothing changes the tree afterwards: one parse serves every device read from it."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        line, col = exc.position
        raise EsiError(f"{source}: line {line} column {col}: malformed XML ({exc.msg if hasattr(exc, 'msg') else exc})"
                       ) from None
    _strip(root)
    return root


def esi_device(root: ET.Element, source: str = "ESI", type_name: str | None = None,
               product_code: int | None = None, revision: int | None = None) -> EsiDevice:
    """One device of a tree :func:`parse_esi` made (by ``<Type>`` text, or product code / revision)."""
    ctx = _Ctx(source)
    if root.tag != "EtherCATInfo":
        raise ctx.fail(f"<{root.tag}>", "the root element must be <EtherCATInfo>")
    vendor = root.find("Vendor")
    vendor_id = ctx.number(_text(vendor, "Id"), "Vendor/Id")
    vendor_name = _text(vendor, "Name", "unknown")
    devices = root.findall("Descriptions/Devices/Device")
    if not devices:
        raise ctx.fail("Descriptions/Devices", "no <Device>")
    chosen = _choose(ctx, devices, type_name, product_code, revision)
    return _device(ctx, chosen, vendor_id, vendor_name)


def _identity(ctx: _Ctx, dev: ET.Element) -> tuple[str, int, int]:
    t = dev.find("Type")
    if t is None:
        raise ctx.fail("Device", "no <Type>")
    where = f"Device {(t.text or '').strip()!r}"
    return ((t.text or "").strip(), ctx.number(t.get("ProductCode"), f"{where} Type@ProductCode", 0),
            ctx.number(t.get("RevisionNo"), f"{where} Type@RevisionNo", 0))


def _choose(ctx: _Ctx, devices: list[ET.Element], type_name: str | None, product_code: int | None,
            revision: int | None) -> ET.Element:
    rows = [(_identity(ctx, d), d) for d in devices]
    picked = [d for (t, p, r), d in rows if (type_name is None or t == type_name)
              and (product_code is None or p == product_code) and (revision is None or r == revision)]
    known = ", ".join(f"{t} (product 0x{p:X} rev 0x{r:X})" for (t, p, r), _ in rows)
    if not picked:
        asked = " ".join(x for x in (f"type {type_name!r}" if type_name else "",
                                     f"product_code 0x{product_code:X}" if product_code is not None else "",
                                     f"revision 0x{revision:X}" if revision is not None else "") if x)
        raise ctx.fail("Descriptions/Devices", f"no device with {asked} (the file has {known})")
    if len(picked) > 1:
        raise ctx.fail("Descriptions/Devices", f"{len(picked)} devices match; say type = (the file has {known})")
    return picked[0]


def _hexbytes(ctx: _Ctx, text: str, where: str) -> bytes:
    try:
        return bytes.fromhex("".join(text.split()))
    except ValueError:
        raise ctx.fail(where, "not hex bytes") from None


def _device(ctx: _Ctx, dev: ET.Element, vendor_id: int, vendor_name: str) -> EsiDevice:
    type_name, product, rev = _identity(ctx, dev)
    here = f"Device {type_name!r}"
    name = _name(dev) or type_name
    group = _text(dev, "GroupType", vendor_name)
    # SyncManagers by their text (MBoxOut, MBoxIn, Outputs, Inputs)
    sms: dict[str, ET.Element] = {}
    for sm in dev.findall("Sm"):
        sms.setdefault((sm.text or "").strip(), sm)
    mailbox = dev.find("Mailbox")
    protocols = tuple(child.tag for child in mailbox) if mailbox is not None else ()
    coe_el = mailbox.find("CoE") if mailbox is not None else None
    coe, foe = coe_el is not None, "FoE" in protocols
    other = sum(bit for tag, bit in (("AoE", 0x01), ("EoE", 0x02), ("SoE", 0x10), ("VoE", 0x20)) if tag in protocols)
    kwargs: dict[str, Any] = {}

    def sm_row(label: str, default_start: int, default_control: int) -> tuple[int, int, int, int | None, bool]:
        el = sms.get(label)
        if el is None:
            return default_start, 0, default_control, None, False
        w = f"{here} Sm {label}"
        size = ctx.number(el.get("DefaultSize"), f"{w}@DefaultSize", -1)
        max_size = ctx.number(el.get("MaxSize"), f"{w}@MaxSize", 0) or None
        return (ctx.number(el.get("StartAddress"), f"{w}@StartAddress"), size,
                ctx.number(el.get("ControlByte"), f"{w}@ControlByte", default_control), max_size,
                el.get("Enable", "1") not in ("0", "false"))

    if coe or foe or other:
        for label, key in (("MBoxOut", "mailbox_out"), ("MBoxIn", "mailbox_in")):
            start, size, _c, max_size, _en = sm_row(label, 0, 0)
            if label not in sms:
                raise ctx.fail(here, f"declares a mailbox but has no <Sm>{label}</Sm>")
            kwargs[key] = (start, size if size > 0 else max_size or 0)
    order = [(sm.text or "").strip() for sm in dev.findall("Sm")]
    kwargs["inputs_first"] = not (coe or foe or other) and order[:1] == ["Inputs"] and "Outputs" not in sms
    out_start, out_size, out_ctrl, out_max, _ = sm_row("Outputs", 0x1100, 0x64)
    in_start, in_size, in_ctrl, in_max, _ = sm_row("Inputs", 0x1400, 0x20)
    notes: list[str] = []
    rx = tuple(_pdo(ctx, p, here, DataType.UNSIGNED8) for p in dev.findall("RxPdo"))
    tx = tuple(_pdo(ctx, p, here, DataType.UNSIGNED8) for p in dev.findall("TxPdo"))
    rx_assign = tuple(p.index for p, el in zip(rx, dev.findall("RxPdo"), strict=True) if el.get("Sm") is not None)
    tx_assign = tuple(p.index for p, el in zip(tx, dev.findall("TxPdo"), strict=True) if el.get("Sm") is not None)
    sizes = []
    for pdos, assign, size, max_size, label in ((rx, rx_assign, out_size, out_max, "Outputs"),
                                               (tx, tx_assign, in_size, in_max, "Inputs")):
        bits = sum(p.bit_length for p in pdos if p.index in assign)
        if size < 0:    # no DefaultSize (SOES's files): the default assignment's size
            size = (bits + 7) // 8
        sizes.append(size)
        limit = max(size, max_size or 0)
        if bits and (label not in sms or (bits + 7) // 8 > limit):
            raise ctx.fail(f"{here} {'RxPdo' if label == 'Outputs' else 'TxPdo'}",
                           f"the assigned PDOs map {bits} bits, more than <Sm>{label}</Sm> holds "
                           f"({8 * limit} bits)")
    out_size, in_size = sizes
    # A SyncManager runs where the file puts it, an EL2008's outputs on the ESC's Digital I/O Output Data
    # register 0x0F00 included; anywhere else below the process RAM the ESC refuses it, as a real one does.
    for label, start, size, ctrl in (("Outputs", out_start, out_size, out_ctrl),
                                     ("Inputs", in_start, in_size, in_ctrl)):
        if label in sms and start < RAM_START and not SmConfig(0, start, max(size, 1), ctrl, 1).on_output_register:
            notes.append(f"Sm {label} at 0x{start:04X} lies on the ESC registers: the ESC refuses it "
                         f"(AL status 0x0017 at PREOP -> SAFEOP)")
    # DC op modes
    dc_el = dev.find("Dc")
    op_modes = []
    if dc_el is not None:
        for mode in dc_el.findall("OpMode"):
            op_modes.append((_text(mode, "Name"), _text(mode, "Desc"),
                             ctx.number(_text(mode, "AssignActivate"), f"{here} Dc/OpMode/AssignActivate", 0)))
    if op_modes:
        kwargs["dc_op_modes"] = tuple(op_modes)
    # EEPROM
    eeprom = dev.find("Eeprom")
    sii: bytes | None = None
    if eeprom is not None:
        data = _text(eeprom, "Data")
        if data:
            sii = _hexbytes(ctx, data, f"{here} Eeprom/Data")
            if len(sii) < 0x80:
                raise ctx.fail(f"{here} Eeprom/Data", f"{len(sii)} bytes, shorter than the SII's fixed 128")
        config = _text(eeprom, "ConfigData")
        if config:
            raw = _hexbytes(ctx, config, f"{here} Eeprom/ConfigData")
            kwargs["sii_config"] = raw[:14].ljust(14, b"\0")
        size_text = _text(eeprom, "ByteSize")
        if size_text:
            kwargs["eeprom_bytes"] = ctx.number(size_text, f"{here} Eeprom/ByteSize")
        boot = _text(eeprom, "BootStrap")
        if boot:
            raw = _hexbytes(ctx, boot, f"{here} Eeprom/BootStrap").ljust(8, b"\0")
            kwargs["bootstrap"] = True
            kwargs["bootstrap_mailbox"] = tuple(int.from_bytes(raw[i:i + 2], "little") for i in range(0, 8, 2))
        cats = []
        for cat in eeprom.findall("Category"):
            no = ctx.number(_text(cat, "CatNo"), f"{here} Eeprom/Category/CatNo")
            cats.append((no, _hexbytes(ctx, _text(cat, "Data"), f"{here} Eeprom/Category {no}/Data")))
        if cats:
            kwargs["sii_categories"] = tuple(cats)
    if coe_el is not None:
        flag = {k: coe_el.get(k, "0") in ("1", "true") for k in
                ("SdoInfo", "PdoAssign", "PdoConfig", "PdoUpload", "CompleteAccess")}
        kwargs["coe_details"] = (0x01 | (0x02 if flag["SdoInfo"] else 0) | (0x04 if flag["PdoAssign"] else 0)
                                 | (0x08 if flag["PdoConfig"] else 0) | (0x10 if flag["PdoUpload"] else 0)
                                 | (0x20 if flag["CompleteAccess"] else 0))
    profile = dev.find("Profile")
    device_type = 0
    if profile is not None:
        device_type = (ctx.number(_text(profile, "ProfileNo"), f"{here} Profile/ProfileNo", 0) & 0xFFFF) | (
            (ctx.number(_text(profile, "AddInfo"), f"{here} Profile/AddInfo", 0) & 0xFFFF) << 16)
    timeouts: dict[str, int] = {}
    for part in ("StateMachine", "Mailbox"):       # Mailbox: RequestTimeout, ResponseTimeout (kept, not timed)
        for t in dev.findall(f"Info/{part}/Timeout/*"):
            if t.text and t.text.strip():
                timeouts[t.tag] = ctx.number(t.text, f"{here} Info/{part}/Timeout/{t.tag}")
    objects: tuple[EsiObject, ...] | None = None
    dictionary = profile.find("Dictionary") if profile is not None else None
    if dictionary is not None:
        objects = _dictionary(ctx, dictionary, here)
    try:
        desc = DeviceDescription(
            name=name, vendor_id=vendor_id, product_code=product, revision=rev, vendor_name=vendor_name,
            group=group, order_code=type_name, outputs_start=out_start, inputs_start=in_start,
            outputs_control=out_ctrl, inputs_control=in_ctrl, outputs_sm_size=out_size, inputs_sm_size=in_size,
            rx_pdos=rx, tx_pdos=tx, rx_assign=rx_assign, tx_assign=tx_assign, coe=coe, foe=foe,
            other_protocols=other, dc=dc_el is not None, device_type=device_type, **kwargs)
    except ConfigError as exc:
        raise ctx.fail(here, str(exc)) from None
    return EsiDevice(ctx.source, type_name, desc, objects, sii, protocols, timeouts, out_max, in_max, tuple(notes))


def _pdo(ctx: _Ctx, el: ET.Element, here: str, default: DataType) -> Pdo:
    index = ctx.number(_text(el, "Index"), f"{here} {el.tag}/Index")
    w = f"{here} {el.tag} #x{index:04X}"
    entries = []
    for i, e in enumerate(el.findall("Entry"), 1):
        ew = f"{w} Entry {i}"
        eindex = ctx.number(_text(e, "Index"), f"{ew}/Index")
        bits = ctx.number(_text(e, "BitLen"), f"{ew}/BitLen")
        if not 0 < bits <= 255:
            raise ctx.fail(f"{ew}/BitLen", f"{bits} bits (1..255)")
        dtype = default
        if eindex:
            tname = _text(e, "DataType")
            found = _base_type(tname) if tname else None
            if tname and found is None:
                raise ctx.fail(f"{ew}/DataType", f"unknown data type {tname!r}")
            if found is not None:
                dtype = found
        entries.append(PdoEntry(eindex, ctx.number(_text(e, "SubIndex"), f"{ew}/SubIndex", 0) if eindex else 0,
                                bits, _text(e, "Name"), dtype))
    exclude = tuple(ctx.number(x.text, f"{w}/Exclude") for x in el.findall("Exclude"))
    return Pdo(index, _name(el), tuple(entries), fixed=el.get("Fixed", "0") in ("1", "true"), exclude=exclude)


# ------------------------------------------------------------------------------------------ dictionary
@dataclass(frozen=True, slots=True)
class _Type:
    name: str
    bits: int
    base: DataType | None
    array: tuple[int, int] | None      # (lbound, elements)
    base_name: str
    subitems: tuple[ET.Element, ...]


def _flags(ctx: _Ctx, el: ET.Element | None, where: str) -> tuple[Access, bool, bool] | None:
    """(access, pdo mappable, writable in PREOP only) of a ``<Flags>``; None when there is none."""
    if el is None:
        return None
    acc_el = el.find("Access")
    text = (acc_el.text or "ro").strip().lower() if acc_el is not None else "ro"
    restrict = (acc_el.get("WriteRestrictions", "") if acc_el is not None else "").strip()
    mapping = _text(el, "PdoMapping").upper()
    rx, tx = "R" in mapping, "T" in mapping
    if text == "ro":
        access = Access.RO
    elif text == "wo":
        access = Access.WO
    elif text == "rw":
        access = Access.RWW if rx and not tx else Access.RWR if tx and not rx else Access.RW
    else:
        raise ctx.fail(f"{where}/Flags/Access", f"{text!r} is not ro, rw or wo")
    return access, bool(mapping), restrict == "PreOP"


def _default(ctx: _Ctx, info: ET.Element | None, dtype: DataType, where: str) -> Any:
    if info is None:
        return None
    raw_hex = _text(info, "DefaultData")
    try:
        if raw_hex:
            raw = _hexbytes(ctx, raw_hex, f"{where}/DefaultData")
            return decode(Entry(0x2000, 0, "", dtype), raw)
        string = info.find("DefaultString")
        if string is not None:
            return (string.text or "") if dtype is DataType.VISIBLE_STRING else (string.text or "").encode("latin-1")
        value = _text(info, "DefaultValue")
        if value:
            if dtype in (DataType.REAL32, DataType.REAL64):
                return float(value)
            return ctx.number(value, f"{where}/DefaultValue")
    except (SdoAbort, ValueError) as exc:
        raise ctx.fail(where, f"default does not fit {dtype.name} ({exc})") from None
    return None


def _dictionary(ctx: _Ctx, dictionary: ET.Element, here: str) -> tuple[EsiObject, ...]:
    types: dict[str, _Type] = {}
    for dt in dictionary.findall("DataTypes/DataType"):
        tname = _text(dt, "Name")
        w = f"{here} DataType {tname!r}"
        arr = dt.find("ArrayInfo")
        array = None
        if arr is not None:
            array = (ctx.number(_text(arr, "LBound"), f"{w}/ArrayInfo/LBound", 0),
                     ctx.number(_text(arr, "Elements"), f"{w}/ArrayInfo/Elements"))
        base_name = _text(dt, "BaseType")
        types[tname] = _Type(tname, ctx.number(_text(dt, "BitSize"), f"{w}/BitSize", 0),
                             _base_type(tname), array, base_name, tuple(dt.findall("SubItem")))
    out = []
    for obj in dictionary.findall("Objects/Object"):
        index = ctx.number(_text(obj, "Index"), f"{here} Object/Index")
        out.append(_object(ctx, types, obj, index, f"{here} Object #x{index:04X}"))
    return tuple(out)


def _resolve(ctx: _Ctx, types: dict[str, _Type], name: str, where: str) -> DataType:
    """The CoE type of a VAR type name (a base type, or a named type with a base type)."""
    base = _base_type(name)
    if base is not None:
        return base
    t = types.get(name)
    if t is not None and t.base_name and not t.array and not t.subitems:
        return _resolve(ctx, types, t.base_name, where)
    raise ctx.fail(f"{where}/Type", f"unknown data type {name!r}")


def _string_size(dtype: DataType, tname: str, el: ET.Element) -> int | None:
    """A string's declared size in bytes: ``STRING(n)``, else the element's BitSize / 8 (None: not a string)."""
    if dtype not in SIZED_TYPES:
        return None
    m = _SIZED.match(tname)
    if m is not None:
        return int(m.group(2))
    bits = _text(el, "BitSize")
    return int(bits, 0) // 8 if bits.isdigit() and int(bits) >= 8 else None


def _object(ctx: _Ctx, types: dict[str, _Type], obj: ET.Element, index: int, w: str) -> EsiObject:
    name = _name(obj)
    tname = _text(obj, "Type")
    flags = _flags(ctx, obj.find("Flags"), w) or (Access.RO, False, False)
    info = obj.find("Info")
    t = types.get(tname)
    if t is None or (not t.subitems and not t.array):
        dtype = _resolve(ctx, types, tname, w)
        return EsiObject(index, name, ObjectCode.VAR,
                         (EsiSub(0, name, dtype, flags[0], flags[1], flags[2], _default(ctx, info, dtype, w),
                                 _string_size(dtype, tname, obj)),))
    infos = info.findall("SubItem") if info is not None else []
    info_by_name = {_text(s, "Name"): s.find("Info") for s in infos}

    def sub_info(k: int, sname: str) -> ET.Element | None:
        """The ``Info`` of sub-item ``k``: by position when the names agree there (names may repeat, as
        SOES's 'PDO Mapping' rows do), else by name, else by position."""
        if k < len(infos) and _text(infos[k], "Name") == sname:
            return infos[k].find("Info")
        if sname in info_by_name:
            return info_by_name[sname]
        return infos[k].find("Info") if k < len(infos) else None

    subs: list[EsiSub] = []
    array_item = next((s for s in t.subitems if (st := types.get(_text(s, "Type"))) is not None and st.array), None)
    if array_item is not None:
        at = types[_text(array_item, "Type")]
        assert at.array is not None
        elem_type = _resolve(ctx, types, at.base_name, f"{w} DataType {at.name!r}/BaseType")
        sub0 = next((s for s in t.subitems if _text(s, "SubIdx", "0") == "0" and s is not array_item), None)
        f0 = _flags(ctx, sub0.find("Flags") if sub0 is not None else None, w) or flags
        sname0 = _text(sub0, "Name", "SubIndex 000") if sub0 is not None else "SubIndex 000"
        subs.append(EsiSub(0, sname0, DataType.UNSIGNED8, f0[0], False, f0[2],
                           _default(ctx, sub_info(0, sname0), DataType.UNSIGNED8, w)))
        fe = _flags(ctx, array_item.find("Flags"), w) or flags
        lbound, count = at.array
        for k in range(count):
            sub = lbound + k if lbound else k + 1
            sname = _text(infos[k + 1], "Name") if k + 1 < len(infos) else f"SubIndex {sub:03d}"
            subs.append(EsiSub(sub, sname, elem_type, fe[0], fe[1], fe[2],
                               _default(ctx, sub_info(k + 1, sname), elem_type, f"{w}:{sub}")))
        return EsiObject(index, name, ObjectCode.ARRAY, tuple(subs))
    for k, item in enumerate(t.subitems):
        sname = _text(item, "Name")
        sub = ctx.number(_text(item, "SubIdx"), f"{w} SubItem {sname!r}/SubIdx", k)
        stype = _resolve(ctx, types, _text(item, "Type"), f"{w}:{sub}")
        f = _flags(ctx, item.find("Flags"), f"{w}:{sub}") or flags
        subs.append(EsiSub(sub, sname, stype, f[0], f[1], f[2], _default(ctx, sub_info(k, sname), stype, f"{w}:{sub}"),
                           _string_size(stype, _text(item, "Type"), item)))
    code = ObjectCode.ARRAY if obj.get("ObjectCode", "") == "ARRAY" else ObjectCode.RECORD
    return EsiObject(index, name, code, tuple(subs))


# ------------------------------------------------------------------------------------------ building
def _drop(od: ObjectDictionary, index: int) -> None:
    obj = od.objects.pop(index)
    for sub in obj.entries:
        key = (index, sub)
        od.entries.pop(key, None)
        od.values.pop(key, None)


def apply_dictionary(od: ObjectDictionary, device: EsiDevice) -> None:
    """Lay the ESI's objects over the standard ones ``build_od`` made (an object in both is the ESI's),
    or, without a dictionary, add a generic object for every mapped entry the standard ones lack."""
    desc = device.desc
    if device.objects is None:
        for pdo in (*desc.rx_pdos, *desc.tx_pdos):
            access = Access.RWW if pdo in desc.rx_pdos else Access.RO
            for e in pdo.entries:
                if not e.index or (e.index, e.subindex) in od.entries:
                    continue
                if e.subindex == 0:
                    od.add_variable(e.index, e.name or f"Object 0x{e.index:04X}", e.data_type, access,
                                    pdo_mappable=True)
                    continue
                if e.index not in od.objects:
                    od.add_record(e.index, e.name or f"Object 0x{e.index:04X}")
                od.add_sub(e.index, e.subindex, e.name or f"SubIndex {e.subindex:03d}", e.data_type, access,
                           pdo_mappable=True, sub0_name="SubIndex 000")
        return
    for obj in device.objects:
        if obj.index in od.objects:
            _drop(od, obj.index)
        preop = 0x1600 <= obj.index < 0x1C30    # PDO mapping and assignment: written in PREOP only
        if obj.code is ObjectCode.VAR:
            s = obj.subs[0]
            od.add_variable(obj.index, obj.name, s.data_type, s.access, s.default, pdo_mappable=s.pdo_mappable,
                            preop_only=s.preop_only or (preop and s.access.writable), max_length=s.max_length)
            continue
        od.add_record(obj.index, obj.name, obj.code)
        for s in sorted(obj.subs, key=lambda s: s.subindex):
            od.add_sub(obj.index, s.subindex, s.name, s.data_type, s.access, s.default,
                       pdo_mappable=s.pdo_mappable, preop_only=s.preop_only or (preop and s.access.writable),
                       sub0_name="SubIndex 000", max_length=s.max_length)
        # subindex 0 as the ESI gives it (add_sub keeps a read-only one at the highest subindex)
        zero = next((s for s in obj.subs if s.subindex == 0), None)
        if zero is not None and zero.default is not None:
            od.values[(obj.index, 0)] = zero.default
            od.replace_entry(replace(od.objects[obj.index].entries[0], default=zero.default))
    # an assignment counts the PDOs it assigns: entries of PDO 0 after the assigned ones (SOES's files give
    # subindex 0 the array's length) are not counted
    for index in (0x1C12, 0x1C13):
        if index in od.objects and (index, 0) in od.values:
            n = int(od.values[(index, 0)])
            assigned = 0
            while assigned < n and int(od.values.get((index, assigned + 1), 0)):
                assigned += 1
            if assigned < n:
                od.values[(index, 0)] = assigned
                od.replace_entry(replace(od.entries[(index, 0)], default=assigned))
    # an entry the file's PDOs map is mappable, flagged or not (SOES's files give no PdoMapping flags)
    for pdo in (*desc.rx_pdos, *desc.tx_pdos):
        for e in pdo.entries:
            entry = od.entries.get((e.index, e.subindex))
            if e.index and entry is not None and not entry.pdo_mappable:
                od.replace_entry(replace(entry, pdo_mappable=True))


def identity_overrides(serial: int | None) -> Callable[[ObjectDictionary], None]:
    """The rig's ``serial`` in 0x1018:04 (after the ESI's default)."""

    def apply(od: ObjectDictionary) -> None:
        if serial is not None and (0x1018, 4) in od.entries:
            od.values[(0x1018, 4)] = serial
            od.replace_entry(replace(od.entries[(0x1018, 4)], default=serial))

    return apply
