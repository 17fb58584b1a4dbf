"""``gatewaylab ecan ...``: ECAN-Lite tools (``pack``: build a FoE OTA package, manual 15.3.1; ``simple-loop``,
``sdo-probe``, ``cia402``: the host programs of 15.4 / 15.6, in ``host/cli.py``)."""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path
from typing import Any

from gatewaylab.cli.ecan_programs import add_host_commands
from gatewaylab.devices.ecanlite.ota import APP_FILE_NAME, HEADER_SIZE, FirmwareVersion, OtaError, pack

__all__ = ["add_subcommand", "cmd_pack"]


_PACK_EPILOG = f"""\
example:
  gatewaylab ecan pack APP.bin --version 1.4 --build 0x2291 -o ecan_lite_v140.bin

The package is a {HEADER_SIZE}-byte header (magic "ECLA", device type, version major.minor,
build, payload size, CRC32s; docs/devices/ecanlite-mcan.md) followed by APP.bin. Write it to the
device with FoE, file name {APP_FILE_NAME!r}, password 0, e.g. IgH:
  ethercat foe_write -p 0 -o {APP_FILE_NAME} ecan_lite_v140.bin
Exit codes: 0 ok, 2 on any error (one line on stderr).
"""


class _Usage(Exception):
    """A wrong command line (exit 2)."""


def _version(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"(\d+)\.(\d+)", text.strip())
    if not m or int(m.group(1)) > 255 or int(m.group(2)) > 255:
        raise argparse.ArgumentTypeError(f"version {text!r} is not MAJOR.MINOR with each 0..255 (e.g. 1.4)")
    return int(m.group(1)), int(m.group(2))


def _build(text: str) -> int:
    try:
        value = int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"build {text!r} is not a number (e.g. 0x2291)") from None
    if not 0 <= value <= 0xFFFF:
        raise argparse.ArgumentTypeError(f"build {text} outside 0..0xFFFF")
    return value


def _device_type(text: str) -> int:
    try:
        value = int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"device type {text!r} is not a number") from None
    if not 0 <= value <= 0xFF:
        raise argparse.ArgumentTypeError(f"device type {text} outside 0..255")
    return value


def cmd_pack(args: argparse.Namespace) -> int:
    """Wrap a bare application into an OTA package."""
    try:
        app = Path(args.app).read_bytes()
    except OSError as exc:
        print(f"gatewaylab: cannot read {args.app}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    if not app:
        print(f"gatewaylab: {args.app} is empty", file=sys.stderr)
        return 2
    if app[:4] == b"ECLA":
        print(f"gatewaylab: {args.app} is already a package", file=sys.stderr)
        return 2
    major, minor = args.version
    try:
        package = pack(app, FirmwareVersion(major, minor, args.build), args.device_type)
    except OtaError as exc:
        print(f"gatewaylab: {exc}", file=sys.stderr)
        return 2
    try:
        Path(args.output).write_bytes(package)
    except OSError as exc:
        print(f"gatewaylab: cannot write {args.output}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    _report(args.output, FirmwareVersion(major, minor, args.build), len(app), len(package))
    return 0


def _report(path: str, version: FirmwareVersion, app_bytes: int, total: int) -> None:
    print(f"{path}: ECAN-Lite package {version}, {app_bytes} B application + {HEADER_SIZE} B header "
          f"= {total} B")


class _Parser(argparse.ArgumentParser):
    """argparse with a one-line error and exit code 2."""

    def error(self, message: str) -> Any:
        self.exit(2, f"gatewaylab ecan: {message}\n")


def add_subcommand(sub: Any) -> None:
    """Register ``gatewaylab ecan`` with its sub-commands (cli/main.py EXTRA_SUBCOMMANDS)."""
    ecan = sub.add_parser("ecan", help="ECAN-Lite tools (OTA package, host programs of 15.4/15.6)",
                          description="Tools for the ECAN-Lite EtherCAT to CAN FD gateway.")
    ecan_sub = ecan.add_subparsers(dest="ecan_command", metavar="COMMAND", parser_class=_Parser)
    p = ecan_sub.add_parser("pack", help="build a FoE OTA package from a bare application image",
                            description="Build a packaged ECAN-Lite application (manual 15.3.1) from a bare "
                                        "application binary.",
                            epilog=_PACK_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("app", metavar="APP.bin", help="bare application binary")
    p.add_argument("--version", required=True, type=_version, metavar="MAJOR.MINOR",
                   help="firmware version shown in 0xF000:05 (e.g. 1.4)")
    p.add_argument("--build", required=True, type=_build, metavar="BUILD",
                   help="16-bit build number shown in 0xF000:06 (e.g. 0x2291)")
    p.add_argument("--device-type", type=_device_type, default=0, metavar="N",
                   help="device type, 0xF000:01 (default 0 = ECAN-Lite)")
    p.add_argument("-o", "--output", required=True, metavar="FILE", help="package to write")
    p.set_defaults(func=cmd_pack)
    add_host_commands(ecan_sub)

    def no_command(args: argparse.Namespace) -> int:
        ecan.print_help()
        return 2
    ecan.set_defaults(func=no_command)
