"""The parts of an ETG.2100 ENI file that masters use (QEC master manual A.7): slave identity,
mailbox, CoE InitCmds (index, subindex, data, complete access), process data SyncManagers and bit
lengths, DC cycle/shift; and a plain list of CoE startup writes (docs/migration-esd-to-ecanlite.md).

Reading is defensive: numbers may be decimal, ``0x..`` or ``#x..`` (TwinCAT), unknown elements are
ignored, a missing or malformed required element is an :class:`EniError` (the one of the general ENI reader,
gatewaylab/ethercat/eni.py, which reads the whole segment for ``[ethercat] eni``).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field

from gatewaylab.ethercat.eni import EniError

__all__ = [
    "WRITE_TYPES",
    "EniError",
    "InitCmd",
    "SlaveConfig",
    "SyncManager",
    "format_writes",
    "parse_eni",
    "parse_int",
    "parse_writes",
    "write_eni",
]


@dataclass(frozen=True, slots=True)
class InitCmd:
    """One CoE InitCmd: an SDO download in a state transition (default PREOP -> SAFEOP)."""

    index: int
    subindex: int
    data: bytes
    complete_access: bool = False
    transition: str = "PS"
    comment: str = ""

    @property
    def value(self) -> int:
        """The data as a little-endian unsigned number."""
        return int.from_bytes(self.data, "little")


@dataclass(frozen=True, slots=True)
class SyncManager:
    """A process data SyncManager of ProcessData (A.7 'SyncManagerSettings')."""

    number: int
    start: int
    control: int
    enable: bool = True
    length: int = 0


@dataclass(frozen=True, slots=True)
class SlaveConfig:
    """One ``Config/Slave`` of an ENI."""

    name: str
    vendor_id: int
    product_code: int
    revision: int = 0
    serial: int = 0
    mailbox_out: tuple[int, int] = (0x1000, 128)   # Mailbox Send: master -> slave (start, length)
    mailbox_in: tuple[int, int] = (0x1080, 128)    # Mailbox Recv
    init_cmds: tuple[InitCmd, ...] = ()
    output_bits: int = 0                            # ProcessData Send BitLength
    input_bits: int = 0                             # ProcessData Recv BitLength
    sync_managers: tuple[SyncManager, ...] = ()
    dc_cycle0: int | None = None                    # ns
    dc_cycle1: int | None = None
    dc_shift: int | None = None
    extra: dict[str, str] = field(default_factory=dict)


def parse_int(text: str | None, what: str = "number") -> int:
    """Decimal, ``0x``-hex or ``#x``-hex (TwinCAT writes both)."""
    if text is None or not text.strip():
        raise EniError(f"{what}: missing")
    t = text.strip().lower()
    try:
        if t.startswith("#x"):
            return int(t[2:], 16)
        return int(t, 0) if t.startswith("0x") else int(t, 10)
    except ValueError:
        raise EniError(f"{what}: {text!r} is not a number") from None


def _opt_int(el: ET.Element | None, path: str, what: str) -> int | None:
    if el is None:
        return None
    child = el.find(path)
    return None if child is None or child.text is None or not child.text.strip() else parse_int(child.text, what)


def _bool(text: str | None) -> bool:
    return (text or "").strip().lower() in ("1", "true")


def _hex_data(text: str | None, what: str) -> bytes:
    t = "".join((text or "").split())
    try:
        return bytes.fromhex(t)
    except ValueError:
        raise EniError(f"{what}: {text!r} is not hex data") from None


def _init_cmd(el: ET.Element, slave: str) -> InitCmd | None:
    """An InitCmd, or None for an upload (Ccs 2 = download is what configures)."""
    ccs = _opt_int(el, "Ccs", f"{slave} InitCmd Ccs")
    if ccs is not None and ccs != 1:
        return None
    what = f"{slave} InitCmd"
    index = parse_int(el.findtext("Index"), f"{what} Index")
    sub = parse_int(el.findtext("SubIndex"), f"{what} SubIndex")
    if not 0 <= index <= 0xFFFF or not 0 <= sub <= 0xFF:
        raise EniError(f"{what}: 0x{index:X}:{sub} out of range")
    transitions = [t.text.strip() for t in el.findall("Transition") if t.text and t.text.strip()]
    return InitCmd(index, sub, _hex_data(el.findtext("Data"), f"{what} 0x{index:04X}:{sub:02X} Data"),
                   _bool(el.get("CompleteAccess")), transitions[0] if transitions else "PS",
                   (el.findtext("Comment") or "").strip())


def parse_eni(text: str) -> list[SlaveConfig]:
    """Every ``EtherCATConfig/Config/Slave`` of an ENI text."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise EniError(f"not XML: {exc}") from None
    config = root if root.tag == "Config" else root.find("Config")
    if config is None:
        raise EniError("no EtherCATConfig/Config element")
    slaves: list[SlaveConfig] = []
    for n, s in enumerate(config.findall("Slave")):
        info = s.find("Info")
        if info is None:
            raise EniError(f"slave {n}: no Info element")
        name = (info.findtext("Name") or f"slave {n}").strip()
        mbx = s.find("Mailbox")
        out = (0x1000, 128)
        inp = (0x1080, 128)
        cmds: list[InitCmd] = []
        if mbx is not None:
            start, length = _opt_int(mbx, "Send/Start", "Send Start"), _opt_int(mbx, "Send/Length", "Send Length")
            out = (start if start is not None else out[0], length if length is not None else out[1])
            start, length = _opt_int(mbx, "Recv/Start", "Recv Start"), _opt_int(mbx, "Recv/Length", "Recv Length")
            inp = (start if start is not None else inp[0], length if length is not None else inp[1])
            for el in mbx.findall("CoE/InitCmds/InitCmd"):
                cmd = _init_cmd(el, name)
                if cmd is not None:
                    cmds.append(cmd)
        pd = s.find("ProcessData")
        sms: list[SyncManager] = []
        if pd is not None:
            for child in pd:
                if child.tag.startswith("Sm") and child.tag[2:].isdigit():
                    start = _opt_int(child, "StartAddress", f"{name} {child.tag} StartAddress")
                    ctrl = _opt_int(child, "ControlByte", f"{name} {child.tag} ControlByte")
                    length = _opt_int(child, "Length", f"{name} {child.tag} Length")
                    sms.append(SyncManager(int(child.tag[2:]), start or 0, ctrl or 0,
                                           _bool(child.findtext("Enable") or "1"), length or 0))
        dc = s.find("DC")
        slaves.append(SlaveConfig(
            name=name,
            vendor_id=parse_int(info.findtext("VendorId"), f"{name} VendorId"),
            product_code=parse_int(info.findtext("ProductCode"), f"{name} ProductCode"),
            revision=_opt_int(info, "RevisionNo", f"{name} RevisionNo") or 0,
            serial=_opt_int(info, "SerialNo", f"{name} SerialNo") or 0,
            mailbox_out=out, mailbox_in=inp, init_cmds=tuple(cmds),
            output_bits=_opt_int(pd, "Send/BitLength", f"{name} Send BitLength") or 0,
            input_bits=_opt_int(pd, "Recv/BitLength", f"{name} Recv BitLength") or 0,
            sync_managers=tuple(sms),
            dc_cycle0=_opt_int(dc, "CycleTime0", f"{name} DC CycleTime0"),
            dc_cycle1=_opt_int(dc, "CycleTime1", f"{name} DC CycleTime1"),
            dc_shift=_opt_int(dc, "ShiftTime", f"{name} DC ShiftTime")))
    if not slaves:
        raise EniError("no Slave in EtherCATConfig/Config")
    return slaves


def _sub(parent: ET.Element, tag: str, text: str | None = None, **attrs: str) -> ET.Element:
    el = ET.SubElement(parent, tag, attrs)
    if text is not None:
        el.text = text
    return el


def write_eni(slaves: list[SlaveConfig], master_name: str = "gatewaylab") -> str:
    """ENI text (numbers in decimal, as TwinCAT exports them; data as hex bytes)."""
    root = ET.Element("EtherCATConfig", {"Version": "1.3"})
    config = _sub(root, "Config")
    master = _sub(config, "Master")
    _sub(_sub(master, "Info"), "Name", master_name)
    for s in slaves:
        slave = _sub(config, "Slave")
        info = _sub(slave, "Info")
        _sub(info, "Name", s.name)
        for tag, value in (("VendorId", s.vendor_id), ("ProductCode", s.product_code),
                           ("RevisionNo", s.revision), ("SerialNo", s.serial)):
            _sub(info, tag, str(value))
        pd = _sub(slave, "ProcessData")
        _sub(_sub(pd, "Send"), "BitLength", str(s.output_bits))
        _sub(_sub(pd, "Recv"), "BitLength", str(s.input_bits))
        for sm in s.sync_managers:
            el = _sub(pd, f"Sm{sm.number}")
            _sub(el, "Type", "Outputs" if sm.number == 2 else "Inputs")
            _sub(el, "StartAddress", str(sm.start))
            _sub(el, "ControlByte", str(sm.control))
            _sub(el, "Enable", "true" if sm.enable else "false")
            _sub(el, "Length", str(sm.length))
        mbx = _sub(slave, "Mailbox", DataLinkLayer="true")
        send, recv = _sub(mbx, "Send"), _sub(mbx, "Recv")
        _sub(send, "Start", str(s.mailbox_out[0]))
        _sub(send, "Length", str(s.mailbox_out[1]))
        _sub(recv, "Start", str(s.mailbox_in[0]))
        _sub(recv, "Length", str(s.mailbox_in[1]))
        _sub(mbx, "Protocol", "CoE")
        cmds = _sub(_sub(mbx, "CoE"), "InitCmds")
        for c in s.init_cmds:
            el = _sub(cmds, "InitCmd", Fixed="true", CompleteAccess="true" if c.complete_access else "false")
            _sub(el, "Transition", c.transition)
            _sub(el, "Comment", c.comment)
            _sub(el, "Timeout", "0")
            _sub(el, "Ccs", "1")
            _sub(el, "Index", str(c.index))
            _sub(el, "SubIndex", str(c.subindex))
            _sub(el, "Data", c.data.hex())
        if s.dc_cycle0 is not None:
            dc = _sub(slave, "DC")
            _sub(dc, "CycleTime0", str(s.dc_cycle0))
            _sub(dc, "CycleTime1", str(s.dc_cycle1 or 0))
            _sub(dc, "ShiftTime", str(s.dc_shift or 0))
    ET.indent(root)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


#: Startup-list value types and their sizes in bytes.
WRITE_TYPES = {"u8": 1, "u16": 2, "u32": 4, "u64": 8}


def parse_writes(text: str) -> list[InitCmd]:
    """A plain list of CoE startup writes, one per line: ``INDEX:SUB TYPE VALUE [ca]``; TYPE is u8, u16,
    u32, u64 or ``hex`` (VALUE then the bytes in wire order); ``ca`` = complete access; ``#`` comments.
    Example: ``0xF800:05 u32 0x40000004`` or ``0x8001:00 hex 0200 0011223344556677 ... ca``."""
    cmds: list[InitCmd] = []
    for n, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split()
        ca = parts[-1].lower() == "ca"
        if ca:
            parts = parts[:-1]
        if len(parts) < 3 or ":" not in parts[0]:
            raise EniError(f"line {n}: expected 'INDEX:SUB TYPE VALUE [ca]', got {raw.strip()!r}")
        idx_text, sub_text = parts[0].split(":", 1)
        try:
            index, sub = int(idx_text, 16), int(sub_text, 16)
        except ValueError:
            raise EniError(f"line {n}: {parts[0]!r} is not hex INDEX:SUB") from None
        kind = parts[1].lower()
        if kind == "hex":
            data = _hex_data("".join(parts[2:]), f"line {n}")
        elif kind in WRITE_TYPES:
            value = parse_int(parts[2], f"line {n} value")
            size = WRITE_TYPES[kind]
            if not 0 <= value < 1 << (8 * size):
                raise EniError(f"line {n}: {value} does not fit {kind}")
            data = value.to_bytes(size, "little")
        else:
            raise EniError(f"line {n}: type {parts[1]!r} is not u8, u16, u32, u64 or hex")
        if not 0 <= index <= 0xFFFF or not 0 <= sub <= 0xFF:
            raise EniError(f"line {n}: 0x{index:X}:{sub:X} out of range")
        cmds.append(InitCmd(index, sub, data, ca))
    return cmds


def format_writes(cmds: list[InitCmd]) -> str:
    """The startup-list form of ``cmds`` (parse_writes reads it back)."""
    lines = []
    for c in cmds:
        kind = {1: "u8", 2: "u16", 4: "u32", 8: "u64"}.get(len(c.data)) if not c.complete_access else None
        value = f"{kind} 0x{c.value:X}" if kind else f"hex {c.data.hex()}"
        tail = (" ca" if c.complete_access else "") + (f"  # {c.comment}" if c.comment else "")
        lines.append(f"0x{c.index:04X}:{c.subindex:02X} {value}{tail}")
    return "\n".join(lines) + "\n"
