"""``gatewaylab monitor``: a live decoded view of a bus of a running rig (or of a recorded trace).

It joins as a listen-only client (``can.Bus(interface="gatewaylab", listen_only=True)``): it
never transmits or acknowledges, so watching changes nothing on the bus. The decoding is
:class:`~.monitor.BusMonitor`; this module only reads frames and draws: a node table and a
scrolling log with rich, one line per event with ``--plain``, one JSON object per event with
``--json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import deque
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import can

from ..bus.frame import CanFrame
from ..common.endpoint import EndpointError, bus_endpoint
from ..common.errors import GatewaylabError
from ..od import ObjectDictionary
from ..od.eds import import_eds
from .monitor import BusMonitor, MonitorEvent

_DESCRIPTION = """\
Watch a bus of a running rig, decoded: a node table (NMT state, heartbeat age, CiA 402 state,
mode, position/velocity from TPDOs, last EMCY) and a log with SDO transfers reassembled into one
line each, PDOs with mapped values, NMT, SYNC, TIME, heartbeats, EMCY and LSS (Fastscan as a
bisection). TARGET is the bus endpoint `gatewaylab run` printed or its ready file (the ready file
also gives the dictionaries of the rig's drives). The monitor is listen-only: it never sends or
acknowledges a frame.

examples:
  gatewaylab monitor ready.json                       # live view (q or Ctrl-C to leave)
  gatewaylab monitor ready.json --plain               # one line per event, for pipes
  gatewaylab monitor unix:/tmp/gl/can0.sock --json --eds 2=drive.eds
  gatewaylab monitor --replay trace.asc --plain       # decode a recorded trace
"""


def _eds_arg(text: str) -> tuple[int, Path]:
    node, sep, path = text.partition("=")
    try:
        node_id = int(node, 0)
    except ValueError:
        node_id = -1
    if not sep or not 1 <= node_id <= 127 or not path:
        raise argparse.ArgumentTypeError(f"--eds wants NODE=FILE with NODE 1..127, got {text!r}")
    return node_id, Path(path)


def _dictionaries(args: argparse.Namespace) -> dict[int, ObjectDictionary]:
    """Dictionaries by node-ID: the rig's drives (ready file "canopen" key), then --eds overrides."""
    out: dict[int, ObjectDictionary] = {}
    target = Path(args.target)
    if not args.replay and target.is_file():
        try:
            info = json.loads(target.read_text())
        except (OSError, ValueError):
            info = {}
        for node in ((info.get("canopen", {}) or {}).get(args.bus, {}) or {}).values():
            node_id, eds = node.get("node_id"), node.get("eds")
            if isinstance(node_id, int) and isinstance(eds, str) and Path(eds).is_file():
                out[node_id] = import_eds(Path(eds).read_text(), node_id)
    for node_id, path in args.eds or ():
        try:
            out[node_id] = import_eds(path.read_text(), node_id)
        except OSError as exc:
            raise GatewaylabError(f"cannot read {path}: {exc.strerror}") from None
    return out


class EthercatWatcher:
    """The EtherCAT side of a rig as the monitor shows it: the AL state of each EtherCAT device, asked
    twice a second from the rig's control endpoint (ready file "control", request "ethercat-states",
    docs/faults.md); each change is one log event ("EtherCAT ecan1: PREOP -> OP")."""

    def __init__(self, endpoint: str, period: float = 0.5) -> None:
        self.endpoint = endpoint
        self.period = period
        self.states: dict[str, str] = {}
        self._next = 0.0
        self.failed: str | None = None

    def _ask(self) -> dict[str, Any]:
        import socket

        from ..common.endpoint import EndpointKind, parse_endpoint
        ep = parse_endpoint(self.endpoint, bare_path=EndpointKind.UNIX)
        if ep.kind is EndpointKind.UNIX:
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            sock.settimeout(2.0)
            sock.connect(ep.path)
        else:
            sock = socket.create_connection((ep.host, ep.port), timeout=2.0)
        with sock, sock.makefile("rwb") as f:
            f.write(b'{"fault": "ethercat-states"}\n')
            f.flush()
            answer: dict[str, Any] = json.loads(f.readline() or b"{}")
        return answer

    def poll(self, now: float) -> list[MonitorEvent]:
        """Events for the devices whose AL state changed since the last poll (none before it is due)."""
        if self.failed is not None or now < self._next:
            return []
        self._next = now + self.period
        try:
            answer = self._ask()
        except (OSError, ValueError, EndpointError) as exc:
            self.failed = str(exc)
            return []
        events = []
        for name, st in (answer.get("devices") or {}).items():
            text = st.get("state", "?") + (f", AL status code 0x{st['code']:04X}" if st.get("error") else "")
            old = self.states.get(name)
            if old != text:
                self.states[name] = text
                events.append(MonitorEvent(now, "ethercat", f"EtherCAT {name}: {old + ' -> ' if old else ''}{text}",
                                           None, {"device": name, **st}))
        return events


def _frames_live(bus: can.BusABC, until: float | None) -> Iterator[tuple[CanFrame, float] | None]:
    """Frames as they come (None every 0.2 s without one, so the view can redraw)."""
    while until is None or time.monotonic() < until:
        msg = bus.recv(0.2)
        if msg is None or msg.is_error_frame:
            yield None
            continue
        yield CanFrame.from_message(msg), msg.timestamp


def _frames_replay(path: Path) -> Iterator[tuple[CanFrame, float] | None]:
    for msg in can.LogReader(str(path)):
        if not msg.is_error_frame:
            yield CanFrame.from_message(msg), msg.timestamp


def _age(t: float | None, now: float) -> str:
    return "" if t is None else f"{now - t:.1f} s"


class _Screen:
    """The rich live view: header, node table, the last lines of the log."""

    def __init__(self, monitor: BusMonitor, title: str, lines: int = 18) -> None:
        from rich.console import Console  # imported here: --plain/--json do not need rich
        from rich.live import Live
        self.monitor = monitor
        self.title = title
        self.log: deque[str] = deque(maxlen=lines)
        self.live = Live(console=Console(), auto_refresh=False, screen=False)
        self._last = 0.0

    def __enter__(self) -> _Screen:
        self.live.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        self.live.__exit__(None, None, None)

    def add(self, event: MonitorEvent) -> None:
        self.log.append(event.text)

    def draw(self, now: float, force: bool = False) -> None:
        if not force and time.monotonic() - self._last < 0.25:
            return
        self._last = time.monotonic()
        from rich.console import Group
        from rich.panel import Panel
        from rich.table import Table
        m = self.monitor
        table = Table(expand=True, title=f"{self.title}   load {m.load_percent():.1f} %   "
                                         f"{m.frames_per_second():.0f} frames/s   {m.frames} frames")
        for col in ("node", "NMT", "heartbeat", "CiA 402", "statusword", "mode", "position", "velocity",
                    "last EMCY"):
            table.add_column(col)
        for node_id in sorted(m.nodes):
            v = m.nodes[node_id]
            table.add_row(str(node_id), v.nmt, _age(v.heartbeat_t, now), v.cia402_state,
                          "" if v.statusword is None else f"0x{v.statusword:04X}", v.mode_name,
                          "" if v.position is None else str(v.position),
                          "" if v.velocity is None else str(v.velocity), v.emcy or "")
        self.live.update(Group(table, Panel("\n".join(self.log) or "(waiting for frames)", title="log")),
                         refresh=True)


def _watcher(args: argparse.Namespace) -> EthercatWatcher | None:
    """An EtherCAT watcher when TARGET is the ready file of a rig with a control endpoint."""
    target = Path(args.target)
    if args.replay or not target.is_file():
        return None
    try:
        control = json.loads(target.read_text()).get("control")
    except (OSError, ValueError):
        return None
    return EthercatWatcher(control) if isinstance(control, str) else None


def cmd_monitor(args: argparse.Namespace) -> int:
    """``gatewaylab monitor TARGET``: decode frames until Ctrl-C, ``--duration`` or the trace's end."""
    bus: can.BusABC | None = None
    try:
        dictionaries = _dictionaries(args)
        if args.replay:
            path = Path(args.target)
            if not path.is_file():
                raise GatewaylabError(f"{path}: no such trace file")
            frames = _frames_replay(path)
            monitor = BusMonitor(dictionaries, args.bitrate, args.data_bitrate)
            title = str(path)
        else:
            endpoint = bus_endpoint(args.target, args.bus)
            try:
                bus = can.Bus(interface="gatewaylab", channel=endpoint, listen_only=True, name="gatewaylab-monitor")
            except (can.CanError, OSError) as exc:
                print(f"error: cannot open bus {endpoint}: {exc}", file=sys.stderr)
                return 1
            until = time.monotonic() + args.duration if args.duration is not None else None
            frames = _frames_live(bus, until)
            monitor = BusMonitor(dictionaries, getattr(bus, "bitrate", args.bitrate),
                                 getattr(bus, "data_bitrate", None))
            title = f"{args.bus} ({endpoint})"
            if args.json or args.plain:
                print(f"monitoring {title}, listen-only", file=sys.stderr, flush=True)
        watcher = _watcher(args)
        if args.json or args.plain:
            _print_events(monitor, frames, args.json, watcher)
        else:
            with _Screen(monitor, title) as screen:
                for item in frames:
                    for event in watcher.poll(time.time()) if watcher is not None else []:
                        screen.add(event)
                    if item is not None:
                        for event in monitor.feed(*item):
                            screen.add(event)
                    screen.draw(time.time() if not args.replay else (item[1] if item else 0.0))
                screen.draw(time.time(), force=True)
    except KeyboardInterrupt:
        return 0
    except (EndpointError, GatewaylabError, can.CanError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2 if isinstance(exc, EndpointError) else 1
    finally:
        if bus is not None:
            bus.shutdown()
    return 0


def _print_events(monitor: BusMonitor, frames: Iterator[tuple[CanFrame, float] | None], as_json: bool,
                  watcher: EthercatWatcher | None = None) -> None:
    out = sys.stdout
    for item in frames:
        events = watcher.poll(time.time()) if watcher is not None else []
        if item is not None:
            events += monitor.feed(*item)
        elif not events:
            out.flush()
            continue
        for event in events:
            line: Any = json.dumps(event.to_json()) if as_json else f"{event.t:.6f}  {event.text}"
            out.write(line + "\n")
    out.flush()


def add_subcommand(subparsers: Any) -> None:
    """Add ``monitor`` to the gatewaylab CLI."""
    p = subparsers.add_parser("monitor", help="live decoded view of a rig's bus (listen-only)",
                              description=_DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("target", metavar="TARGET", help="bus endpoint, ready file, or with --replay a trace file")
    p.add_argument("--bus", default="can0", help="bus name in the ready file (default can0)")
    p.add_argument("--eds", type=_eds_arg, action="append", metavar="NODE=FILE",
                   help="the dictionary of a node, for PDO values and object names (repeatable)")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--plain", action="store_true", help="one line per event (for pipes)")
    mode.add_argument("--json", action="store_true", help="one JSON object per event (for scripts)")
    p.add_argument("--replay", action="store_true", help="TARGET is a trace file (.asc, .log, .blf, .csv, ...)")
    p.add_argument("--bitrate", type=int, default=1_000_000, help="bit rate for the load figure of a replay")
    p.add_argument("--data-bitrate", type=int, default=None, help="CAN FD data bit rate of a replay")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds")
    p.set_defaults(func=cmd_monitor)
