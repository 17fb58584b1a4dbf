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
import sys
import types
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, NoReturn

from gatewaylab.cli.ec_args import (
    PROG,
    STATES,
    TYPES,
    CoeType,
    EcUsage,
    format_value,
    parse_number,
    parse_value,
    read_input,
)
from gatewaylab.cli.ec_foe import cmd_foe_read, cmd_foe_write
from gatewaylab.cli.ec_pdo import LiveMaster, cmd_config, cmd_cstruct, cmd_data, cmd_domains, cmd_pdos, cmd_xml
from gatewaylab.cli.ec_sdo import cmd_download, cmd_sdos, cmd_upload
from gatewaylab.cli.ec_slaves import cmd_reg_read, cmd_reg_write, cmd_sii_read, cmd_slaves, cmd_states
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.common.errors import ConfigError, GatewaylabError
from gatewaylab.ethercat.errors import AlStatusError, FoeError, FoeErrorCode
from gatewaylab.hosts.ethercat.backend import MasterBackend, MasterTimeout
from gatewaylab.hosts.ethercat.shared import FOE_CODE_SUFFIX, al_status_name
from gatewaylab.hosts.ethercat.states import state_path
from gatewaylab.od.aborts import SdoAbort, abort_text

if TYPE_CHECKING:
    from gatewaylab.rig.runtime import Rig

__all__ = [   # the verbs' values and helpers, still found here by tests and scripts
    "TYPES", "VERBS", "CoeType", "LiveMaster", "add_subcommand", "cmd_ec", "describe", "format_value",
    "open_backend", "open_rig", "parse_value", "run_verb", "state_path",
]

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


# ------------------------------------------------------------------------------- backend
def open_rig(path: str) -> Rig:
    """The rig of ``path`` on a simulated clock, without bus endpoints or wires, started: the line of
    ``--rig`` for ``gatewaylab ec`` and the ``gatewaylab ecan`` host programs."""
    from gatewaylab.rig.runtime import Rig

    rig = Rig.from_file(path, clock=SimulatedClock(), endpoints=False)
    try:
        rig.start()
    except BaseException:
        rig.close()
        raise
    return rig


@contextmanager
def open_line(interface: str | None, rig_path: str | None,
              usage: type[GatewaylabError]) -> Iterator[tuple[MasterBackend, Rig | None]]:
    """The backend of ``-i IFNAME`` (PysoemBackend) or of ``--rig RIG.toml`` (in process on a simulated
    clock) with the rig it runs in (None on a real line), both closed after; ``usage`` is raised for a
    missing or wrong rig file. ``gatewaylab ec`` and the ``gatewaylab ecan`` host programs open lines so."""
    if interface:
        from gatewaylab.hosts.ethercat.pysoem_backend import PysoemBackend

        backend: MasterBackend = PysoemBackend(interface)
        try:
            yield backend, None
        finally:
            backend.close()
        return
    if not rig_path or not Path(rig_path).is_file():
        raise usage(f"rig file {rig_path} does not exist")
    try:
        rig = open_rig(rig_path)
    except ConfigError as exc:
        raise usage(" ".join(str(exc).split())) from None
    try:
        from gatewaylab.hosts.ethercat.inprocess import InProcessBackend

        backend = InProcessBackend.from_rig(rig)
        try:
            yield backend, rig
        finally:
            backend.close()
    finally:
        rig.close()


@contextmanager
def open_backend(args: argparse.Namespace) -> Iterator[MasterBackend]:
    """``-i IFNAME`` -> PysoemBackend; ``--rig RIG.toml`` -> the rig in process on a simulated clock."""
    if bool(args.interface) == bool(args.rig):
        raise EcUsage("give the line: -i IFNAME (real interface, root), --rig RIG.toml (in process) or "
                      "--master SOCKET (a persistent master)")
    with open_line(args.interface, args.rig, EcUsage) as (backend, _rig):
        yield backend


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
        args.data = read_input(args.file)


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
_LOCAL_ARGS = ("func", "master", "interface", "rig", "command", "verbose_log")


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


def add_subcommand(subparsers: Any) -> None:
    """Register ``gatewaylab ec VERB`` (cli/main.py EXTRA_SUBCOMMANDS)."""
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
        p.set_defaults(func=cmd_ec)
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
