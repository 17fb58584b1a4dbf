"""``gatewaylab ec VERB``: the everyday verbs of IgH's ``ethercat`` tool over a :class:`MasterBackend`.

Same argument order and output shapes as IgH's tool (``ethercat slaves``, ``upload``, ...), on a
network interface through SOEM (``-i IFNAME``, root) or in process on a rig file (``--rig
RIG.toml``: the rig runs on a simulated clock, its segment is brought to PREOP). Exit codes: 0 ok,
1 the slave or the line refused or did not answer, 2 a wrong command line; errors are one line
on stderr.
"""

from __future__ import annotations

import argparse
import base64
import socket
import struct
import sys
import types
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, NoReturn, Protocol, runtime_checkable

from gatewaylab.common.clock import Clock
from gatewaylab.common.errors import ConfigError, GatewaylabError
from gatewaylab.ethercat.errors import AlStatusError, FoeError, FoeErrorCode
from gatewaylab.ethercat.esc import FMMU_REG, REG_FMMU, AlState
from gatewaylab.ethercat.sii import CATEGORY_HEADER, PDO_ENTRY, PDO_HEADER, Category, SmType
from gatewaylab.hosts.ethercat.backend import (
    FOE_CODE_SUFFIX,
    EntryInfo,
    MasterBackend,
    MasterTimeout,
    ProgressFn,
    RigLike,
    al_status_name,
)
from gatewaylab.od.aborts import SdoAbort, abort_text

PROG = "gatewaylab ec"


@dataclass(frozen=True, slots=True)
class CoeType:
    """One CoE data type as IgH's tool names it (``--type``): code, size in bytes (0 = variable), struct."""

    name: str
    code: int
    size: int
    fmt: str = ""


#: IgH ``ethercat`` data type names (``ethercat upload --help``) with their CoE codes (ETG.1000.6).
TYPES: dict[str, CoeType] = {t.name: t for t in (
    CoeType("bool", 0x0001, 1, "<B"), CoeType("int8", 0x0002, 1, "<b"), CoeType("int16", 0x0003, 2, "<h"),
    CoeType("int32", 0x0004, 4, "<i"), CoeType("int64", 0x0015, 8, "<q"), CoeType("uint8", 0x0005, 1, "<B"),
    CoeType("uint16", 0x0006, 2, "<H"), CoeType("uint32", 0x0007, 4, "<I"), CoeType("uint64", 0x001B, 8, "<Q"),
    CoeType("float", 0x0008, 4, "<f"), CoeType("double", 0x0011, 8, "<d"), CoeType("string", 0x0009, 0),
    CoeType("octet_string", 0x000A, 0), CoeType("unicode_string", 0x000B, 0),
)}
TYPE_BY_CODE: dict[int, CoeType] = {t.code: t for t in TYPES.values()}
#: Bit types as IgH's ``sdos`` shows them.
BIT_TYPES = {0x0030 + i: f"bit{i + 1}" for i in range(8)}
STATES = {"INIT": AlState.INIT, "PREOP": AlState.PREOP, "BOOT": AlState.BOOT, "SAFEOP": AlState.SAFEOP,
          "OP": AlState.OP}

DESCRIPTION = """\
The everyday verbs of IgH's `ethercat` tool, on a real line through SOEM (-i IFNAME, needs root)
or in process on a rig file (--rig RIG.toml: simulated clock, the segment brought to PREOP), or
through a persistent master (`gatewaylab ec master -i IFNAME --serve SOCKET`, then --master SOCKET),
which keeps the line open and the process data cycling, so slaves stay in OP between calls.
Every verb takes -i/--rig/--master and -p POSITION after the verb, in IgH's argument order.

examples:
  gatewaylab ec slaves -i gl-ecat-m
  gatewaylab ec upload --rig rig.toml -p 0 --type string 0x1008 0
  gatewaylab ec download -i gl-ecat-m -p 0 --type uint32 0x8000 2 1234
  gatewaylab ec sdos --rig rig.toml -p 0
  gatewaylab ec foe-write -i gl-ecat-m -p 0 firmware.bin -n app.bin

Exit codes: 0 ok; 1 the slave refused or did not answer (SDO abort code and text, AL status code
by name, FoE error code); 2 a wrong command line. Errors are one line on stderr.
"""

EXAMPLES: dict[str, str] = {
    "slaves": "gatewaylab ec slaves -i gl-ecat-m\n  gatewaylab ec slaves --rig rig.toml -v -p 1",
    "states": "gatewaylab ec states --rig rig.toml            # list\n"
              "  gatewaylab ec states -i gl-ecat-m -p 0 INIT     # request a state",
    "upload": "gatewaylab ec upload -i gl-ecat-m -p 0 --type string 0x1008 0\n"
              "  gatewaylab ec upload --rig rig.toml -p 0 0x1018 1   # type from SDO information",
    "download": "gatewaylab ec download -i gl-ecat-m -p 0 --type uint32 0x8000 2 1234\n"
                "  gatewaylab ec download --rig rig.toml -p 0 --type string 0x8000 1 'my box'",
    "sdos": "gatewaylab ec sdos -i gl-ecat-m -p 0\n  gatewaylab ec sdos --rig rig.toml -q",
    "pdos": "gatewaylab ec pdos -i gl-ecat-m\n  gatewaylab ec pdos --rig rig.toml -p 1",
    "sii-read": "gatewaylab ec sii-read -i gl-ecat-m -p 0 > slave0.sii\n"
                "  gatewaylab ec sii-read --rig rig.toml -p 0 --hex",
    "foe-read": "gatewaylab ec foe-read -i gl-ecat-m -p 0 config.bin -o config.bin",
    "foe-write": "gatewaylab ec foe-write -i gl-ecat-m -p 0 ecan_lite_v140.bin -n ecan_lite_app.bin\n"
                 "  gatewaylab ec foe-write --rig esd.toml -p 1 --boot firmware.bin -n firmwareUpdate",
    "cstruct": "gatewaylab ec cstruct --rig rig.toml -p 0 > slave0_pdos.h",
    "xml": "gatewaylab ec xml -i gl-ecat-m -p 0 > slave0.xml",
    "reg-read": "gatewaylab ec reg-read --rig rig.toml -p 0 0x0130 2        # AL status\n"
                "  gatewaylab ec reg-read -i gl-ecat-m -p 0 --type uint16 0x0010",
    "reg-write": "gatewaylab ec reg-write --rig rig.toml -p 0 --type uint16 0x0012 0x1234   # station alias\n"
                 "  gatewaylab ec reg-write -i gl-ecat-m -p 0 0x0120 0200",
    "domains": "gatewaylab ec domains --rig rig.toml -v\n"
               "  gatewaylab ec domains --master /tmp/ec.sock   # the live domain",
    "data": "gatewaylab ec data -i gl-ecat-m > image.bin\n  gatewaylab ec data --master /tmp/ec.sock --hex",
    "config": "gatewaylab ec config --rig rig.toml\n  gatewaylab ec config -i gl-ecat-m -v -p 0",
    "master": "gatewaylab ec master -i gl-ecat-m --serve /tmp/ec.sock &   # a persistent master\n"
              "  gatewaylab ec states --master /tmp/ec.sock OP               # slaves stay in OP between calls\n"
              "  gatewaylab ec master --master /tmp/ec.sock                  # its state\n"
              "  gatewaylab ec master --master /tmp/ec.sock --stop",
}


class EcUsage(GatewaylabError):
    """A wrong command line (exit 2)."""


class EcRefused(GatewaylabError):
    """The line or a slave refused, or a file could not be used (exit 1)."""


# ------------------------------------------------------------------------------- values
def type_name(code: int) -> str:
    """IgH's name of a CoE data type, ``type 0x0029`` for one it has none for."""
    t = TYPE_BY_CODE.get(code)
    if t is not None:
        return t.name
    return BIT_TYPES.get(code, f"type 0x{code:04x}")


def format_value(ctype: CoeType | None, data: bytes) -> str:
    """An uploaded value as IgH prints it: integers as ``0x%0*x %d``, strings as text,
    floats as numbers, octet strings (and unknown types) as hex bytes."""
    if ctype is not None and ctype.fmt and len(data) >= ctype.size:
        raw = data[:ctype.size]
        value = struct.unpack(ctype.fmt, raw)[0]
        if ctype.name in ("float", "double"):
            return repr(value)
        unsigned = int.from_bytes(raw, "little")
        return f"0x{unsigned:0{2 * ctype.size}x} {value}"
    if ctype is not None and ctype.name == "string":
        return data.decode("latin-1").rstrip("\0")
    if ctype is not None and ctype.name == "unicode_string":
        return data.decode("utf-16-le", "replace").rstrip("\0")
    return " ".join(f"{b:02x}" for b in data)


def parse_value(ctype: CoeType, text: str) -> bytes:
    """A download value from the command line: integers in any base (0x.., negative), floats,
    text for strings, hex for octet strings ("01 02 ff" or "0102ff")."""
    if ctype.fmt and ctype.name not in ("float", "double"):
        try:
            value = int(text, 0)
        except ValueError:
            raise EcUsage(f"value {text!r} is not an integer (for {ctype.name})") from None
        try:
            return struct.pack(ctype.fmt, value)
        except struct.error:
            raise EcUsage(f"value {text} is out of range for {ctype.name}") from None
    if ctype.fmt:
        try:
            return struct.pack(ctype.fmt, float(text))
        except (ValueError, OverflowError):
            raise EcUsage(f"value {text!r} is not a number (for {ctype.name})") from None
    if ctype.name == "octet_string":
        try:
            return bytes.fromhex(text)
        except ValueError:
            raise EcUsage(f"value {text!r} is not hex bytes (for octet_string, e.g. '01 02 ff')") from None
    if ctype.name == "unicode_string":
        return text.encode("utf-16-le")
    return text.encode("latin-1", "replace")


def parse_number(text: str, what: str, maximum: int) -> int:
    """An index/subindex like IgH takes them: decimal or 0x hex."""
    try:
        value = int(text, 0)
    except ValueError:
        raise EcUsage(f"{what} {text!r} is not a number") from None
    if not 0 <= value <= maximum:
        raise EcUsage(f"{what} {text} is outside 0..0x{maximum:X}")
    return value


def access_text(access: int) -> str:
    """ETG.1000.6 entry access bits (read PREOP/SAFEOP/OP = bits 0-2, write = 3-5) as IgH's ``rwrwrw``."""
    return "".join(("r" if access >> i & 1 else "-") + ("w" if access >> (i + 3) & 1 else "-") for i in range(3))


# ------------------------------------------------------------------------------- SII PDOs
@dataclass(frozen=True, slots=True)
class SiiPdo:
    """A PDO of the SII TxPDO/RxPDO categories: names for ``pdos``."""

    index: int
    sm: int
    name: str
    entries: tuple[tuple[int, int, int, str], ...]   # index, subindex, bit length, name


def sii_pdos(img: bytes, strings: tuple[str, ...]) -> dict[int, SiiPdo]:
    """The PDOs of the SII categories (ETG.2010 TxPDO 50 / RxPDO 51), by index."""

    def text(i: int) -> str:
        return strings[i - 1] if 0 < i <= len(strings) else ""

    out: dict[int, SiiPdo] = {}
    pos = 0x80
    while pos + CATEGORY_HEADER.size <= len(img):
        kind, words = CATEGORY_HEADER.unpack_from(img, pos)
        if kind == Category.END:
            break
        data = img[pos + 4:pos + 4 + 2 * words]
        if kind in (Category.TXPDO, Category.RXPDO):
            p = 0
            while p + PDO_HEADER.size <= len(data):
                index, n, sm, _dc, name_idx, _flags = PDO_HEADER.unpack_from(data, p)
                p += PDO_HEADER.size
                entries = []
                for _ in range(n):
                    if p + PDO_ENTRY.size > len(data):
                        break
                    e_index, e_sub, e_name, _dt, bits, _f = PDO_ENTRY.unpack_from(data, p)
                    p += PDO_ENTRY.size
                    entries.append((e_index, e_sub, bits, text(e_name)))
                out[index] = SiiPdo(index, sm, text(name_idx), tuple(entries))
        pos += 4 + 2 * words
    return out


# ------------------------------------------------------------------------------- backend
class OpenRig(RigLike, Protocol):
    """A started rig the command runs in process (``gatewaylab.rig.runtime.Rig``)."""

    def close(self) -> None: ...


#: Builds and starts a rig from a file on a simulated clock; the rig layer injects it
#: (``gatewaylab.cli.ec_rig``), so this module does not import the layer above it.
RigOpener = Callable[[str], OpenRig]


@contextmanager
def open_backend(args: argparse.Namespace) -> Iterator[MasterBackend]:
    """``-i IFNAME`` -> PysoemBackend; ``--rig RIG.toml`` -> the rig in process on a simulated clock."""
    if bool(args.interface) == bool(args.rig):
        raise EcUsage("give the line: -i IFNAME (real interface, root), --rig RIG.toml (in process) or "
                      "--master SOCKET (a persistent master)")
    if args.interface:
        from gatewaylab.hosts.ethercat.pysoem_backend import PysoemBackend

        backend: MasterBackend = PysoemBackend(args.interface)
        try:
            yield backend
        finally:
            backend.close()
        return
    open_rig: RigOpener | None = getattr(args, "open_rig", None)
    if open_rig is None:
        raise EcUsage("--rig needs the rig runtime (run through the gatewaylab command)")
    if not Path(args.rig).is_file():
        raise EcUsage(f"rig file {args.rig} does not exist")
    try:
        rig = open_rig(args.rig)
    except ConfigError as exc:
        raise EcUsage(" ".join(str(exc).split())) from None
    try:
        from gatewaylab.hosts.ethercat.backend import InProcessBackend

        backend = InProcessBackend.from_rig(rig)
        try:
            yield backend
        finally:
            backend.close()
    finally:
        rig.close()


def _one(backend: MasterBackend, args: argparse.Namespace) -> int:
    """The one slave a verb acts on: -p, or the only slave of the line."""
    count = len(backend.slaves())
    if args.position is None:
        if count == 1:
            return 0
        raise EcUsage(f"{count} slaves on the line: select one with -p POSITION")
    _check_position(args.position, count)
    return int(args.position)


def _check_position(position: int, count: int) -> None:
    if not 0 <= position < count:
        raise EcUsage(f"no slave at position {position} ({count} slave{'s' if count != 1 else ''} on the line, "
                      f"positions 0..{count - 1})")


def _selected(backend: MasterBackend, args: argparse.Namespace) -> list[int]:
    """-p POSITION or every slave (IgH's default for listings)."""
    count = len(backend.slaves())
    if args.position is None:
        return list(range(count))
    _check_position(args.position, count)
    return [int(args.position)]


def _state_name(status: int) -> str:
    """The state of an AL status byte by name (``0x3`` for a value that is no state)."""
    return AlState(status & 0x0F).name if status & 0x0F in set(STATES.values()) else f"0x{status & 0x0F:X}"


def _header(position: int, several: bool, out: IO[str]) -> None:
    if several:
        print(f"=== Master 0, Slave {position} ===", file=out)


# ------------------------------------------------------------------------------- verbs
def cmd_slaves(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``ethercat slaves``: ``POS  ALIAS:RELPOS  STATE  FLAG  NAME``, one line per slave."""
    ident = {s.position: s for s in backend.slaves()}
    positions = _selected(backend, args)
    rows = []
    for pos in positions:
        status, code = backend.al_status(pos)
        rows.append((pos, _state_name(status), "E" if status & 0x10 else "+", code))
    if args.verbose:
        for pos, state, flag, code in rows:
            s = ident[pos]
            print(f"=== Master 0, Slave {pos} ===", file=out)
            print(f"State: {state}\nFlag: {flag}\nAL status code: {al_status_name(code)}", file=out)
            print("Identity:", file=out)
            print(f"  Vendor Id:       0x{s.vendor_id:08x}\n  Product code:    0x{s.product_code:08x}\n"
                  f"  Revision number: 0x{s.revision:08x}\n  Serial number:   0x{s.serial:08x}", file=out)
            print(f"Station address: 0x{s.station:04x}\nName: {s.name}", file=out)
        return
    wpos = max(len(str(p)) for p, *_ in rows)
    wrel = max(len(f"0:{p}") for p, *_ in rows)
    wstate = max(len(st) for _p, st, *_ in rows)
    for pos, state, flag, _code in rows:
        print(f"{pos:>{wpos}}  {f'0:{pos}':<{wrel}}  {state:<{wstate}}  {flag}  {ident[pos].name}", file=out)


def cmd_states(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``ethercat states STATE`` requests a state; without STATE the states are listed
    (position, state, error flag, AL status code by name)."""
    positions = _selected(backend, args)
    if args.state is not None:
        target = STATES[args.state.upper()]
        if target in (AlState.SAFEOP, AlState.OP):
            backend.config_map()     # a one-shot command maps first, as IgH's master does on activation
        for pos in positions:
            for step in state_path(backend.state(pos)[0], target):
                backend.request_state(step, pos)
    for pos in positions:
        status, code = backend.al_status(pos)
        state = _state_name(status)
        print(f"{pos}  {state:<6}  {'E' if status & 0x10 else '+'}  {al_status_name(code)}", file=out)


def state_path(current: AlState, target: AlState) -> list[AlState]:
    """The legal ESM steps from ``current`` to ``target`` (ETG.1000.6 table 'state transitions'):
    upwards one state at a time, downwards directly, BOOT only from and to INIT; as IgH's master walks."""
    order = [AlState.INIT, AlState.PREOP, AlState.SAFEOP, AlState.OP]
    if target == current:
        return [target]
    if target == AlState.BOOT or current == AlState.BOOT:
        return ([AlState.INIT] if current != AlState.INIT else []) + ([target] if target != AlState.INIT else [])
    if order.index(target) < order.index(current):
        return [target]
    return order[order.index(current) + 1:order.index(target) + 1]


def _entry(backend: MasterBackend, pos: int, index: int, sub: int) -> EntryInfo | None:
    try:
        info = backend.object_info(pos, index)
    except SdoAbort:
        raise
    except GatewaylabError:
        return None            # no SDO information: the caller needs --type
    for e in info.entries:
        if e.subindex == sub:
            return e
    raise SdoAbort(0x06090011, f"0x{index:04X}:{sub:02X}")


def cmd_upload(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``ethercat upload [-t TYPE] INDEX SUBINDEX``: prints the value (integers ``0x.. dec``)."""
    pos = _one(backend, args)
    index = parse_number(args.index, "index", 0xFFFF)
    sub = parse_number(args.subindex, "subindex", 0xFF)
    ctype = TYPES[args.type] if args.type else None
    data = backend.sdo_upload(pos, index, sub)
    if ctype is None:
        entry = _entry(backend, pos, index, sub)
        ctype = TYPE_BY_CODE.get(entry.data_type) if entry is not None else None
    print(format_value(ctype, data), file=out)


def cmd_download(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``ethercat download [-t TYPE] INDEX SUBINDEX VALUE``."""
    pos = _one(backend, args)
    index = parse_number(args.index, "index", 0xFFFF)
    sub = parse_number(args.subindex, "subindex", 0xFF)
    if args.type:
        ctype = TYPES[args.type]
    else:
        entry = _entry(backend, pos, index, sub)
        found = TYPE_BY_CODE.get(entry.data_type) if entry is not None else None
        if found is None:
            raise EcUsage(f"no data type known for 0x{index:04X}:{sub:02X}: give --type")
        ctype = found
    backend.sdo_download(pos, index, sub, parse_value(ctype, args.value))


def cmd_sdos(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``ethercat sdos``: every object by SDO Information, then its entries (``-q``: objects only)."""
    positions = _selected(backend, args)
    for pos in positions:
        _header(pos, len(positions) > 1, out)
        for obj in backend.object_dictionary(pos):
            print(f'SDO 0x{obj.index:04x}, "{obj.name}"', file=out)
            if args.quiet:
                continue
            for e in obj.entries:
                print(f"  0x{obj.index:04x}:{e.subindex:02x}, {access_text(e.access)}, {type_name(e.data_type)}, "
                      f'{e.bit_length} bit, "{e.name}"', file=out)


@dataclass(frozen=True)
class _SyncLayout:
    """One SyncManager of a slave with its assigned PDOs: [(index, name, [(index, sub, bits, name)])]."""

    index: int
    start: int
    length: int
    control: int
    enable: int
    sm_type: int
    pdos: tuple[tuple[int, str, tuple[tuple[int, int, int, str], ...]], ...]

    @property
    def output(self) -> bool:
        """Master writes, slave reads: SM control register direction bits 2-3 = 01 (ETG.1000.4 SM)."""
        return self.control & 0x0C == 0x04

    @property
    def watchdog(self) -> bool:
        """The SM's watchdog trigger (control register bit 6)."""
        return bool(self.control & 0x40)


def _layout(backend: MasterBackend, pos: int) -> list[_SyncLayout]:
    """SyncManagers (SII), their assigned PDOs (0x1C1x by SDO for CoE slaves) and each PDO's mapped
    entries (0x16xx/0x1Axx), names from the SII PDO categories: what ``pdos`` and ``cstruct`` show."""
    info = backend.sii_info(pos)
    named = sii_pdos(backend.sii_read(pos), info.strings)
    names = {(i, s): n for p in named.values() for i, s, _b, n in p.entries}
    out = []
    for sm_index, (start, length, ctrl, enable, sm_type) in enumerate(info.sync_managers):
        pdos: list[tuple[int, str, tuple[tuple[int, int, int, str], ...]]] = []
        if sm_type in (SmType.OUTPUTS, SmType.INPUTS):
            for pdo_index, entries in _assigned(backend, pos, sm_index, info.coe_details != 0, named):
                pdos.append((pdo_index, named[pdo_index].name if pdo_index in named else "",
                             tuple((i, s, b, names.get((i, s), "")) for i, s, b in entries)))
        out.append(_SyncLayout(sm_index, start, length, ctrl, enable, sm_type, tuple(pdos)))
    return out


def cmd_pdos(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``ethercat pdos``: SyncManagers (SII), their assigned PDOs (0x1C1x by SDO for CoE slaves)
    and each PDO's mapped entries (0x16xx/0x1Axx), names from the SII PDO categories."""
    positions = _selected(backend, args)
    for pos in positions:
        _header(pos, len(positions) > 1, out)
        for sm in _layout(backend, pos):
            print(f"SM{sm.index}: PhysAddr 0x{sm.start:04x}, DefaultSize {sm.length:4d}, ControlRegister "
                  f"0x{sm.control:02x}, Enable {sm.enable}", file=out)
            direction = "R" if sm.sm_type == SmType.OUTPUTS else "T"
            for pdo_index, name, entries in sm.pdos:
                print(f'  {direction}xPDO 0x{pdo_index:04x} "{name}"', file=out)
                for e_index, e_sub, bits, e_name in entries:
                    print(f'    PDO entry 0x{e_index:04x}:{e_sub:02x}, {bits:2d} bit, "{e_name}"', file=out)


def cmd_cstruct(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``ethercat cstruct``: the slave's PDO configuration as the C structures an IgH application
    hands to ``ecrt_slave_config_pdos()`` (ec_pdo_entry_info_t, ec_pdo_info_t, ec_sync_info_t)."""
    ident = {s.position: s for s in backend.slaves()}
    for pos in _selected(backend, args):
        s = ident[pos]
        layout = _layout(backend, pos)
        print(f'/* Master 0, Slave {pos}, "{s.name}"\n * Vendor ID:       0x{s.vendor_id:08x}\n'
              f" * Product code:    0x{s.product_code:08x}\n * Revision number: 0x{s.revision:08x}\n */\n",
              file=out)
        entries = [e for sm in layout for _i, _n, es in sm.pdos for e in es]
        if entries:
            print(f"ec_pdo_entry_info_t slave_{pos}_pdo_entries[] = {{", file=out)
            for index, sub, bits, name in entries:
                print(f"    {{0x{index:04x}, {sub}, {bits}}}, /* {name} */", file=out)
            print("};\n", file=out)
        pdos = [p for sm in layout for p in sm.pdos]
        if pdos:
            print(f"ec_pdo_info_t slave_{pos}_pdos[] = {{", file=out)
            at = 0
            for index, name, es in pdos:
                where = f"slave_{pos}_pdo_entries + {at}" if es else "NULL"
                print(f"    {{0x{index:04x}, {len(es)}, {where}}}, /* {name} */", file=out)
                at += len(es)
            print("};\n", file=out)
        print(f"ec_sync_info_t slave_{pos}_syncs[] = {{", file=out)
        at = 0
        for sm in layout:
            direction = "EC_DIR_OUTPUT" if sm.output else "EC_DIR_INPUT"
            where = f"slave_{pos}_pdos + {at}" if sm.pdos else "NULL"
            watchdog = "EC_WD_ENABLE" if sm.watchdog else "EC_WD_DISABLE"
            print(f"    {{{sm.index}, {direction}, {len(sm.pdos)}, {where}, {watchdog}}},", file=out)
            at += len(sm.pdos)
        print("    {0xff}\n};\n", file=out)


def _assigned(backend: MasterBackend, pos: int, sm_index: int, coe: bool,
              named: dict[int, SiiPdo]) -> list[tuple[int, list[tuple[int, int, int]]]]:
    """(PDO index, [(index, subindex, bits)]) assigned to one SM: by SDO (0x1C10 + SM) on CoE
    slaves, from the SII categories otherwise."""
    if not coe:
        return [(p.index, [(i, s, b) for i, s, b, _n in p.entries]) for p in named.values() if p.sm == sm_index]
    assign = 0x1C10 + sm_index
    out = []
    for i in range(1, backend.sdo_upload(pos, assign, 0)[0] + 1):
        pdo = struct.unpack("<H", backend.sdo_upload(pos, assign, i)[:2])[0]
        entries = []
        for j in range(1, backend.sdo_upload(pos, pdo, 0)[0] + 1):
            word = struct.unpack("<I", backend.sdo_upload(pos, pdo, j)[:4])[0]
            entries.append((word >> 16, (word >> 8) & 0xFF, word & 0xFF))
        out.append((pdo, entries))
    return out


def cmd_sii_read(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``ethercat sii_read``: the SII bytes to stdout (binary), ``--hex`` as an offset/hex listing."""
    img = backend.sii_read(_one(backend, args))
    _bytes_out(img, args.hex, out)


def _bytes_out(data: bytes, hex_listing: bool, out: IO[str]) -> None:
    """Binary to stdout, or (``--hex``) an offset/hex listing, 16 bytes a line."""
    if hex_listing:
        for off in range(0, len(data), 16):
            print(f"{off:04x}: {data[off:off + 16].hex(' ')}", file=out)
        return
    out.flush()
    _binary_out().write(data)


def _binary_out() -> IO[bytes]:
    return sys.stdout.buffer


@contextmanager
def _progress(args: argparse.Namespace, clock: Clock, what: str, total: int | None) -> Iterator[ProgressFn | None]:
    """A rich progress bar on stderr when it is a terminal (or ``--progress``), else nothing; its
    speed is measured on the backend's clock (simulated time in process)."""
    show = args.progress if args.progress is not None else sys.stderr.isatty()
    if not show:
        yield None
        return
    from rich.console import Console
    from rich.progress import BarColumn, DownloadColumn, Progress, TextColumn, TransferSpeedColumn

    console = Console(stderr=True)     # not a terminal (--progress): rich prints the finished bar once
    with Progress(TextColumn("{task.description}"), BarColumn(), DownloadColumn(), TransferSpeedColumn(),
                  console=console, transient=False, get_time=clock.now) as bar:
        task = bar.add_task(what, total=total)

        def update(done: int, _total: int) -> None:
            bar.update(task, completed=done)

        yield update
        bar.update(task, total=bar.tasks[0].completed, completed=bar.tasks[0].completed)


@contextmanager
def _boot(backend: MasterBackend, pos: int, boot: bool) -> Iterator[None]:
    """``--boot``: INIT -> BOOT around the transfer and back to INIT (a firmware update, ETG.1000.6
    bootstrap state), what ``ethercat states BOOT`` before the transfer does on IgH's master."""
    if not boot:
        yield
        return
    for step in state_path(backend.state(pos)[0], AlState.BOOT):
        backend.request_state(step, pos)
    yield
    backend.request_state(AlState.INIT, pos)


def cmd_foe_read(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``ethercat foe_read [-o FILE] NAME``: the file to stdout or to FILE."""
    pos = _one(backend, args)
    with _boot(backend, pos, args.boot), _progress(args, backend.clock, f"foe read {args.name}", None) as progress:
        data = backend.foe_read(pos, args.name, args.password, progress=progress)
    if args.output:
        try:
            Path(args.output).write_bytes(data)
        except OSError as exc:
            raise EcRefused(f"cannot write {args.output}: {exc.strerror or exc}") from None
        return
    out.flush()
    _binary_out().write(data)


def cmd_foe_write(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``ethercat foe_write [-o NAME] FILE``: FILE (``-`` = stdin) to the slave, named NAME
    (default: FILE's base name)."""
    pos = _one(backend, args)
    data: bytes = args.data if getattr(args, "data", None) is not None else _read_input(args.file)
    name = args.name or Path(args.file).name
    with _boot(backend, pos, args.boot), _progress(args, backend.clock, f"foe write {name}", len(data)) as progress:
        backend.foe_write(pos, name, data, args.password, progress=progress)


def _read_input(path: str) -> bytes:
    if path == "-":
        return sys.stdin.buffer.read()
    try:
        return Path(path).read_bytes()
    except OSError as exc:
        raise EcUsage(f"cannot read {path}: {exc.strerror or exc}") from None


#: ESI data type names by bit length (ETG.2000 base types) for ``xml``'s PDO entries.
_ESI_TYPES = {1: "BOOL", 8: "UINT8", 16: "UINT16", 32: "UINT32", 64: "UINT64"}


def cmd_xml(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``ethercat xml``: an ESI (EtherCATInfo, ETG.2000) of each slave from what the line says:
    identity and name, SyncManagers, assigned PDOs and entries (data types by bit length)."""
    from xml.sax.saxutils import escape

    ident = {s.position: s for s in backend.slaves()}
    for pos in _selected(backend, args):
        s = ident[pos]
        lines = ['<?xml version="1.0" ?>', "<EtherCATInfo>", f"  <!-- Slave {pos} -->", "  <Vendor>",
                 f"    <Id>{s.vendor_id}</Id>", "  </Vendor>", "  <Descriptions>", "    <Devices>", "      <Device>",
                 f'        <Type ProductCode="#x{s.product_code:08x}" RevisionNo="#x{s.revision:08x}">'
                 f"{escape(s.name)}</Type>", f"        <Name>{escape(s.name)}</Name>"]
        layout = _layout(backend, pos)
        for sm in layout:
            lines.append(f'        <Sm Enable="{sm.enable}" StartAddress="#x{sm.start:04x}" ControlByte='
                         f'"#x{sm.control:02x}" DefaultSize="{sm.length}" />')
        for sm in layout:
            kind = "RxPdo" if sm.sm_type == SmType.OUTPUTS else "TxPdo"
            for index, name, entries in sm.pdos:
                lines += [f'        <{kind} Sm="{sm.index}" Fixed="1" Mandatory="1">',
                          f"          <Index>#x{index:04x}</Index>", f"          <Name>{escape(name)}</Name>"]
                for e_index, e_sub, bits, e_name in entries:
                    lines += ["          <Entry>", f"            <Index>#x{e_index:04x}</Index>",
                              f"            <SubIndex>{e_sub}</SubIndex>", f"            <BitLen>{bits}</BitLen>",
                              f"            <Name>{escape(e_name)}</Name>"]
                    if e_index:
                        lines.append(f"            <DataType>{_ESI_TYPES.get(bits, f'BIT{bits}')}</DataType>")
                    lines.append("          </Entry>")
                lines.append(f"        </{kind}>")
        lines += ["      </Device>", "    </Devices>", "  </Descriptions>", "</EtherCATInfo>"]
        print("\n".join(lines), file=out)


def cmd_reg_read(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``reg_read ADDRESS [SIZE]``: the bytes in hex, 16 a line; with ``--type`` the value."""
    pos = _one(backend, args)
    address = parse_number(args.address, "address", 0xFFFF)
    ctype = TYPES[args.type] if args.type else None
    size = parse_number(args.size, "size", 0x10000) if args.size is not None else (
        _type_size(ctype) if ctype is not None else 1)
    if address + size > 0x10000:
        raise EcUsage(f"registers 0x{address:04X}+{size} go past the ESC's 64 KiB (0x0000..0xFFFF)")
    data = backend.reg_read(pos, address, size)
    if ctype is not None:
        print(format_value(ctype, data), file=out)
        return
    for k in range(0, len(data), 16):
        print(" ".join(f"0x{b:02x}" for b in data[k:k + 16]), file=out)


def cmd_reg_write(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``reg_write ADDRESS DATA``: DATA by ``--type``, else hex bytes (``0x0a 0x00`` or ``0a00``)."""
    pos = _one(backend, args)
    address = parse_number(args.address, "address", 0xFFFF)
    data = _register_bytes(args)
    if address + len(data) > 0x10000:
        raise EcUsage(f"registers 0x{address:04X}+{len(data)} go past the ESC's 64 KiB (0x0000..0xFFFF)")
    backend.reg_write(pos, address, data)


def _register_bytes(args: argparse.Namespace) -> bytes:
    if args.type:
        return parse_value(TYPES[args.type], args.data)
    text = args.data.replace("0x", "").replace(" ", "").replace(",", "")
    try:
        data = bytes.fromhex(text)
    except ValueError:
        raise EcUsage(f"register data {args.data!r}: hex bytes (0a00 or '0x0a 0x00'), or give --type") from None
    if not data:
        raise EcUsage("register data is empty")
    return data


def _type_size(ctype: CoeType) -> int:
    if not ctype.size:
        raise EcUsage(f"reg-read --type {ctype.name} (variable length) needs SIZE")
    return ctype.size


# ------------------------------------------------------------------------------- domain, config
#: FMMUs an ESC may have (ETG.1000.4 registers 0x0600-0x06FF, 16 bytes each).
MAX_FMMUS = 16
#: FMMU type register: 1 = read (the slave's inputs), 2 = write (its outputs).
FMMU_READ, FMMU_WRITE = 1, 2


@runtime_checkable
class LiveMaster(Protocol):
    """The backend of a persistent master (ec_server): mapped or not, and its exchange counters."""

    @property
    def mapped(self) -> bool: ...

    def counters(self) -> tuple[int, int | None, int | None]: ...


@dataclass(frozen=True, slots=True)
class DomainFmmu:
    """One process-data FMMU as the slave's registers hold it (IgH ``domains -v`` lines)."""

    position: int
    sm: int
    output: bool
    logical: int
    size: int


@dataclass(frozen=True, slots=True)
class Domain:
    """The one process-data domain of the master: the mapped image (IgH ``ethercat domains``)."""

    base: int
    size: int
    fmmus: tuple[DomainFmmu, ...]
    working_counter: int | None
    expected: int | None
    exchanges: int
    wkc_errors: int
    data: bytes


def slave_fmmus(backend: MasterBackend, pos: int) -> list[DomainFmmu]:
    """The active read/write FMMUs of one slave (registers 0x0600..), each with the SyncManager whose
    physical start it maps (SyncManagers from the SII): what the master programmed, on either backend."""
    raw = backend.reg_read(pos, REG_FMMU, 16 * MAX_FMMUS)
    starts = {sm[0]: i for i, sm in enumerate(backend.sii_info(pos).sync_managers)}
    out = []
    for k in range(MAX_FMMUS):
        logical, length, _b0, _b1, phys, _pbit, ftype, active = FMMU_REG.unpack_from(raw, 16 * k)
        if active & 1 and length and ftype in (FMMU_READ, FMMU_WRITE) and phys in starts:
            out.append(DomainFmmu(pos, starts[phys], ftype == FMMU_WRITE, logical, length))
    return out


def read_domain(backend: MasterBackend) -> Domain:
    """The domain: mapped first if the master has not (one exchange then, as a one-shot command has no
    cycle), its FMMUs from the slaves' registers and the image put together from outputs and inputs."""
    live = backend if isinstance(backend, LiveMaster) else None
    wkc: int | None = None
    expected: int | None = None
    exchanges = 0
    if live is None or not live.mapped:
        backend.config_map()
        wkc, expected = backend.exchange()
        exchanges = 1
    if live is not None:
        exchanges, wkc, expected = live.counters()
    fmmus = sorted((f for pos in range(len(backend.slaves())) for f in slave_fmmus(backend, pos)),
                   key=lambda f: (f.logical, f.position))
    base = min((f.logical for f in fmmus), default=0)
    size = max((f.logical + f.size for f in fmmus), default=base) - base
    image = bytearray(size)
    for f in fmmus:
        part = bytes(backend.outputs(f.position)) if f.output else backend.inputs(f.position)
        at = f.logical - base
        image[at:at + f.size] = part[:f.size].ljust(f.size, b"\0")
    return Domain(base, size, tuple(fmmus), wkc, expected, exchanges, backend.wkc_errors, bytes(image))


def _check_domain(args: argparse.Namespace) -> None:
    if args.domain not in (None, 0):
        raise EcUsage(f"no domain {args.domain} (the master has one domain: 0, the mapped image)")


def cmd_domains(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``ethercat domains``: logical base address, size, working counter (last / expected), the
    exchanges so far; ``-v``: each FMMU (slave, SM, direction, logical address, size) with its data."""
    _check_domain(args)
    d = read_domain(backend)
    wkc = "-" if d.working_counter is None else str(d.working_counter)
    expected = "-" if d.expected is None else str(d.expected)
    print(f"Domain0: LogBaseAddr 0x{d.base:08x}, Size {d.size:3d}, WorkingCounter {wkc}/{expected}", file=out)
    print(f"  Exchanges {d.exchanges}, WorkingCounter mismatches {d.wkc_errors}", file=out)
    if not args.verbose:
        return
    for f in d.fmmus:
        print(f"  SlaveConfig 0:{f.position}, SM{f.sm} ({'Output' if f.output else 'Input':>6}), "
              f"LogAddr 0x{f.logical:08x}, Size {f.size}", file=out)
        data = d.data[f.logical - d.base:f.logical - d.base + f.size]
        for k in range(0, len(data), 16):
            print(f"    {data[k:k + 16].hex(' ')}", file=out)


def cmd_data(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``ethercat data``: the domain's process data, binary on stdout (``--hex``: a listing)."""
    _check_domain(args)
    _bytes_out(read_domain(backend).data, args.hex, out)


def cmd_config(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``ethercat config``: one slave configuration per slave (alias:position, vendor/product,
    the attached slave and its state); ``-v``: the SyncManagers with the PDOs and entries assigned."""
    ident = {s.position: s for s in backend.slaves()}
    rows = []
    for pos in _selected(backend, args):
        status, _code = backend.al_status(pos)
        rows.append((pos, _state_name(status) + ("+ERROR" if status & 0x10 else "")))
    if not args.verbose:
        wpos = max(len(str(p)) for p, _ in rows)
        for pos, state in rows:
            s = ident[pos]
            print(f"0:{pos:<{wpos}}  0x{s.vendor_id:08x}/0x{s.product_code:08x}  {pos:>{wpos}}  {state}", file=out)
        return
    for pos, state in rows:
        s = ident[pos]
        print(f"Alias: 0\nPosition: {pos}\nVendor Id: 0x{s.vendor_id:08x}\nProduct code: 0x{s.product_code:08x}\n"
              f"Attached slave: {pos} ({state})\nWatchdog divider: (Default)\nWatchdog intervals: (Default)",
              file=out)
        for sm in _layout(backend, pos):
            if not sm.pdos:
                continue
            print(f"SM{sm.index}, Dir: {'Output' if sm.output else 'Input'}, "
                  f"Watchdog: {'Enable' if sm.watchdog else 'Disable'}", file=out)
            for pdo_index, _name, entries in sm.pdos:
                print(f"  PDO 0x{pdo_index:04x}", file=out)
                for e_index, e_sub, bits, _e_name in entries:
                    print(f"    PDO entry 0x{e_index:04x}:{e_sub:02x}, {bits:2d} bit", file=out)
        print("SDO configuration:\n  None.\nIDN configuration:\n  None.\nFeature flags:\n  None.\n", file=out)


def cmd_master(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """``master``: the master's state (IgH ``ethercat master``); with ``--serve SOCKET`` it stays up
    as a persistent master the other verbs attach to with ``--master SOCKET``."""
    if getattr(args, "serve", None):
        from gatewaylab.cli.ec_server import EcMasterServer

        line = f"-i {args.interface}" if args.interface else f"--rig {args.rig}"
        server = EcMasterServer(backend, args.serve, run_verb, cycle=args.cycle_ms / 1000, line=line)

        def ready() -> None:
            print(f"master serving {line} on {args.serve} ({len(backend.slaves())} slaves, cycle "
                  f"{args.cycle_ms:g} ms); verbs attach with --master {args.serve}; stop: Ctrl-C or "
                  f"gatewaylab ec master --master {args.serve} --stop", file=out, flush=True)

        try:
            server.serve(ready)
        except KeyboardInterrupt:
            pass
        return
    if getattr(args, "stop", False):
        raise EcUsage("--stop needs --master SOCKET")
    slaves = backend.slaves()
    print("Master0", file=out)
    print(f"  Line: {f'-i {args.interface}' if args.interface else f'--rig {args.rig}'} (one-shot)", file=out)
    print(f"  Slaves: {len(slaves)}", file=out)


VERBS: dict[str, tuple[Callable[[MasterBackend, argparse.Namespace, IO[str]], None], str]] = {
    "slaves": (cmd_slaves, "list the slaves: position, alias:position, state, error flag, name"),
    "states": (cmd_states, "list the AL states, or request STATE (INIT, PREOP, BOOT, SAFEOP, OP)"),
    "upload": (cmd_upload, "read an SDO: upload [--type TYPE] INDEX SUBINDEX"),
    "download": (cmd_download, "write an SDO: download [--type TYPE] INDEX SUBINDEX VALUE"),
    "sdos": (cmd_sdos, "list the object dictionary by SDO information"),
    "pdos": (cmd_pdos, "list SyncManagers, assigned PDOs and their mapped entries"),
    "sii-read": (cmd_sii_read, "dump the SII EEPROM (binary to stdout, or --hex)"),
    "foe-read": (cmd_foe_read, "read a file by FoE: foe-read NAME [-o FILE]"),
    "foe-write": (cmd_foe_write, "write a file by FoE: foe-write FILE [-n NAME]"),
    "master": (cmd_master, "the master's state; --serve SOCKET keeps a persistent master up for --master"),
    "cstruct": (cmd_cstruct, "the PDO configuration as C structures for an IgH application"),
    "xml": (cmd_xml, "an ESI (EtherCATInfo XML) of the slave from its SII and PDO assignment"),
    "reg-read": (cmd_reg_read, "read ESC registers: reg-read [--type TYPE] ADDRESS [SIZE]"),
    "reg-write": (cmd_reg_write, "write ESC registers: reg-write [--type TYPE] ADDRESS DATA"),
    "domains": (cmd_domains, "the process-data domain: base address, size, working counter; -v: FMMUs and data"),
    "data": (cmd_data, "the domain's process data (binary to stdout, or --hex)"),
    "config": (cmd_config, "the slave configurations: identity, attached slave, state; -v: SMs, PDOs, entries"),
}


# ------------------------------------------------------------------------------- errors, parser
def describe(exc: BaseException, where: str = "") -> str:
    """One line for an error, with its wire code and the code's text (``where``: " for 0x1008:00")."""
    if isinstance(exc, SdoAbort):
        return f"SDO abort 0x{exc.code:08X}{where}: {abort_text(exc.code)}"
    if isinstance(exc, FoeError):
        try:
            name = f" {FoeErrorCode(exc.code or 0).name}"
        except ValueError:
            name = ""
        return f"FoE error 0x{exc.code:04X}{name}: {FOE_CODE_SUFFIX.sub('', str(exc))}"
    if isinstance(exc, AlStatusError):
        return f"{exc}" if "code 0x" in str(exc) else f"{exc} ({al_status_name(exc.code or 0)})"
    return " ".join(str(exc).split())


def _precheck(args: argparse.Namespace) -> None:
    """Command-line errors that need no slave are reported before the line is opened."""
    ifname = getattr(args, "interface", None)
    if ifname and not getattr(args, "master", None):
        try:
            socket.if_nametoindex(ifname)
        except OSError:   # not found is a usage error (docs/cli.md), not a matter of permissions
            raise EcUsage(f"no such network interface {ifname!r} (`ip link` lists them)") from None
    if getattr(args, "index", None) is not None:
        parse_number(args.index, "index", 0xFFFF)
        parse_number(args.subindex, "subindex", 0xFF)
    if args.verb == "download" and args.type:
        parse_value(TYPES[args.type], args.value)
    if args.verb == "foe-write":
        if args.file == "-" and not args.name:
            raise EcUsage("foe-write from stdin needs -n NAME")
        args.data = _read_input(args.file)


def _failure(args: argparse.Namespace, exc: BaseException) -> tuple[int, str]:
    """The exit code and the one stderr line of a verb's error."""
    if isinstance(exc, EcUsage):
        return 2, f"{PROG} {args.verb}: {exc}"
    where = ""
    if getattr(args, "index", None) is not None:
        try:
            where = f" for 0x{int(args.index, 0):04X}:{int(args.subindex, 0):02X}"
        except ValueError:
            pass
    return 1, f"{PROG} {args.verb}: {describe(exc, where)}"


def cmd_ec(args: argparse.Namespace) -> int:
    """Run one verb: its own errors to one stderr line and an exit code (never a traceback)."""
    fn, _help = VERBS[args.verb]
    try:
        _precheck(args)
        if getattr(args, "master", None):
            if args.verb == "master" and not args.serve:
                return _master_info(args)
            return _remote(args)
        with open_backend(args) as backend:
            fn(backend, args, sys.stdout)
        return 0
    except BrokenPipeError:
        return 0
    except (GatewaylabError, OSError, MasterTimeout) as exc:
        code, line = _failure(args, exc)
        print(line, file=sys.stderr)
        return code


# ------------------------------------------------------------------------------- persistent master
#: Arguments that name the line or the program, not the verb: not sent to a persistent master.
_LOCAL_ARGS = ("func", "open_rig", "master", "interface", "rig", "command", "verbose_log")


def _remote(args: argparse.Namespace) -> int:
    """Run the verb on the persistent master at ``--master SOCKET`` (ec_server.py)."""
    from gatewaylab.cli.ec_server import request

    if args.interface or args.rig:
        raise EcUsage("give the line once: --master SOCKET attaches to a master that has it")
    if args.verb == "master" and args.serve:
        raise EcUsage("--serve starts a master on -i IFNAME or --rig RIG.toml, not on another master")
    if (args.verb in ("sii-read", "data") and not args.hex) or (args.verb == "foe-read" and not args.output):
        raise EcUsage(f"{args.verb} through --master writes no binary to stdout: give "
                      f"{'-o FILE' if args.verb == 'foe-read' else '--hex'}")
    payload: dict[str, Any] = {}
    for key, value in vars(args).items():
        if key in _LOCAL_ARGS or callable(value):
            continue
        if isinstance(value, bytes):
            payload[key + "_b64"] = base64.b64encode(value).decode()
        else:
            payload[key] = value
    if args.verb == "foe-read":
        payload["output"] = str(Path(args.output).resolve())
    answer = request(args.master, {"verb": args.verb, "args": payload})
    sys.stdout.write(answer.get("stdout", ""))
    sys.stderr.write(answer.get("stderr", ""))
    return int(answer.get("code", 1))


def run_verb(backend: MasterBackend, verb: str, payload: dict[str, Any]) -> tuple[int, str, str]:
    """A persistent master runs a client's verb on its backend: (exit code, stdout, stderr)."""
    from io import StringIO

    fields = {k: v for k, v in payload.items() if not k.endswith("_b64")}
    fields.update({k[:-4]: base64.b64decode(v) for k, v in payload.items() if k.endswith("_b64")})
    args = argparse.Namespace(**fields, interface=None, rig=None, master=None)
    args.verb = verb
    out = StringIO()
    if verb not in VERBS:
        return 2, "", f"{PROG}: unknown verb {verb!r}\n"
    try:
        VERBS[verb][0](backend, args, out)
        return 0, out.getvalue(), ""
    except (GatewaylabError, OSError, MasterTimeout) as exc:
        code, line = _failure(args, exc)
        return code, out.getvalue(), line + "\n"
    except (AttributeError, TypeError, ValueError) as exc:     # a client of another version
        return 2, out.getvalue(), f"{PROG} {verb}: bad request: {exc}\n"


def _master_info(args: argparse.Namespace) -> int:
    from gatewaylab.cli.ec_server import request

    if args.stop:
        request(args.master, {"stop": True})
        print(f"master at {args.master} stopped")
        return 0
    info = request(args.master, {"info": True})
    print("Master0")
    print(f"  Line: {info['line']} (persistent, pid {info['pid']}, socket {info['socket']})")
    print(f"  Slaves: {info['slaves']}")
    print(f"  Process data: {'mapped' if info['mapped'] else 'not mapped'}, cycle {info['cycle_ms']:g} ms, "
          f"{info['exchanges']} exchanges, last working counter {info['working_counter']}")
    print(f"  Requests served: {info['requests']}")
    return 0


def _one_line_error(parser: argparse.ArgumentParser, message: str) -> NoReturn:
    """argparse errors as one line (exit 2), like every other error of ``gatewaylab ec``."""
    parser.exit(2, f"{parser.prog}: {' '.join(message.split())} (see --help)\n")


def add_subcommand(subparsers: Any, open_rig: RigOpener | None = None) -> None:
    """``gatewaylab ec VERB`` (registered by ``gatewaylab.cli.ec_rig``, which passes ``open_rig``)."""
    ec = subparsers.add_parser("ec", help="IgH `ethercat`-like verbs: slaves, upload, download, sdos, pdos, FoE",
                               description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    ec.error = types.MethodType(_one_line_error, ec)
    verbs = ec.add_subparsers(dest="verb", metavar="VERB", required=True)
    common = argparse.ArgumentParser(add_help=False)
    line = common.add_argument_group("line (one of)")
    line.add_argument("-i", "--interface", metavar="IFNAME", help="network interface of the line (SOEM, root)")
    line.add_argument("--rig", metavar="RIG.toml", help="run the rig file in process on a simulated clock")
    line.add_argument("--master", metavar="SOCKET", help="attach to a persistent master (gatewaylab ec master "
                      "--serve SOCKET), which keeps the line open and the process data cycling")
    common.add_argument("-p", "--position", type=int, metavar="POSITION",
                        help="slave position (default: all slaves for listings, the only slave otherwise)")
    for verb, (_fn, help_text) in VERBS.items():
        p = verbs.add_parser(verb, parents=[common], help=help_text, description=help_text + ".",
                             epilog=f"example:\n  {EXAMPLES[verb]}",
                             formatter_class=argparse.RawDescriptionHelpFormatter)
        p.error = types.MethodType(_one_line_error, p)
        p.set_defaults(func=cmd_ec, open_rig=open_rig)
        if verb in ("slaves", "config"):
            p.add_argument("-v", "--verbose", action="store_true",
                           help="identity and status of each slave" if verb == "slaves"
                           else "the SyncManagers, PDOs and entries of each configuration")
        elif verb in ("domains", "data"):
            p.add_argument("-d", "--domain", type=int, metavar="INDEX", help="domain index (there is one: 0)")
            if verb == "domains":
                p.add_argument("-v", "--verbose", action="store_true", help="the FMMUs and their process data")
            else:
                p.add_argument("--hex", action="store_true", help="an offset/hex listing instead of binary")
        elif verb in ("reg-read", "reg-write"):
            p.add_argument("-t", "--type", choices=list(TYPES), metavar="TYPE",
                           help=f"data type: {', '.join(TYPES)} (default: raw bytes in hex)")
            p.add_argument("address", help="register address (0x0130 or 304)")
            if verb == "reg-read":
                p.add_argument("size", nargs="?", help="bytes to read (default: the type's size, else 1)")
            else:
                p.add_argument("data", help="value of --type, or hex bytes")
        elif verb == "master":
            p.add_argument("--serve", metavar="SOCKET", help="stay up as a persistent master on this Unix socket")
            p.add_argument("--cycle-ms", type=float, default=2.0, metavar="MS",
                           help="process data cycle of a persistent master once mapped (default 2 ms)")
            p.add_argument("--stop", action="store_true", help="stop the persistent master at --master SOCKET")
        elif verb == "states":
            p.add_argument("state", nargs="?", type=str.upper, choices=list(STATES), metavar="STATE",
                           help="state to request: INIT, PREOP, BOOT, SAFEOP, OP (omit to list)")
        elif verb in ("upload", "download"):
            p.add_argument("-t", "--type", choices=list(TYPES), metavar="TYPE",
                           help=f"data type: {', '.join(TYPES)} (default: from SDO information)")
            p.add_argument("index", help="object index (0x1008 or 4104)")
            p.add_argument("subindex", help="subindex (0 or 0x00)")
            if verb == "download":
                p.add_argument("value", help="value: integer (any base), number, text or hex bytes")
        elif verb == "sdos":
            p.add_argument("-q", "--quiet", action="store_true", help="objects only, no entries")
        elif verb == "sii-read":
            p.add_argument("--hex", action="store_true", help="an offset/hex listing instead of binary")
        elif verb in ("foe-read", "foe-write"):
            if verb == "foe-read":
                p.add_argument("name", metavar="NAME", help="file name on the slave")
                p.add_argument("-o", "--output", metavar="FILE", help="write here instead of stdout")
            else:
                p.add_argument("file", metavar="FILE", help="file to send (- = stdin)")
                p.add_argument("-n", "--name", "-o", "--output-file", dest="name", metavar="NAME",
                               help="file name on the slave (default: FILE's base name)")
            p.add_argument("--password", type=lambda t: int(t, 0), default=0, help="FoE password (default 0)")
            p.add_argument("--boot", action="store_true",
                           help="go to BOOT (via INIT) for the transfer and back to INIT after it (firmware)")
            bar = p.add_mutually_exclusive_group()
            bar.add_argument("--progress", action="store_true", default=None,
                             help="show the progress bar even when stderr is not a terminal")
            bar.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")

