"""ENI (ETG.2100 EtherCAT Network Information) reader: the segment a master was configured for.

What a simulator needs from ``EtherCATConfig/Config``: every ``<Slave>`` in order with its ``<Info>``
identity and addresses, ``<Mailbox>`` (SyncManagers, protocols, CoE InitCmds), ``<ProcessData>``
(``Send``/``Recv`` bit lengths, ``SmN`` settings with their ``Pdo`` lists, ``RxPdo``/``TxPdo`` with
entries), the slave's register ``<InitCmds>`` (ESC datagrams by transition with the expected working
counter) and ``<DC>``; and the master's ``<Cyclic>`` commands (their expected working counters) and the
``<ProcessImage>`` sizes (QEC master manual A.7 lists the subset masters use).

Numbers may be decimal, ``0x..`` or ``#x..`` (TwinCAT writes both); unknown elements are ignored. Every
problem is one :class:`EniError` line: the file, the line, the element and what is wrong.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pyexpat import ExpatError, ParserCreate

from gatewaylab.common.errors import ConfigError
from gatewaylab.ethercat.description import Pdo, PdoEntry
from gatewaylab.od import DataType

__all__ = [
    "CMD_NAMES",
    "CoeInitCmd",
    "Eni",
    "EniError",
    "EniSlave",
    "EniSm",
    "RegisterInitCmd",
    "parse_eni_xml",
]

#: ETG.1000.4 datagram commands by number (ENI ``<Cmd>``).
CMD_NAMES = {0: "NOP", 1: "APRD", 2: "APWR", 3: "APRW", 4: "FPRD", 5: "FPWR", 6: "FPRW", 7: "BRD", 8: "BWR",
             9: "BRW", 10: "LRD", 11: "LWR", 12: "LRW", 13: "ARMW", 14: "FRMW"}
#: The most data one datagram carries (a 1,514-byte frame less its headers).
MAX_DATA = 1486
#: ETG.2000 base types an ENI's PDO entries name, besides the CoE names.
_TYPES = {"BOOL": DataType.BOOLEAN, "BIT": DataType.BOOLEAN, "SINT": DataType.INTEGER8, "INT": DataType.INTEGER16,
          "DINT": DataType.INTEGER32, "LINT": DataType.INTEGER64, "USINT": DataType.UNSIGNED8,
          "UINT": DataType.UNSIGNED16, "UDINT": DataType.UNSIGNED32, "ULINT": DataType.UNSIGNED64,
          "BYTE": DataType.UNSIGNED8, "WORD": DataType.UNSIGNED16, "DWORD": DataType.UNSIGNED32,
          "REAL": DataType.REAL32, "LREAL": DataType.REAL64}


class EniError(ConfigError):
    """An ENI file the segment cannot be built from (exit 2 on the command line)."""


@dataclass(frozen=True, slots=True)
class RegisterInitCmd:
    """One ``Slave/InitCmds/InitCmd``: an ESC datagram sent in a state transition."""

    transitions: tuple[str, ...]
    comment: str
    cmd: int
    adp: int
    ado: int
    data: bytes                  # written data, or zeros of ``DataLength`` for a read
    cnt: int | None              # expected working counter
    validate: bytes | None = None
    validate_mask: bytes | None = None
    timeout_ms: int = 0

    @property
    def is_read(self) -> bool:
        """APRD, FPRD, BRD (and LRD): the datagram reads."""
        return self.cmd in (1, 4, 7, 10)


@dataclass(frozen=True, slots=True)
class CoeInitCmd:
    """One ``Mailbox/CoE/InitCmds/InitCmd``: an SDO download (Ccs 1) or upload (Ccs 2) in a transition."""

    transitions: tuple[str, ...]
    comment: str
    index: int
    subindex: int
    data: bytes
    complete_access: bool = False
    ccs: int = 1
    timeout_ms: int = 0


@dataclass(frozen=True, slots=True)
class EniSm:
    """One ``ProcessData/SmN``: a process data SyncManager and the PDOs it carries."""

    number: int
    kind: str                    # "Outputs" or "Inputs"
    start: int
    control: int
    enable: bool
    length: int | None           # bytes, when the ENI gives it
    pdos: tuple[int, ...]


@dataclass(frozen=True, slots=True)
class EniSlave:
    """One ``Config/Slave``."""

    position: int
    name: str
    line: int
    vendor_id: int
    product_code: int
    revision: int
    serial: int
    phys_addr: int | None
    auto_inc_addr: int | None
    mailbox_out: tuple[int, int] | None      # (start, length); None: no mailbox
    mailbox_in: tuple[int, int] | None
    protocols: tuple[str, ...]
    send_bits: int
    recv_bits: int
    sms: tuple[EniSm, ...]
    rx_pdos: tuple[Pdo, ...]
    tx_pdos: tuple[Pdo, ...]
    rx_assign: tuple[int, ...]
    tx_assign: tuple[int, ...]
    init_cmds: tuple[RegisterInitCmd, ...]
    coe_cmds: tuple[CoeInitCmd, ...]
    dc: bool

    @property
    def identity(self) -> tuple[int, int, int]:
        """(vendor id, product code, revision)."""
        return self.vendor_id, self.product_code, self.revision


@dataclass(frozen=True, slots=True)
class Eni:
    """A whole ENI: the master's name, the slaves in order, the cyclic commands' expected working counter."""

    source: str
    master: str
    slaves: tuple[EniSlave, ...]
    #: Sum of the ``Cnt`` of the ``<Cyclic>`` logical commands (LRD/LWR/LRW); None when the ENI has none.
    cyclic_wkc: int | None
    cycle_time_us: int | None
    inputs_bytes: int | None
    outputs_bytes: int | None


class _Reader:
    """Parse state: the file's name and the line of every element (for the one-line errors)."""

    def __init__(self, source: str) -> None:
        self.source = source
        self.lines: dict[int, int] = {}

    def fail(self, el: ET.Element | None, where: str, what: str) -> EniError:
        line = self.lines.get(id(el)) if el is not None else None
        at = f"line {line}: " if line else ""
        return EniError(f"{self.source}: {at}{where}: {what}")

    def number(self, el: ET.Element | None, tag: str, where: str, default: int | None = None,
               hi: int = 0xFFFFFFFF, lo: int = 0) -> int:
        """The number in ``el``'s child ``tag`` (``default`` when there is none), within ``lo..hi``."""
        child = el.find(tag) if el is not None else None
        text = child.text if child is not None else None
        if text is None or not text.strip():
            if default is None:
                raise self.fail(el, f"{where}/{tag}", "missing")
            return default
        value = self.parse(text, child, f"{where}/{tag}")
        if not lo <= value <= hi:
            raise self.fail(child, f"{where}/{tag}", f"{value} is out of range ({lo}..{hi})")
        return value

    def parse(self, text: str, el: ET.Element | None, where: str) -> int:
        t = text.strip().lower()
        try:
            value = int(t[2:], 16) if t.startswith("#x") else int(t, 16) if t.startswith("0x") else int(t, 10)
        except ValueError:
            raise self.fail(el, where, f"{text.strip()!r} is not a number") from None
        return value

    def hexdata(self, el: ET.Element | None, where: str) -> bytes:
        text = "".join((el.text or "").split()) if el is not None else ""
        try:
            return bytes.fromhex(text)
        except ValueError:
            raise self.fail(el, where, f"{text[:40]!r} is not hex bytes") from None


def _xml(data: bytes | str, r: _Reader) -> ET.Element:
    """The document's root, every element's line noted (expat directly: ElementTree keeps no lines)."""
    parser = ParserCreate()
    builder = ET.TreeBuilder()

    def start(tag: str, attrs: dict[str, str]) -> None:
        el = builder.start(tag.split(":")[-1], attrs)
        r.lines[id(el)] = parser.CurrentLineNumber

    parser.StartElementHandler = start
    parser.EndElementHandler = lambda tag: builder.end(tag.split(":")[-1])
    parser.CharacterDataHandler = builder.data
    try:
        parser.Parse(data, True)
        return builder.close()
    except ExpatError as exc:
        raise EniError(f"{r.source}: line {exc.lineno} column {exc.offset}: malformed XML "
                       f"({str(exc).split(':')[0]})") from None
    except (AssertionError, IndexError):     # a TreeBuilder fed an unbalanced document: expat said so first
        raise EniError(f"{r.source}: malformed XML") from None


def _text(el: ET.Element | None, tag: str) -> str:
    child = el.find(tag) if el is not None else None
    return (child.text or "").strip() if child is not None else ""


def _bool(text: str, default: bool = True) -> bool:
    t = text.strip().lower()
    return default if not t else t in ("1", "true")


def _transitions(el: ET.Element) -> tuple[str, ...]:
    return tuple(t.text.strip().upper() for t in el.findall("Transition") if t.text and t.text.strip())


def _register_cmd(r: _Reader, el: ET.Element, where: str) -> RegisterInitCmd:
    cmd = r.number(el, "Cmd", where, hi=0xFF)
    if cmd not in CMD_NAMES:
        raise r.fail(el, f"{where}/Cmd", f"{cmd} is not an EtherCAT command (0..14)")
    data_el = el.find("Data")
    if data_el is not None and (data_el.text or "").strip():
        data = r.hexdata(data_el, f"{where}/Data")
    else:
        data = bytes(r.number(el, "DataLength", where, 0, hi=MAX_DATA))
    validate = el.find("Validate")
    check = mask = None
    timeout = r.number(el, "Timeout", where, 0)
    if validate is not None:
        check = r.hexdata(validate.find("Data"), f"{where}/Validate/Data")
        mask_el = validate.find("DataMask")
        mask = r.hexdata(mask_el, f"{where}/Validate/DataMask") if mask_el is not None else None
        timeout = r.number(validate, "Timeout", f"{where}/Validate", timeout)
    cnt_el = el.find("Cnt")
    return RegisterInitCmd(_transitions(el), _text(el, "Comment"), cmd,
                           r.number(el, "Adp", where, 0, lo=-0x8000, hi=0xFFFF) & 0xFFFF,
                           r.number(el, "Ado", where, 0, hi=0xFFFF), data,
                           None if cnt_el is None else r.number(el, "Cnt", where), check, mask, timeout)


def _coe_cmd(r: _Reader, el: ET.Element, where: str) -> CoeInitCmd:
    index = r.number(el, "Index", where, hi=0xFFFF)
    sub = r.number(el, "SubIndex", where, 0, hi=0xFF)
    return CoeInitCmd(_transitions(el), _text(el, "Comment"), index, sub,
                      r.hexdata(el.find("Data"), f"{where} 0x{index:04X}:{sub:02X}/Data"),
                      _bool(el.get("CompleteAccess", ""), False), r.number(el, "Ccs", where, 1),
                      r.number(el, "Timeout", where, 0))


def _pdo(r: _Reader, el: ET.Element, where: str) -> Pdo:
    index = r.number(el, "Index", where, hi=0xFFFF)
    w = f"{where} 0x{index:04X}"
    entries = []
    for i, e in enumerate(el.findall("Entry"), 1):
        ew = f"{w} Entry {i}"
        eindex = r.number(e, "Index", ew, hi=0xFFFF)
        bits = r.number(e, "BitLen", ew, hi=0xFFFF)
        if not 0 < bits <= 255:
            raise r.fail(e, f"{ew}/BitLen", f"{bits} bits (1..255)")
        dtype = _TYPES.get(_text(e, "DataType").upper(), DataType.UNSIGNED8 if bits <= 8 else
                           DataType.UNSIGNED16 if bits <= 16 else DataType.UNSIGNED32 if bits <= 32
                           else DataType.UNSIGNED64)
        if bits == 1:
            dtype = DataType.BOOLEAN
        sub = r.number(e, "SubIndex", ew, 0, hi=0xFF) if eindex else 0
        entries.append(PdoEntry(eindex, sub, bits, _text(e, "Name"), dtype))
    return Pdo(index, _text(el, "Name") or f"PDO 0x{index:04X}", tuple(entries), fixed=_bool(el.get("Fixed", ""),
                                                                                               False))


def _slave(r: _Reader, s: ET.Element, position: int) -> EniSlave:
    info = s.find("Info")
    here = f"Slave #{position + 1}"
    if info is None:
        raise r.fail(s, here, "no <Info> element")
    name = _text(info, "Name") or f"slave {position}"
    here = f"Slave #{position + 1} ({name})"
    wi = f"{here} Info"
    mbx = s.find("Mailbox")
    out = inp = None
    protocols: tuple[str, ...] = ()
    coe: list[CoeInitCmd] = []
    if mbx is not None:
        wm = f"{here} Mailbox"
        send, recv = mbx.find("Send"), mbx.find("Recv")
        if send is None or recv is None:
            raise r.fail(mbx, wm, "needs <Send> and <Recv>")
        out = (r.number(send, "Start", f"{wm}/Send", hi=0xFFFF), r.number(send, "Length", f"{wm}/Send", hi=0xFFFF))
        inp = (r.number(recv, "Start", f"{wm}/Recv", hi=0xFFFF), r.number(recv, "Length", f"{wm}/Recv", hi=0xFFFF))
        for (start, length), tag in ((out, "Send"), (inp, "Recv")):
            if start < 0x1000 or length < 16 or start + length > 0x10000:
                raise r.fail(mbx, f"{wm}/{tag}", f"a mailbox at 0x{start:04X} of {length} bytes is impossible "
                                                 f"(process RAM from 0x1000, at least 16 bytes)")
        protocols = tuple(p.text.strip() for p in mbx.findall("Protocol") if p.text and p.text.strip())
        protocols += tuple(t for t in ("CoE", "FoE", "EoE", "SoE", "AoE", "VoE")
                           if mbx.find(t) is not None and t not in protocols)
        for i, el in enumerate(mbx.findall("CoE/InitCmds/InitCmd"), 1):
            coe.append(_coe_cmd(r, el, f"{wm}/CoE/InitCmds/InitCmd #{i}"))
    pd = s.find("ProcessData")
    wp = f"{here} ProcessData"
    sms: list[EniSm] = []
    rx: list[Pdo] = []
    tx: list[Pdo] = []
    rx_assign: list[int] = []
    tx_assign: list[int] = []
    send_bits = recv_bits = 0
    if pd is not None:
        send_bits = r.number(pd.find("Send"), "BitLength", f"{wp}/Send", 0) if pd.find("Send") is not None else 0
        recv_bits = r.number(pd.find("Recv"), "BitLength", f"{wp}/Recv", 0) if pd.find("Recv") is not None else 0
        for child in pd:
            if child.tag.startswith("Sm") and child.tag[2:].isdigit():
                ws = f"{wp}/{child.tag}"
                kind = _text(child, "Type") or ("Outputs" if child.tag == "Sm2" else "Inputs")
                if kind not in ("Outputs", "Inputs"):
                    raise r.fail(child, f"{ws}/Type", f"{kind!r} is not Outputs or Inputs")
                length_el = child.find("Length")
                number = int(child.tag[2:])
                if number > 15:
                    raise r.fail(child, ws, "an ESC has SyncManagers 0..15")
                sms.append(EniSm(number, kind, r.number(child, "StartAddress", ws, hi=0xFFFF),
                                 r.number(child, "ControlByte", ws, 0x64 if kind == "Outputs" else 0x20, hi=0xFF),
                                 _bool(_text(child, "Enable")),
                                 None if length_el is None else r.number(child, "Length", ws, hi=0xFFFF),
                                 tuple(r.parse(p.text or "", p, f"{ws}/Pdo") for p in child.findall("Pdo"))))
        in_sm = {p: sm for sm in sms for p in sm.pdos}
        for tag, pdos, assign in (("RxPdo", rx, rx_assign), ("TxPdo", tx, tx_assign)):
            for el in pd.findall(tag):
                pdo = _pdo(r, el, f"{wp}/{tag}")
                pdos.append(pdo)
                if el.get("Sm") is not None or pdo.index in in_sm:
                    assign.append(pdo.index)
        for sm in sms:
            pdos = rx if sm.kind == "Outputs" else tx
            bits = sum(p.bit_length for p in pdos if p.index in sm.pdos) or (
                sum(p.bit_length for p in pdos if p.index in (rx_assign if sm.kind == "Outputs" else tx_assign)))
            if sm.length is not None and bits > 8 * sm.length:
                raise r.fail(pd, f"{wp}/Sm{sm.number}", f"its PDOs map {bits} bits, more than the SyncManager's "
                                                         f"Length {sm.length} bytes ({8 * sm.length} bits)")
        for bits, total, tag in ((sum(p.bit_length for p in rx if p.index in rx_assign), send_bits, "Send"),
                                 (sum(p.bit_length for p in tx if p.index in tx_assign), recv_bits, "Recv")):
            if bits > total and pd.find(tag) is not None:
                raise r.fail(pd, f"{wp}/{tag}/BitLength", f"the assigned PDOs map {bits} bits, more than the "
                                                          f"{total} bits of the process data")
    cmds = [_register_cmd(r, el, f"{here} InitCmds/InitCmd #{i}") for i, el in enumerate(s.findall("InitCmds/InitCmd"),
                                                                                            1)]
    phys = r.number(info, "PhysAddr", wi, -1, hi=0xFFFF)
    auto = r.number(info, "AutoIncAddr", wi, -0x10000, lo=-0x8000, hi=0xFFFF)
    return EniSlave(position, name, r.lines.get(id(s), 0), r.number(info, "VendorId", wi),
                    r.number(info, "ProductCode", wi), r.number(info, "RevisionNo", wi, 0),
                    r.number(info, "SerialNo", wi, 0), None if phys < 0 else phys,
                    None if auto == -0x10000 else auto & 0xFFFF, out, inp, protocols, send_bits, recv_bits,
                    tuple(sms), tuple(rx), tuple(tx), tuple(rx_assign), tuple(tx_assign), tuple(cmds), tuple(coe),
                    s.find("DC") is not None)


def parse_eni_xml(data: bytes | str, source: str = "ENI") -> Eni:
    """Parse an ENI document (``source`` names it in errors)."""
    r = _Reader(source)
    root = _xml(data, r)
    if root.tag != "EtherCATConfig":
        raise r.fail(root, f"<{root.tag}>", "the root element must be <EtherCATConfig> (ETG.2100)")
    config = root.find("Config")
    if config is None:
        raise r.fail(root, "EtherCATConfig", "no <Config> element")
    slaves = tuple(_slave(r, s, i) for i, s in enumerate(config.findall("Slave")))
    if not slaves:
        raise r.fail(config, "EtherCATConfig/Config", "no <Slave>")
    for s in slaves:
        for i, v in enumerate(slaves[:s.position]):
            if s.phys_addr is not None and s.phys_addr == v.phys_addr:
                raise EniError(f"{source}: line {s.line}: Slave #{s.position + 1} ({s.name}) Info/PhysAddr: "
                               f"{s.phys_addr} is already Slave #{i + 1}'s ({v.name})")
    wkc = None
    cycle = None
    cyclic = config.find("Cyclic")
    if cyclic is not None:
        cycle = r.number(cyclic, "CycleTime", "Config/Cyclic", 0) or None
        for cmd in cyclic.findall("Frame/Cmd"):
            if r.number(cmd, "Cmd", "Config/Cyclic/Frame/Cmd", 0) in (10, 11, 12):
                wkc = (wkc or 0) + r.number(cmd, "Cnt", "Config/Cyclic/Frame/Cmd", 0)
    image = config.find("ProcessImage")
    sizes: list[int | None] = []
    for tag in ("Inputs", "Outputs"):
        el = image.find(tag) if image is not None else None
        sizes.append(None if el is None else r.number(el, "ByteSize", f"Config/ProcessImage/{tag}", 0))
    master = _text(config.find("Master/Info"), "Name")
    return Eni(source, master, slaves, wkc, cycle, sizes[0], sizes[1])
