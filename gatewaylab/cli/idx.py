"""``gatewaylab idx ...``: talk to an IDX (emulated or real) over its USB command protocol.

PORT is an endpoint (docs/endpoints.md): a serial device (``/dev/pts/N``, ``/dev/ttyACM0``),
``tcp:127.0.0.1:PORT`` (aliases ``socket://127.0.0.1:PORT``, ``127.0.0.1:PORT``), or ``usb`` /
``usb:VID:PID`` for pyusb.
"""

from __future__ import annotations

import argparse
import errno
import struct
import sys
from collections.abc import Callable
from typing import Any

from gatewaylab.common.endpoint import EndpointError
from gatewaylab.common.errors import ConfigError, LocalError
from gatewaylab.devices.maxon_idx.commands import NmtCommand
from gatewaylab.devices.maxon_idx.errors import SdoAbortCode
from gatewaylab.hosts.maxon_idx.client import IdxClient, IdxError, IdxTimeout

__all__ = ["IdxValueError", "add_subcommand", "cmd_lss_scan", "cmd_nmt", "cmd_read", "cmd_write", "main"]


_NMT = {
    "start": NmtCommand.START_REMOTE_NODE,
    "stop": NmtCommand.STOP_REMOTE_NODE,
    "preop": NmtCommand.ENTER_PRE_OPERATIONAL,
    "reset": NmtCommand.RESET_NODE,
    "reset-comm": NmtCommand.RESET_COMMUNICATION,
}
_TYPES = ("u8", "u16", "u32", "i8", "i16", "i32", "str", "hex")
_DESCRIPTION = """\
Talk to a maxon IDX (emulated or real) over its USB command protocol (IDX Communication Guide
chapter 2); node ids other than 0 and the IDX's own go through its CAN gateway (chapter 5).

PORT is a serial device (/dev/pts/N, /dev/ttyACM0), tcp:127.0.0.1:PORT (what the rig's ready
file lists; socket://127.0.0.1:PORT and 127.0.0.1:PORT are accepted too) or usb / usb:VID:PID
for pyusb. Numbers (node ids, indexes, subindexes, values) are decimal or 0x hex. Errors print
the chapter 6 code, name and cause, e.g.
  error: read node 9 0x1000:00: 0x05040000 "SDO timeout" (SDO protocol timed out)
Exit codes: 0 ok, 1 the IDX or the port failed, 2 the command line is wrong.
"""


class IdxValueError(LocalError, ValueError):
    """A ``write`` VALUE that is no number or does not fit its type (exit 2, as other usage errors)."""


def _ranged(what: str, low: int, high: int, fmt: str) -> Callable[[str], int]:
    """An argparse type: an integer (0x.. ok) in low..high, with a message that says so."""
    def parse(text: str) -> int:
        try:
            value = int(text, 0)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{what} {text!r} is not a number (e.g. {fmt.format(low)})") from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(
                f"{what} {text} outside {fmt.format(low)}..{fmt.format(high)}")
        return value
    parse.__name__ = what
    return parse


#: Guide 2.1: Node-ID BYTE (0 = the IDX, 1..127 CAN nodes, 3.4), Index WORD, Subindex BYTE.
_node = _ranged("node id", 0, 127, "{}")
_index = _ranged("index", 0, 0xFFFF, "0x{:04X}")
_sub = _ranged("subindex", 0, 0xFF, "{}")


def _obj(args: argparse.Namespace) -> str:
    return f"node {args.node} 0x{args.index:04X}:{args.sub:02X}"


def cmd_read(args: argparse.Namespace) -> int:
    """``gatewaylab idx read``: print an object as a typed number, string or hex (ReadObject/segmented, guide 2.1.1)."""
    with IdxClient(args.port, timeout=args.timeout) as client:
        if args.type == "str":
            print(f"{_obj(args)} = {client.read_string(args.node, args.index, args.sub)!r}")
        elif args.type == "hex" or args.segmented:
            data = (client.read_segmented(args.node, args.index, args.sub) if args.segmented
                    else client.read_object(args.node, args.index, args.sub))
            print(f"{_obj(args)} = {data.hex(' ').upper()} ({len(data)} bytes)")
        else:
            value = client.read(args.node, args.index, args.sub, args.type)
            width = _width(args.type)
            print(f"{_obj(args)} = {value} (0x{value & ((1 << 4 * width) - 1):0{width}X})")
    return 0


def _width(type_: str) -> int:
    return {"8": 2, "16": 4, "32": 8}[type_[1:]]


def _value(text: str, type_: str) -> int:
    """VALUE of ``write`` as an integer that fits ``type_`` (u8..i32), else a clear ValueError."""
    try:
        value = int(text, 0)
    except ValueError:
        raise IdxValueError(f"VALUE {text!r} is not a number (use -t str or -t hex for bytes)") from None
    bits = int(type_[1:])
    low, high = (0, (1 << bits) - 1) if type_[0] == "u" else (-(1 << (bits - 1)), (1 << (bits - 1)) - 1)
    if not low <= value <= high:
        raise IdxValueError(f"VALUE {text} does not fit {type_} ({low}..{high})")
    return value


def cmd_write(args: argparse.Namespace) -> int:
    """``gatewaylab idx write``: write a typed value, bytes or a string (WriteObject/segmented, guide 2.1.2)."""
    with IdxClient(args.port, timeout=args.timeout) as client:
        if args.type in ("str", "hex"):
            data = args.value.encode() if args.type == "str" else bytes.fromhex(args.value)
            if len(data) <= 4 and not args.segmented:
                client.write_object(args.node, args.index, args.sub, data)
            else:
                client.write_segmented(args.node, args.index, args.sub, data)
        else:
            client.write(args.node, args.index, args.sub, _value(args.value, args.type), args.type)
        print(f"{_obj(args)} written")
    return 0


def cmd_nmt(args: argparse.Namespace) -> int:
    """``gatewaylab idx nmt``: send an NMT command to one node, node 0 = all (SendNMTService, guide 2.1.2.4)."""
    with IdxClient(args.port, timeout=args.timeout) as client:
        client.nmt(args.node, _NMT[args.command])
    target = "all nodes" if args.node == 0 else f"node {args.node}"
    print(f"NMT {args.command} ({int(_NMT[args.command])}) sent to {target}")
    return 0


def cmd_lss_scan(args: argparse.Namespace) -> int:
    """Fastscan unconfigured drives one by one; assign node ids from --assign on."""
    found = 0
    with IdxClient(args.port, timeout=args.timeout) as client:
        client.switch_state_global(False)
        next_id = args.assign
        while found < args.max:
            address = client.fastscan(args.lss_timeout)
            if address is None:
                break
            found += 1
            line = (f"found vendor 0x{address.vendor_id:08X} product 0x{address.product_code:08X} "
                    f"revision 0x{address.revision:08X} serial 0x{address.serial:08X}")
            if next_id is None:
                print(line)
                print("(stopped at the first one: it keeps answering until it has a node id; "
                      "--assign N configures the found drives as N, N+1, ...)")
                client.switch_state_global(False)
                break                      # without a node id it would answer every scan again
            client.configure_node_id(next_id, args.lss_timeout)
            if args.store:
                client.store_configuration(args.lss_timeout)
            client.switch_state_global(False)
            print(f"{line} -> node id {next_id}{' (stored)' if args.store else ''}")
            next_id += 1
        if not found:
            print("no unconfigured LSS slave answered")
    return 0


def _reason(exc: Exception, port: str) -> str:
    """pyserial's message without its own "could not open port PORT: " and errno prefixes."""
    text = (exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)).strip()
    for prefix in (f"could not open port {port}: ", "[Errno "):
        if text.lower().startswith(prefix.lower()):
            text = text[len(prefix):]
            if prefix == "[Errno ":
                text = text.split("] ", 1)[-1]
    return text


def _run(func: Any) -> Any:
    def wrapper(args: argparse.Namespace) -> int:
        try:
            result: int = func(args)
            return result
        except EndpointError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        except IdxTimeout as exc:
            print(f"error: no reply from {args.port} within {args.timeout:g} s to {exc.request}: "
                  "is it an IDX, and is no other program using it?", file=sys.stderr)
            return 1
        except IdxError as exc:
            hint = ""
            if exc.code == SdoAbortCode.LENGTH_MISMATCH and getattr(args, "idx_command", "") == "read" \
                    and not args.segmented and args.type not in ("str",):
                hint = "\nhint: an object longer than 4 bytes needs the segmented read: add -s or -t str"
            print(f"error: {exc}{hint}", file=sys.stderr)
            return 1
        except (OSError, ConfigError) as exc:        # serial.SerialException is an OSError
            reason = _reason(exc, args.port)
            if "Inappropriate ioctl" in reason:
                reason = "not a serial port (so not an IDX)"
            print(f"error: cannot open port {args.port}: {reason}", file=sys.stderr)
            # docs/cli.md: a port that is not one (no such device, a Unix socket) is the user's to fix (2)
            missing = isinstance(exc, OSError) and exc.errno == errno.ENOENT
            return 2 if missing or isinstance(exc, ConfigError) else 1
        except (ValueError, struct.error, LocalError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
    return wrapper


def add_subcommand(subparsers: Any) -> None:
    """Add ``idx`` with ``read``, ``write``, ``nmt`` and ``lss-scan`` to the gatewaylab CLI."""
    idx = subparsers.add_parser("idx", help="maxon IDX USB client (read/write objects, NMT, LSS)",
                                description=_DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = idx.add_subparsers(dest="idx_command", required=True)

    def common(p: argparse.ArgumentParser) -> None:
        p.add_argument("port", metavar="PORT", help="/dev/pts/N, tcp:127.0.0.1:PORT, or usb")
        p.add_argument("--timeout", type=float, default=1.0, help="reply timeout in seconds")

    def obj(p: argparse.ArgumentParser) -> None:
        p.add_argument("node", metavar="NODE", type=_node, help="0 = the IDX itself, 1..127 = a CAN node "
                       "(the IDX's own id is local, others go through the gateway)")
        p.add_argument("index", metavar="INDEX", type=_index, help="object index, e.g. 0x6041")
        p.add_argument("sub", metavar="SUB", type=_sub, help="subindex, e.g. 0")
        p.add_argument("--type", "-t", choices=_TYPES, default="u32",
                       help="value type (default u32); str and hex are bytes: str always read segmented, "
                            "hex with -s, writes of more than 4 bytes segmented")
        p.add_argument("--segmented", "-s", action="store_true", help="use the segmented commands")

    p = sub.add_parser("read", help="read an object")
    common(p)
    obj(p)
    p.set_defaults(func=_run(cmd_read))

    p = sub.add_parser("write", help="write an object")
    common(p)
    obj(p)
    p.add_argument("value", metavar="VALUE", help="integer (0x.. ok), text for str, hex bytes for hex")
    p.set_defaults(func=_run(cmd_write))

    p = sub.add_parser("nmt", help="send an NMT command")
    common(p)
    p.add_argument("node", metavar="NODE", type=_node, help="0 = all nodes, else 1..127")
    p.add_argument("command", choices=sorted(_NMT))
    p.set_defaults(func=_run(cmd_nmt))

    p = sub.add_parser("lss-scan", help="find unconfigured drives by LSS fastscan (and configure them)")
    common(p)
    p.add_argument("--assign", type=_ranged("node id", 1, 127, "{}"), default=None, metavar="N",
                   help="give the found drives node ids N, N+1, ...")
    p.add_argument("--store", action="store_true", help="store the configuration in each drive")
    p.add_argument("--max", type=_ranged("count", 1, 127, "{}"), default=127, help="stop after this many drives")
    p.add_argument("--lss-timeout", type=_ranged("timeout", 1, 0xFFFF, "{}"), default=20,
                   metavar="MS", help="ReadLSS timeout per request")
    p.set_defaults(func=_run(cmd_lss_scan))


def main(argv: list[str] | None = None) -> int:
    """Stand-alone entry (``python -m gatewaylab.cli.idx idx read ...``)."""
    parser = argparse.ArgumentParser(prog="gatewaylab")
    add_subcommand(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    result: int = args.func(args)
    return result


if __name__ == "__main__":
    sys.exit(main())
