"""The ``gatewaylab`` command line."""

from __future__ import annotations

import argparse
import contextlib
import errno
import gc
import json
import logging
import os
import signal
import sys
from collections.abc import Callable
from importlib import import_module
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any

from gatewaylab import __version__, build_info
from gatewaylab.common.errors import ConfigError, GatewaylabError

if TYPE_CHECKING:
    from gatewaylab.rig.config import RigConfig
    from gatewaylab.rig.runtime import Rig
    from gatewaylab.rig.web import RigWeb

__all__ = [
    "EXTRA_SUBCOMMANDS",
    "RIG_HELP",
    "RUN_UNTIL_STOPPED",
    "STOP_SIGNALS",
    "Interrupted",
    "SubcommandError",
    "UsageError",
    "build_parser",
    "cmd_demo",
    "cmd_rig_show",
    "cmd_run",
    "interrupted_exit",
    "main",
]


#: Sub-commands contributed by other parts of the package: module with ``add_subcommand(subparsers)``.
#: Each must load: a module that fails to import (or lacks the function) stops ``gatewaylab`` with
#: :class:`SubcommandError` naming it, rather than leaving its command out of the parser.
EXTRA_SUBCOMMANDS = (
    "gatewaylab.cli.idx",
    "gatewaylab.cli.lss",
    "gatewaylab.cli.monitor",
    "gatewaylab.cli.send",
    "gatewaylab.cli.sdo",
    "gatewaylab.cli.eds",
    "gatewaylab.cli.lesson",
    "gatewaylab.cli.plot",
    "gatewaylab.cli.play",
    "gatewaylab.cli.net",
    "gatewaylab.cli.ec",
    "gatewaylab.cli.fault",
    "gatewaylab.cli.ecan",
    "gatewaylab.cli.migrate",
    "gatewaylab.cli.esi",
)

RIG_HELP = """\
A rig file (TOML) declares the clock mode, the buses and the simulated participants, e.g.:

  clock = "realtime"
  [[bus]]
  name = "can0"
  bitrate = 1000000
  data_bitrate = 5000000      # optional: CAN FD
  endpoint = "unix"           # unix (default) | tcp | none
  [[drive]]
  bus = "can0"
  node_id = 2                 # omit: unconfigured until an LSS master assigns one
  serial = 0x1002

See docs/rig.md for every section.
"""


class UsageError(GatewaylabError):
    """The command line asks for something impossible (exit code 2, like argparse's own errors)."""


class SubcommandError(GatewaylabError):
    """A module of :data:`EXTRA_SUBCOMMANDS` does not load: a broken install or a defect (exit code 1),
    never a command quietly missing from ``gatewaylab --help``."""


def _subcommand_adder(module_name: str) -> Callable[[Any], None]:
    """The ``add_subcommand`` of one EXTRA_SUBCOMMANDS module; SubcommandError saying why it is not there."""
    try:
        module = import_module(module_name)
    except ImportError as exc:
        raise SubcommandError(f"the sub-command module {module_name} does not import: {exc}") from exc
    add = getattr(module, "add_subcommand", None)
    if not callable(add):
        raise SubcommandError(f"the sub-command module {module_name} has no add_subcommand(subparsers)")
    adder: Callable[[Any], None] = add
    return adder


def _parse_trace(value: str) -> tuple[str, str]:
    bus, sep, path = value.partition("=")
    if not sep or not bus or not path:
        raise argparse.ArgumentTypeError(f"--trace wants BUS=FILE, got {value!r}")
    return bus, path


def _tcp_port(value: str) -> int:
    """A TCP port for --web: 0 (any free one) .. 65535; anything else is a usage error (exit 2)."""
    try:
        port = int(value, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--web wants a TCP port 0..65535, got {value!r}") from None
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"--web wants a TCP port 0..65535 (0: any free port), got {port}")
    return port


def _check_rig_file(path: str | None) -> None:
    """A missing or unreadable rig file is the user's to fix: say which and why (exit 2)."""
    if path is None:
        return
    try:
        with open(path, "rb") as f:
            f.read().decode()
    except IsADirectoryError:
        raise UsageError(f"rig file {path} is a directory, not a TOML file") from None
    except OSError as exc:
        raise UsageError(f"cannot read rig file {path}: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise UsageError(f"rig file {path} is not UTF-8 text (TOML): byte {exc.start} "
                         f"is 0x{exc.object[exc.start]:02X}") from None


def _check_writable(option: str, path: str) -> None:
    """The folder of an output file must exist before the rig starts, and the file must not be a folder
    (exit 2 otherwise)."""
    if Path(path).is_dir():
        raise UsageError(f"{option} {path}: is a folder; give the name of a file (in it, or elsewhere)")
    folder = Path(path).resolve().parent
    if not folder.is_dir():
        raise UsageError(f"{option} {path}: folder {folder} does not exist")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise UsageError(f"{option} {path}: folder {folder} is not writable")


def _write_ready_file(path: str, info: dict[str, Any]) -> None:
    tmp = Path(path + ".tmp")
    try:
        tmp.write_text(json.dumps(info, indent=2))
        tmp.replace(path)
    except OSError as exc:
        raise UsageError(f"--ready-file {path}: {exc.strerror or exc}") from None


def _start_web(rig: Rig, port: int, db: str | None = None) -> RigWeb:
    """The --web page: monitors on every bus, the drives' dictionaries for PDO values, --db's signals."""
    from gatewaylab.bus.signals import load_database
    from gatewaylab.devices.canopen_drive.device import Drive
    from gatewaylab.rig.runtime import RigStartError
    from gatewaylab.rig.web import RigWeb

    signals = load_database(db) if db else None
    try:
        web = RigWeb(dict(rig.buses), [p for p in rig.participants if isinstance(p, Drive)], port, signals=signals)
    except OSError as exc:      # a port in use is a run-time failure (exit 1), like a rig file's tcp_port
        raise RigStartError(f"--web {port} cannot be used on 127.0.0.1 ({exc.strerror or exc}; choose another "
                            f"port, or --web alone for any free one)") from None
    web.start()
    return web


class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM, raised where the program is (docs/cli.md "Signals"): both signals end a command
    the same way. A KeyboardInterrupt, so whatever handles Ctrl-C handles SIGTERM alike; not an
    Exception, so no participant's ``except Exception`` swallows it while a rig is built or closed."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


#: The commands that run until they are stopped: a signal is their ordinary end, exit 0 at every moment.
RUN_UNTIL_STOPPED = frozenset({"run", "monitor", "dump"})
#: The signals that stop every command alike (docs/cli.md "Signals").
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def interrupted_exit(command: str | None, signum: int) -> int:
    """The exit code of a command a signal ended: 0 for those that run until stopped, otherwise
    128 + the signal's number (130 SIGINT, 143 SIGTERM), as a shell reports a process the signal ended."""
    return 0 if command in RUN_UNTIL_STOPPED else 128 + signum


def _command_of(argv: list[str]) -> str | None:
    """The sub-command a command line names (its first word that is not an option), before parsing."""
    return next((word for word in argv if not word.startswith("-")), None)


class _Received:
    """Handlers that raise :class:`Interrupted` where the program is and keep the signal in :attr:`signum`: a
    handler's exception raised while the main thread runs a weakref callback (an import's module lock, while a
    command's modules load) is printed as "Exception ignored" and lost, so a command looks here too."""

    def __init__(self) -> None:
        self.signum: int | None = None

    def stop_at_once(self, signum: int, frame: FrameType | None) -> None:
        """The handler."""
        self.signum = signum
        raise Interrupted(signum)

    def check(self) -> None:
        """Raise :class:`Interrupted` for a signal taken whose exception was lost."""
        if self.signum is not None:
            raise Interrupted(self.signum)


class _Signals:
    """SIGINT and SIGTERM for the time of :func:`main`: raise :class:`Interrupted` where the program is
    (from the first line of ``main``, so also while the command's modules load); once ``main`` has its
    exit code (``leave``), a further signal ends the process at once with that code."""

    def __init__(self) -> None:
        self.code: int | None = None
        #: the signal taken (checked before the command runs: its exception may have been lost)
        self.received = _Received()
        self.previous: dict[int, Any] = {}
        try:
            for signum in STOP_SIGNALS:
                self.previous[signum] = signal.signal(signum, self._on_signal)
        except ValueError:          # not the main thread (main() called from a test's thread): leave them
            self.previous.clear()

    def _on_signal(self, signum: int, frame: FrameType | None) -> None:
        if self.code is not None:
            os._exit(self.code)
        self.received.stop_at_once(signum, frame)

    def leave(self, code: int, restore: bool) -> None:
        """``main`` returns ``code``: put the previous handlers back (``restore``: main() was called by
        other Python code), or make a further signal end the process with ``code`` (the command line;
        the command may have set handlers of its own meanwhile)."""
        self.code = code
        for signum, handler in self.previous.items():
            signal.signal(signum, handler if restore else self._on_signal)


def _eni_rig(args: argparse.Namespace) -> RigConfig:
    """The rig of ``run --eni``: the rig file's (its ``[ethercat]`` taking the ENI, the ESI list and the
    interface), or, without one, a rig of that segment alone. Paths given here are relative to the
    current folder."""
    from gatewaylab.rig.config import load_rig, parse_rig

    eni = str(Path(args.eni).resolve())
    if not Path(eni).is_file():
        raise UsageError(f"--eni {args.eni}: {'is a folder' if Path(eni).is_dir() else 'no such file'}")
    esi = []
    for path in args.esi or []:
        if not Path(path).exists():
            raise UsageError(f"--esi {path}: no such ESI file or folder")
        esi.append(str(Path(path).resolve()))
    if args.rig is None:
        section: dict[str, Any] = {"interface": args.interface or "gl-ecat", "eni": eni}
        if esi:
            section["esi"] = esi
        return parse_rig({"ethercat": section}, f"--eni {args.eni}")
    config = load_rig(args.rig)
    section = dict(config.ethercat or {"interface": "gl-ecat"})
    section["eni"] = eni
    if esi:
        section["esi"] = esi
    if args.interface:
        section["interface"] = args.interface
    from dataclasses import replace

    return replace(config, ethercat=section)


def cmd_run(args: argparse.Namespace) -> int:
    """``gatewaylab run RIG.toml``: start the rig (ready file, trace, web page on request) and run it until stopped."""
    from dataclasses import replace

    from gatewaylab.rig.config import load_rig
    from gatewaylab.rig.runtime import Rig

    if args.db and args.web is None:
        raise UsageError(f"--db {args.db} decodes signals on the --web page: give --web too "
                         f"(or decode them live with `gatewaylab monitor READY.json --db {args.db}`)")
    _check_rig_file(args.rig)
    from gatewaylab.bus.transport.trace import check_trace_path

    for _bus_name, path in args.trace or []:
        check_trace_path(path)
        _check_writable("--trace", path)
    if args.ready_file:
        _check_writable("--ready-file", args.ready_file)
    if (args.esi or args.interface) and not args.eni:
        raise UsageError("--esi and --interface go with --eni (the segment an ENI describes)")
    # Until the loop runs (and again while it shuts down), SIGTERM/SIGINT unwind at once: a rig stopped
    # while it starts leaves no temporary folder, socket or thread behind either.
    record = _Received()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, record.stop_at_once)
    rig: Rig | None = None
    ready_written = False
    web: RigWeb | None = None
    try:
        config = _eni_rig(args) if args.eni else load_rig(args.rig)
        if args.scenario:
            from gatewaylab.rig.scenario import load_scenario

            config = replace(config, scenario=load_scenario(args.scenario))   # replaces the rig file's steps
        if args.socketcand:
            config = replace(config, buses=tuple(replace(b, socketcand=True) for b in config.buses))
        rig = Rig(config)
        if not rig.realtime:
            print("note: the rig file asks for a simulated clock; `gatewaylab run` always runs in real time",
                  file=sys.stderr)
            rig.close()
            rig = None
            from gatewaylab.common.clock import RealTimeClock

            rig = Rig(config, clock=RealTimeClock())
        for bus_name, path in args.trace or []:
            try:
                rig.add_trace(bus_name, path)
            except OSError as exc:
                raise UsageError(f"--trace {bus_name}={path}: {exc.strerror or exc}") from None
        if args.acker:
            for bus in rig.buses.values():
                bus.attach("acker")   # hears every frame, acknowledges it, sends nothing
        if args.web is not None:
            web = _start_web(rig, args.web, args.db)    # before start(): the page sees the boot-ups
        rig.start()
        info = rig.ready_info()
        if web is not None:
            info.setdefault("web", {})["monitor"] = web.url
        #: Unix time of the rig's clock time 0: trace files and client timestamps count from it.
        info.setdefault("wall_epoch", rig.clock.wall_epoch)
        if args.ready_file:
            ready_written = True       # first: a signal during the write still removes what it left
            _write_ready_file(args.ready_file, info)
        print(f"gatewaylab rig {rig.config.source} running (pid {os.getpid()})")
        for name, bus in info["buses"].items():
            print(f"  bus {name}: {bus.get('endpoint', '(no endpoint)')}"
                  f"  ->  can.Bus(interface='gatewaylab', channel={bus.get('endpoint', '')!r})")
            if "socketcand" in bus:
                print(f"  bus {name}: socketcand 127.0.0.1:{bus['socketcand']}  ->  can.Bus(interface='socketcand', "
                      f"host='127.0.0.1', port={bus['socketcand']}, channel={name!r})")
        for key, value in info.items():
            if key == "compiled":
                print(f"  {len(value)} modules compiled" if value else "  pure Python")
            elif key == "eni":
                for row in value["slaves"]:
                    source = f"{row['file']} {row['type']} ({row['match']})" if row["file"] else (
                        f"[[device]] {row['name']}" if row["match"] == "device" else row["match"])
                    print(f"  eni slave {row['position']} {row['name']}: {source}")
            elif key not in ("pid", "buses"):
                print(f"  {key}: {json.dumps(value)}")
        sys.stdout.flush()
        record.check()      # a signal whose exception an import's weakref callback swallowed
        rig.run(until=lambda: record.signum is not None)   # its own handlers: the loop returns at its next pass
        # (docs/rig.md); ``until``: a signal taken before them whose exception was lost
    except Interrupted:
        pass
    finally:
        for signum in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signum, record.stop_at_once)   # a second signal while closing: do not wait
        try:
            if web is not None:
                web.stop()
            if rig is not None:
                rig.close()
            if ready_written:
                for path in (args.ready_file, args.ready_file + ".tmp"):
                    with contextlib.suppress(FileNotFoundError, IsADirectoryError):   # only the file it wrote
                        os.unlink(path)
        finally:
            # Exit within milliseconds: the collector's passes over every object the rig ever imported
            # would take 120-200 ms of the second SIGTERM promises; nothing left needs them.
            gc.freeze()
    print("gatewaylab rig stopped")
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    """``gatewaylab demo``: the guided tour (cli/demo.py)."""
    from gatewaylab.cli.demo import main as demo_main

    return demo_main([] if args.rig is None else [args.rig])


def cmd_rig_show(args: argparse.Namespace) -> int:
    """``gatewaylab rig show [RIG.toml]``: print the rig file (the default rig without one) to start a new one from."""
    from importlib import resources

    if args.rig is None:
        print(resources.files("gatewaylab.rig").joinpath("default.toml").read_text(), end="")
    else:
        _check_rig_file(args.rig)
        print(Path(args.rig).read_text(), end="")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The ``gatewaylab`` parser with every sub-command (those of EXTRA_SUBCOMMANDS included);
    SubcommandError when one of those modules does not load."""
    parser = argparse.ArgumentParser(
        prog="gatewaylab",
        description="Emulated industrial CAN gateways (ECAN-Lite, esd CAN-EtherCAT, maxon IDX) on virtual "
                    "CAN / CAN FD buses with simulated CANopen drives.",
        epilog="Run 'gatewaylab COMMAND --help' for the options of each command.")
    parser.add_argument("--version", action=build_info.version_action(f"gatewaylab {__version__}"))
    parser.add_argument("-v", "--verbose", dest="verbose_log", action="store_true", help="log debug messages to stderr")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    from gatewaylab.bus.transport.trace import TRACE_FORMATS

    run = sub.add_parser(
        "run", help="start a rig in real time and serve its buses to other processes",
        description="Start a rig in real time. Prints the endpoint of every bus (for "
                    "can.Bus(interface='gatewaylab', channel=ENDPOINT)) and runs until SIGINT/SIGTERM, "
                    "then shuts down cleanly and removes its endpoints.",
        epilog=RIG_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    run.add_argument("rig", nargs="?", help="rig file (TOML); default: the rig shipped in the package")
    run.add_argument("--ready-file", metavar="PATH",
                     help="write JSON {pid, buses: {NAME: {endpoint}}, ...} here once everything is up; "
                          "removed again at shutdown")
    run.add_argument("--trace", metavar="BUS=FILE", action="append", type=_parse_trace,
                     help="record BUS to FILE, streamed (flushed every 100 ms), in the format of its suffix: "
                          f"{', '.join(TRACE_FORMATS)}; may be repeated")
    run.add_argument("--web", type=_tcp_port, nargs="?", const=0, default=None, metavar="PORT",
                     help="serve a live page of the rig (node table, decoded log, drive plot) on "
                          "http://127.0.0.1:PORT/ (no PORT: any free port; listed in the ready file as "
                          "web.monitor)")
    run.add_argument("--socketcand", action="store_true",
                     help="serve every bus also over the socketcand protocol on 127.0.0.1 (a free port each, "
                          "listed in the ready file as buses.NAME.socketcand; or socketcand = true per [[bus]])")
    run.add_argument("--db", metavar="FILE", help="needs --web: a signal database (DBC, KCD, ARXML, SYM; cantools) "
                     "whose frames the page decodes into signals")
    run.add_argument("--acker", action="store_true",
                     help="attach to every bus a passive node that only acknowledges frames, so a lone "
                          "client's frames are not ACK errors (see docs/bus.md)")
    run.add_argument("--eni", metavar="PATH", help="an ENI file: the [ethercat] segment in its <Slave> order "
                     "(without a rig file: a rig of that segment alone)")
    run.add_argument("--esi", metavar="DIR", action="append", help="with --eni: an ESI file or folder for the ENI's "
                     "slaves (repeatable); slaves without one are built from the ENI alone")
    run.add_argument("--interface", metavar="NAME", help="with --eni: the segment's network interface (default: the "
                     "rig file's [ethercat] interface, else gl-ecat)")
    run.add_argument("--scenario", metavar="FILE",
                     help="fire the [[scenario]] steps of FILE (a TOML file of [[scenario]] tables, instead of the "
                          "rig file's): faults at times and milestones, see docs/faults.md 'Scenarios'")
    run.set_defaults(func=cmd_run)

    demo = sub.add_parser("demo", help="run the scripted demo (what `make demo` does)",
                          description="Start the default rig, drive real traffic on it and explain each step.")
    demo.add_argument("rig", nargs="?", help="rig file; default: the rig shipped in the package")
    demo.set_defaults(func=cmd_demo)

    show = sub.add_parser("rig", help="print a rig file (the default one without an argument)",
                          description="Print the default rig file, a starting point for your own.")
    show.add_argument("rig", nargs="?", help="rig file to print")
    show.set_defaults(func=cmd_rig_show)

    for module_name in EXTRA_SUBCOMMANDS:
        _subcommand_adder(module_name)(sub)
    return parser


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())


def main(argv: list[str] | None = None) -> int:
    """The ``gatewaylab`` command: parse ``argv`` and run the sub-command; its exit code.

    SIGINT and SIGTERM are taken first, before the sub-commands' modules load: from here on a signal
    ends every command the same way, with the code of :func:`interrupted_exit`, never a traceback
    (docs/cli.md "Signals")."""
    signals = _Signals()
    words = sys.argv[1:] if argv is None else argv
    code = 1
    try:
        try:
            code = _main(argv, signals)
        except SystemExit as exc:          # argparse: --help, --version, a usage error
            code = exc.code if isinstance(exc.code, int) else 0 if exc.code is None else 2
            raise
        except KeyboardInterrupt as exc:
            code = interrupted_exit(_command_of(words), exc.signum if isinstance(exc, Interrupted) else signal.SIGINT)
    except KeyboardInterrupt as exc:       # a second signal while the first was being handled
        code = interrupted_exit(_command_of(words), exc.signum if isinstance(exc, Interrupted) else signal.SIGINT)
    finally:
        signals.leave(code, restore=argv is not None)
    return code


def _main(argv: list[str] | None, signals: _Signals | None = None) -> int:
    try:
        parser = build_parser()
    except SubcommandError as exc:
        print(f"gatewaylab: {_one_line(exc)}", file=sys.stderr)
        return 1
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose_log else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    if signals is not None:
        signals.received.check()    # taken while the modules loaded, its exception lost
    try:
        result: int | None = args.func(args)
        return result if isinstance(result, int) else 0     # None: done (sys.exit(None) is 0 too)
    except (UsageError, ConfigError) as exc:
        print(f"gatewaylab: {_one_line(exc)}", file=sys.stderr)
        return 2
    except GatewaylabError as exc:
        print(f"gatewaylab: {_one_line(exc)}", file=sys.stderr)
        return 1
    except OSError as exc:                 # e.g. a rig's TCP port already in use
        where = f" ({exc.filename})" if exc.filename else ""
        print(f"gatewaylab: {exc.strerror or exc}{where}", file=sys.stderr)
        # docs/cli.md: a path the command names that does not exist (an output folder) is the user's to fix
        return 2 if exc.filename and exc.errno in (errno.ENOENT, errno.ENOTDIR, errno.EISDIR) else 1


if __name__ == "__main__":
    sys.exit(main())
