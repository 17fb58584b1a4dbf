"""The values of ``gatewaylab ec``: CoE types as IgH names them, value parsing and printing, which
slaves a verb acts on, and the usage/refusal errors every verb raises."""

from __future__ import annotations

import argparse
import struct
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from gatewaylab.common.errors import GatewaylabError
from gatewaylab.ethercat.esc import AlState
from gatewaylab.hosts.ethercat.backend import MasterBackend

__all__ = [
    "BIT_TYPES",
    "PROG",
    "STATES",
    "TYPES",
    "TYPE_BY_CODE",
    "CoeType",
    "EcRefused",
    "EcUsage",
    "access_text",
    "binary_out",
    "bytes_out",
    "format_value",
    "one_slave",
    "parse_number",
    "parse_value",
    "read_input",
    "selected_slaves",
    "slave_header",
    "state_name",
    "type_name",
]


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


# ------------------------------------------------------------------------------- slave selection, output
def one_slave(backend: MasterBackend, args: argparse.Namespace) -> int:
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


def selected_slaves(backend: MasterBackend, args: argparse.Namespace) -> list[int]:
    """-p POSITION or every slave (IgH's default for listings)."""
    count = len(backend.slaves())
    if args.position is None:
        return list(range(count))
    _check_position(args.position, count)
    return [int(args.position)]


def state_name(status: int) -> str:
    """The state of an AL status byte by name (``0x3`` for a value that is no state)."""
    return AlState(status & 0x0F).name if status & 0x0F in set(STATES.values()) else f"0x{status & 0x0F:X}"


def slave_header(position: int, several: bool, out: IO[str]) -> None:
    """IgH's ``=== Master 0, Slave N ===`` line, printed only when a listing covers several slaves."""
    if several:
        print(f"=== Master 0, Slave {position} ===", file=out)


def bytes_out(data: bytes, hex_listing: bool, out: IO[str]) -> None:
    """Binary to stdout, or (``--hex``) an offset/hex listing, 16 bytes a line."""
    if hex_listing:
        for off in range(0, len(data), 16):
            print(f"{off:04x}: {data[off:off + 16].hex(' ')}", file=out)
        return
    out.flush()
    binary_out().write(data)


def binary_out() -> IO[bytes]:
    """Where binary output (SII, FoE files, process data) goes: stdout's byte stream."""
    return sys.stdout.buffer


def read_input(path: str) -> bytes:
    """The bytes of a file to send (``-`` = stdin), or EcUsage naming a file that cannot be read."""
    if path == "-":
        return sys.stdin.buffer.read()
    try:
        return Path(path).read_bytes()
    except OSError as exc:
        raise EcUsage(f"cannot read {path}: {exc.strerror or exc}") from None
