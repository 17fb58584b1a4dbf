"""``gatewaylab sdo``: read or write one object of any CANopen node on a rig's bus over SDO.

The client is python ``canopen``'s (the one CANopen users have), reaching the bus through the
``gatewaylab`` python-can interface: expedited, segmented and (``--block``) block transfers, with
canopen's default timeouts and no retry. A value is printed as a number in decimal and hex for
integer types, as text for strings, as hex bytes otherwise; an SDO abort prints its code and text
(CiA 301 7.2.4.3.17) and exits 1, like every answer the node refuses (docs/cli.md exit codes).
"""

from __future__ import annotations

import argparse
import logging
import struct
import sys
from dataclasses import dataclass
from typing import Any

import can

from gatewaylab.cli.target import bus_target
from gatewaylab.common.endpoint import EndpointError
from gatewaylab.common.errors import ConfigError

__all__ = ["TYPES", "SdoType", "add_subcommand", "cmd_sdo", "format_value", "parse_value"]


@dataclass(frozen=True, slots=True)
class SdoType:
    """One ``--type``: how a value is written to and read from the object's bytes (little endian)."""

    name: str
    #: struct code of an integer or float type; "" for str / hex (any length)
    code: str = ""

    @property
    def size(self) -> int:
        """Bytes of a fixed-size type, 0 for str / hex."""
        return struct.calcsize("<" + self.code) if self.code else 0

    @property
    def is_integer(self) -> bool:
        """An integer type: printed in decimal and hex."""
        return self.code not in ("", "f", "d")


TYPES: dict[str, SdoType] = {t.name: t for t in (
    SdoType("u8", "B"), SdoType("u16", "H"), SdoType("u32", "I"), SdoType("u64", "Q"),
    SdoType("i8", "b"), SdoType("i16", "h"), SdoType("i32", "i"), SdoType("i64", "q"),
    SdoType("f32", "f"), SdoType("f64", "d"), SdoType("str"), SdoType("hex"))}

#: canopen.objectdictionary data type codes (CiA 301 table 44) -> our types
_EDS_TYPES = {0x01: "u8", 0x02: "i8", 0x03: "i16", 0x04: "i32", 0x05: "u8", 0x06: "u16", 0x07: "u32",
              0x08: "f32", 0x09: "str", 0x0A: "hex", 0x0F: "hex", 0x11: "f64", 0x15: "i64", 0x1B: "u64"}

_DESCRIPTION = """\
Read (upload) or write (download) one object of a CANopen node on a bus of a running rig, over
SDO with python canopen's client: expedited and segmented transfers, block transfers with --block.

  gatewaylab sdo TARGET NODE upload INDEX SUBINDEX [--type TYPE]
  gatewaylab sdo TARGET NODE download INDEX SUBINDEX VALUE --type TYPE

TARGET is the ready file of `gatewaylab run` (with --bus NAME, default can0) or a bus endpoint
(unix:PATH, tcp:HOST:PORT). TYPE: u8 u16 u32 u64 i8 i16 i32 i64 f32 f64 str hex. An upload prints
integers as `DECIMAL (0xHEX)`, strings as text, other values as hex bytes; without --type (and
without --eds) the bytes are printed as hex. --eds FILE takes names and types from an EDS/DCF:
INDEX and SUBINDEX may then be names ("Producer heartbeat time", 0x1017) and --type may be left out.

exit 0: done; 1: the node aborted the transfer (code and text printed) or did not answer;
2: usage (bad number, value, type or target).

examples:
  gatewaylab sdo ready.json 2 upload 0x1000 0 --type u32
  gatewaylab sdo ready.json 2 upload 0x1008 0 --type str
  gatewaylab sdo ready.json 2 download 0x1017 0 500 --type u16
  gatewaylab sdo ready.json 2 upload 0x1008 0 --type str --block
"""


class UsageError(ConfigError):
    """A wrong argument: exit 2 with this text."""


def parse_value(text: str, kind: SdoType) -> bytes:
    """The bytes a download of ``text`` as ``kind`` sends (UsageError when it does not fit)."""
    if kind.name == "str":
        return text.encode("utf-8")
    if kind.name == "hex":
        cleaned = text.replace(" ", "").replace(":", "").replace(".", "")
        if cleaned.lower().startswith("0x"):
            cleaned = cleaned[2:]
        try:
            return bytes.fromhex(cleaned)
        except ValueError:
            raise UsageError(f"value {text!r} is not hex bytes (e.g. 01A2FF)") from None
    try:
        value: int | float = float(text) if kind.code in ("f", "d") else int(text, 0)
        return struct.pack("<" + kind.code, value)
    except (ValueError, struct.error):
        raise UsageError(f"value {text!r} does not fit type {kind.name}") from None


def format_value(data: bytes, kind: SdoType | None) -> str:
    """How an upload is printed: ``DECIMAL (0xHEX)`` for integers, text for strings, hex bytes otherwise."""
    if kind is None or kind.name == "hex" or (kind.size and len(data) != kind.size):
        return data.hex(" ").upper() if data else "(no data)"
    if kind.name == "str":
        return data.decode("utf-8", errors="replace").rstrip("\0")
    (value,) = struct.unpack("<" + kind.code, data)
    if not kind.is_integer:
        return repr(value)
    return f"{value} (0x{value & ((1 << 8 * kind.size) - 1):0{2 * kind.size}X})"


def _number(text: str, what: str, limit: int) -> int:
    try:
        value = int(text, 0)
    except ValueError:
        raise UsageError(f"{what} {text!r} is not a number (decimal or 0x hex)") from None
    if not 0 <= value <= limit:
        raise UsageError(f"{what} {value} is outside 0..{limit}")
    return value


def _address(od: Any, index_text: str, sub_text: str) -> tuple[int, int, Any]:
    """(index, subindex, the EDS variable or None) from numbers or, with an EDS, names."""
    var = None
    try:
        index = int(index_text, 0)
    except ValueError:
        if od is None or index_text not in od:
            raise UsageError(f"object {index_text!r} is neither a number nor a name in the EDS") from None
        index = od[index_text].index
    _number(str(index), "index", 0xFFFF)
    try:
        subindex = _number(sub_text, "subindex", 0xFF)
    except UsageError:
        if od is None or index not in od:
            raise
        obj = od[index]
        try:
            subindex = obj[sub_text].subindex
        except (KeyError, TypeError):
            raise UsageError(f"sub-object {sub_text!r} is neither a number nor a name of 0x{index:04X}") from None
    if od is not None and index in od:
        obj = od[index]
        try:
            var = obj if not hasattr(obj, "subindices") else obj[subindex]
        except KeyError:
            var = None
        if var is not None and not hasattr(obj, "subindices") and subindex != 0:
            var = None
    return index, subindex, var


def _type_of(args: argparse.Namespace, var: Any) -> SdoType | None:
    if args.type is not None:
        return TYPES[args.type]
    if var is not None and getattr(var, "data_type", None) in _EDS_TYPES:
        return TYPES[_EDS_TYPES[var.data_type]]
    return None


def cmd_sdo(args: argparse.Namespace) -> int:
    """Run one upload or download; print the value or the abort."""
    import canopen
    from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

    try:
        node_id = _number(args.node, "node-ID", 127)
        if node_id == 0:
            raise UsageError("node-ID 0 is not a node (1..127)")
        od: Any = None
        if args.eds is not None:
            try:
                od = canopen.import_od(args.eds, node_id)
            except Exception as exc:   # canopen raises what its parser meets: one line for the user
                raise UsageError(f"{args.eds}: not a readable EDS/DCF ({exc})") from None
        index, subindex, var = _address(od, args.index, args.subindex)
        kind = _type_of(args, var)
        payload = b""
        if args.action == "download":
            if args.value is None:
                raise UsageError("download needs a VALUE")
            if kind is None:
                raise UsageError("download needs --type (u8 u16 u32 u64 i8 i16 i32 i64 f32 f64 str hex) or --eds")
            payload = parse_value(args.value, kind)
        elif args.value is not None:
            raise UsageError(f"upload takes no VALUE (got {args.value!r})")
        endpoint = bus_target(args.target, args.bus)      # docs/cli.md: malformed or not there: exit 2
    except (UsageError, EndpointError) as exc:
        print(f"gatewaylab sdo: {exc}", file=sys.stderr)
        return 2
    where = f"node {node_id} 0x{index:04X}:{subindex:02X}"
    # canopen logs the aborts and timeouts it raises; this command reports them itself, once
    logging.getLogger("canopen").setLevel(logging.CRITICAL)
    network = canopen.Network()
    try:
        network.connect(interface="gatewaylab", channel=endpoint, shutdown_timeout=0.5)
    except (can.CanError, OSError) as exc:
        print(f"gatewaylab sdo: cannot open bus {endpoint}: {exc}", file=sys.stderr)
        return 1
    try:
        node = network.add_node(node_id, od if od is not None else canopen.ObjectDictionary())  # type: ignore[no-untyped-call]
        if args.action == "upload":
            if args.block:
                with node.sdo.open(index, subindex, "rb", block_transfer=True) as stream:
                    data = stream.read()
            else:
                data = node.sdo.upload(index, subindex)
            text = format_value(bytes(data), kind)
            name = getattr(var, "name", None)
            print(f"{name}: {text}" if name else text)
        else:
            if args.block:
                with node.sdo.open(index, subindex, "wb", size=len(payload), block_transfer=True) as stream:
                    stream.write(payload)
            else:
                node.sdo.download(index, subindex, payload)
        return 0
    except SdoAbortedError as exc:
        print(f"gatewaylab sdo: {where}: SDO abort 0x{exc.code:08X}: {_abort_text(exc)}", file=sys.stderr)
        return 1
    except SdoCommunicationError as exc:
        print(f"gatewaylab sdo: {where}: {exc} (is node {node_id} on bus {args.bus} and powered?)", file=sys.stderr)
        return 1
    except can.CanError as exc:
        print(f"gatewaylab sdo: {where}: {exc}", file=sys.stderr)
        return 1
    finally:
        network.disconnect()


def _abort_text(exc: Any) -> str:
    """canopen's text of an abort code, without its own 'Code 0x...' prefix."""
    text = str(exc)
    return text.split(", ", 1)[1] if text.startswith("Code ") and ", " in text else text


def add_subcommand(subparsers: Any) -> None:
    """Add ``sdo`` to the gatewaylab CLI."""
    p = subparsers.add_parser("sdo", help="read or write an object of a CANopen node over SDO",
                              description=_DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("target", metavar="TARGET", help="ready file of `gatewaylab run`, or a bus endpoint")
    p.add_argument("node", metavar="NODE", help="node-ID 1..127")
    p.add_argument("action", choices=("upload", "download"), help="upload (read) or download (write)")
    p.add_argument("index", metavar="INDEX", help="object index, e.g. 0x1017 (or a name with --eds)")
    p.add_argument("subindex", metavar="SUBINDEX", help="sub-index, e.g. 0 (or a name with --eds)")
    p.add_argument("value", metavar="VALUE", nargs="?", help="the value to download")
    p.add_argument("--type", choices=sorted(TYPES), help="the object's type (u8 ... hex)")
    p.add_argument("--bus", default="can0", help="bus name in the ready file (default can0)")
    p.add_argument("--block", action="store_true", help="use an SDO block transfer (CiA 301 7.2.4.3.9)")
    p.add_argument("--eds", metavar="FILE", help="EDS or DCF of the node: names and types")
    p.set_defaults(func=cmd_sdo)
