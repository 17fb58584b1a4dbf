"""``gatewaylab monitor``: a live decoded view of a bus of a running rig (or of a recorded trace).

It joins as a listen-only client (``can.Bus(interface="gatewaylab", listen_only=True)``): it
never transmits or acknowledges, so watching changes nothing on the bus. The decoding is
:class:`~.monitor.BusMonitor`; this module only reads frames and draws: a node table and a
scrolling log with rich, one line per event with ``--plain``, one JSON object per event with
``--json``.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import sys
import time
from collections import deque
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import can

from gatewaylab.bus.candump import (
    TIMESTAMP_MODES,
    CandumpSyntaxError,
    FilterSet,
    IdTable,
    Timestamps,
    line,
    long_error_frame,
    long_frame,
    parse_filters,
)
from gatewaylab.bus.errorframe import CAN_ERR_MASK, ErrorFrame, describe
from gatewaylab.bus.frame import CanFrame
from gatewaylab.bus.signals import SignalDecoder, load_database
from gatewaylab.bus.transport.trace import TraceError, read_trace
from gatewaylab.bus.transport.trace_window import TimeWindow
from gatewaylab.canopen.monitor import BusMonitor, ControllerWatch, MonitorEvent
from gatewaylab.cli.monitor_faults import FaultWatch
from gatewaylab.cli.monitor_order import TimeOrder, sender_node
from gatewaylab.cli.monitor_scenario import ScenarioSeen
from gatewaylab.cli.target import USAGE, bus_target, exit_code, open_endpoint
from gatewaylab.cli.terminal import QuitKey
from gatewaylab.common.endpoint import EndpointError
from gatewaylab.common.errors import ConfigError, GatewaylabError
from gatewaylab.od import ObjectDictionary
from gatewaylab.od.eds import import_eds

__all__ = ["HOLD", "HOLD_WATCHED", "CanWatcher", "EthercatWatcher", "Item", "add_subcommand", "cmd_monitor"]


_DESCRIPTION = """\
Watch a bus of a running rig, decoded: a node table (NMT state, heartbeat age, CiA 402 state,
mode, position/velocity from TPDOs, last EMCY) and a log with SDO transfers reassembled into one
line each, PDOs with mapped values, NMT, SYNC, TIME, heartbeats, EMCY and LSS (Fastscan as a
bisection); error frames, controller state changes (bus-off, recovery, unplugged) and nodes that
went silent. Identifiers that are not CANopen in context are shown raw. TARGET is the bus endpoint
`gatewaylab run` printed or its ready file (the ready file also gives the rig's nodes, their
dictionaries and the control endpoint). The monitor is listen-only: it never sends or acknowledges
a frame. --raw (or `gatewaylab dump`) prints frames as candump does, --viewer a table per id as
can.viewer; see docs/monitor.md.

examples:
  gatewaylab monitor ready.json                       # live view (q or Ctrl-C to leave)
  gatewaylab monitor ready.json --plain               # one line per event, for pipes
  gatewaylab monitor unix:/tmp/gl/can0.sock --json --eds 2=drive.eds
  gatewaylab monitor --replay trace.pcapng --plain    # decode a recorded trace
  gatewaylab monitor ready.json --raw -t d -e -f 700:780   # candump: heartbeats, error frames
  gatewaylab monitor ready.json --viewer              # can.viewer: count, period, data per id
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


class _ControlPoller:
    """Asks the rig's control endpoint (ready file "control") one status request every ``period``."""

    request: str = ""

    def __init__(self, endpoint: str, period: float = 0.5) -> None:
        self.endpoint = endpoint
        self.period = period
        self._next = 0.0
        self.failed: str | None = None

    def _ask(self) -> dict[str, Any]:
        from gatewaylab.common.ask import ask, endpoint_address
        from gatewaylab.common.endpoint import EndpointKind, parse_endpoint

        ep = parse_endpoint(self.endpoint, bare_path=EndpointKind.UNIX)
        answer: dict[str, Any] = json.loads(ask(endpoint_address(ep), {"fault": self.request}, 2.0) or b"{}")
        return answer

    def poll(self, now: float) -> list[MonitorEvent]:
        """Events for what changed since the last poll (none before it is due)."""
        if self.failed is not None or now < self._next:
            return []
        self._next = now + self.period
        try:
            answer = self._ask()
        except (OSError, ValueError, EndpointError) as exc:
            self.failed = str(exc)
            return []
        if answer.get("error"):             # a rig without this request
            self.failed = str(answer["error"])
            return []
        return self.changes(answer, now)

    def changes(self, answer: dict[str, Any], now: float) -> list[MonitorEvent]:
        """What changed since the last answer, as monitor events (each watcher reads its part of the answer)."""
        raise NotImplementedError

    def saw(self, frame: CanFrame, t: float) -> None:
        """A frame of the bus at ``t`` (what a watcher may date its events by)."""


class EthercatWatcher(_ControlPoller):
    """The EtherCAT side of a rig as the monitor shows it: the AL state of each EtherCAT device, asked
    twice a second from the rig's control endpoint (request "ethercat-states", docs/faults.md); each
    change is one log event ("EtherCAT ecan1: PREOP -> OP"), and so is each EtherCAT fault starting and
    ending (the answer's "faults", ``monitor_faults.py``)."""

    request = "ethercat-states"

    def __init__(self, endpoint: str, period: float = 0.5) -> None:
        super().__init__(endpoint, period)
        self.states: dict[str, str] = {}
        self.faults = FaultWatch()
        self.scenario = ScenarioSeen()    # the steps of a [[scenario]] as they fire

    def changes(self, answer: dict[str, Any], now: float) -> list[MonitorEvent]:
        """What changed in the rig's device states since the last answer, as monitor events."""
        events = []
        for name, st in (answer.get("devices") or {}).items():
            text = st.get("state", "?") + (f", AL status code 0x{st['code']:04X}" if st.get("error") else "")
            old = self.states.get(name)
            if old != text:
                self.states[name] = text
                events.append(MonitorEvent(now, "ethercat", f"EtherCAT {name}: {old + ' -> ' if old else ''}{text}",
                                           None, {"device": name, **st}))
        return events + self.faults.changes(answer.get("faults"), now) + self.scenario.changes(answer, now)


class CanWatcher(_ControlPoller):
    """The CAN controllers of the rig's devices on one bus (request "can-states", docs/faults.md): a
    listen-only monitor cannot see another node's error counters, bus-off or unplugged cable, the
    rig can. Each change is one ``can`` event (:class:`~.monitor.ControllerWatch`): "CAN axis2:
    went bus-off and recovered", "CAN axis3: unplugged, left the bus"."""

    request = "can-states"

    def __init__(self, endpoint: str, bus: str, period: float = 0.5, nodes: dict[str, int] | None = None) -> None:
        super().__init__(endpoint, period)
        self.bus = bus
        self.watch = ControllerWatch()
        #: controller (participant) name -> its CANopen node-ID (the ready file's "canopen" list)
        self.nodes = dict(nodes or {})
        self._asked = 0.0                       # when the last answer was asked for
        self._first: dict[int, float] = {}      # node-ID -> its first frame after that
        self._latest = 0.0                      # the newest frame seen
        self._looked = False                    # an answer came before
        #: events of controllers that came back, with their node and the time they were still away:
        #: held until every frame before them has been read (frames come in time order)
        self._held: list[tuple[MonitorEvent, int, float]] = []

    def saw(self, frame: CanFrame, t: float) -> None:
        """Date the held events of a node that came back by the first frame it sent."""
        self._latest = max(self._latest, t)
        node = sender_node(frame)
        if node is None:
            return
        if t > self._asked:
            self._first.setdefault(node, t)
        for k, (event, held_node, away) in enumerate(self._held):
            if held_node == node and away < t < event.t:
                self._held[k] = (replace(event, t=t - 1e-6), held_node, away)

    def poll(self, now: float) -> list[MonitorEvent]:
        """The controllers' news: what the rig answered, and the held events now dated."""
        events = super().poll(now)
        return self.release(now) + events

    def release(self, now: float) -> list[MonitorEvent]:
        """The held events every frame before which has been read (or that waited two periods)."""
        ready = [h for h in self._held if h[0].t <= self._latest or h[0].t + 2 * self.period <= now]
        self._held = [h for h in self._held if h not in ready]
        return [h[0] for h in ready]

    def changes(self, answer: dict[str, Any], now: float) -> list[MonitorEvent]:
        """What changed on the watched bus since the last answer, as monitor events. A controller that
        came back (plugged in again, recovered from bus-off, joined) sent nothing before it did: its
        event is dated just before the first frame its node sent since the last answer, if one came."""
        before, looked = dict(self.watch.states), self._looked
        self._looked = True
        events = self.watch.update((answer.get("buses") or {}).get(self.bus) or {}, now)
        first, away, self._first, self._asked = self._first, self._asked, {}, now
        out = []
        for event in events:
            name = str(event.fields.get("controller"))
            old = before.get(name)
            now_on = event.fields.get("connected", True) and event.fields.get("state") != "bus-off"
            back = now_on and (not old.get("connected", True) or old.get("state") == "bus-off") if old is not None \
                else now_on and looked            # joined the bus (the first answer only says how things are)
            node = self.nodes.get(name)
            if not back or node is None:
                out.append(event)
                continue
            seen = first.get(node)
            if seen is not None and seen < event.t:
                event = replace(event, t=seen - 1e-6)
            self._held.append((event, node, away))
        return out


def _error_of(msg: can.Message) -> ErrorFrame:
    return ErrorFrame(msg.arbitration_id & CAN_ERR_MASK, bytes(msg.data or b"").ljust(8, b"\0")[:8])


Item = tuple[CanFrame | ErrorFrame, float] | None


def _frames_live(bus: can.BusABC, until: float | None, keys: QuitKey | None = None) -> Iterator[Item]:
    """Frames and error frames as they come (None every 0.2 s without one, so the view can redraw),
    until ``until`` (monotonic) or ``q`` on the terminal (looked at every 0.1 s at most)."""
    look = 0.0
    while True:
        now = time.monotonic()
        if until is not None and now >= until:
            return
        if keys is not None and now >= look:
            look = now + 0.1
            if keys.poll():
                return
        msg = bus.recv(0.2)
        if msg is None:
            yield None
        elif msg.is_error_frame:
            yield _error_of(msg), msg.timestamp
        else:
            yield CanFrame.from_message(msg), msg.timestamp


def _frames_replay(path: Path) -> Iterator[Item]:
    yield from read_trace(path)


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
                                         f"{m.frames_per_second():.0f} frames/s   {m.frames} frames   "
                                         f"{m.error_frames} error frames   controller {m.bus_state}")
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


def _control(args: argparse.Namespace) -> str | None:
    """The rig's control endpoint when TARGET is its ready file."""
    target = Path(args.target)
    if args.replay or not target.is_file():
        return None
    try:
        control = json.loads(target.read_text()).get("control")
    except (OSError, ValueError):
        return None
    return control if isinstance(control, str) else None


def _watchers(args: argparse.Namespace) -> list[_ControlPoller]:
    """The EtherCAT and CAN controller watchers when TARGET is the ready file of a rig."""
    control = _control(args)
    return [] if control is None else [EthercatWatcher(control), CanWatcher(control, args.bus, nodes=_node_names(args))]


def _node_names(args: argparse.Namespace) -> dict[str, int]:
    """The rig's CANopen devices on the bus (ready file "canopen"): name -> node-ID."""
    target = Path(args.target)
    if args.replay or not target.is_file():
        return {}
    try:
        info = json.loads(target.read_text())
    except (OSError, ValueError):
        return {}
    nodes = ((info.get("canopen", {}) or {}).get(args.bus, {}) or {})
    return {name: n["node_id"] for name, n in nodes.items()
            if isinstance(n, dict) and isinstance(n.get("node_id"), int)}


def _known_nodes(args: argparse.Namespace) -> list[int]:
    """The node-IDs of the rig's CANopen devices on the bus (ready file), listed before they speak."""
    return list(_node_names(args).values())


def _filters(args: argparse.Namespace) -> FilterSet:
    fs = parse_filters(args.filter or [])
    if args.errors and not fs.err_mask:
        fs = FilterSet(fs.filters, fs.join, CAN_ERR_MASK)    # -e: every error class
    return fs


def cmd_monitor(args: argparse.Namespace) -> int:
    """``gatewaylab monitor TARGET`` / ``gatewaylab dump TARGET``: until Ctrl-C (or SIGTERM), ``q`` on
    the terminal, ``--duration``, ``-n`` frames or the trace's end."""
    with QuitKey(enabled=not args.replay) as keys:
        return _monitor(args, keys)


def _monitor(args: argparse.Namespace, keys: QuitKey) -> int:
    bus: can.BusABC | None = None
    try:
        filters = _filters(args)
        stamps = Timestamps(args.timestamp)
        window = TimeWindow.parse(args.window_from, args.window_to)
        if window and not args.replay:
            raise ConfigError("--from / --to select a time window of a trace: they need --replay")
        if args.replay:
            path = Path(args.target)
            if not path.is_file():
                raise TraceError(f"{path}: no such trace file")
            frames: Iterator[Item] = _frames_replay(path)
            bitrate, data_bitrate = args.bitrate, args.data_bitrate
            title = str(path)
            frames, base = _replay_base(frames, args.absolute)
            frames = window.select(frames)          # after the time base: it is the whole trace's
        else:
            endpoint = bus_target(args.target, args.bus)      # exit 2: malformed, no such file (docs/cli.md)
            bus = open_endpoint(endpoint, listen_only=True, name="gatewaylab-monitor")   # exit 1: not reachable
            until = time.monotonic() + args.duration if args.duration is not None else None
            frames = _frames_live(bus, until, keys)
            bitrate, data_bitrate = getattr(bus, "bitrate", args.bitrate), getattr(bus, "data_bitrate", None)
            title = f"{args.bus} ({endpoint})"
            epoch = getattr(bus, "wall_epoch", None)
            base = (0.0, "Unix time") if args.absolute or not epoch else (
                float(epoch), f"seconds since the rig started (its time 0 is Unix time {epoch:.6f}; --absolute "
                              "for Unix time)")
        if args.count is not None:
            frames = _first(frames, args.count)
        signals = load_database(args.db) if args.db else None
        if args.raw:
            _print_raw(frames, filters, stamps, args.bus, args.errors, signals)
            return 0
        if args.viewer:
            _viewer(frames, filters, title)
            return 0
        monitor = BusMonitor(_dictionaries(args), bitrate, data_bitrate, known=_known_nodes(args), signals=signals)
        watchers = _watchers(args)
        if args.json or args.plain:
            if not args.replay:
                leave = "; q or Ctrl-C leaves" if keys.active else ""
                print(f"monitoring {title}, listen-only; times: {base[1]}{leave}", file=sys.stderr, flush=True)
            else:
                print(f"replaying {title}; times: {base[1]}", file=sys.stderr, flush=True)
            _print_events(monitor, frames, filters, args.json, watchers, stamps if args.timestamp else None,
                          base[0], live=not args.replay)
        else:
            order = TimeOrder(_hold(not args.replay, watchers))
            with _Screen(monitor, title) as screen:
                try:
                    for item in frames:
                        order.add(_decode(monitor, item, filters, watchers, live=not args.replay))
                        for event in order.due(time.time() if not args.replay else math.inf):
                            screen.add(event)
                        screen.draw(time.time() if not args.replay else (item[1] if item else 0.0))
                finally:
                    for event in order.flush():
                        screen.add(event)
                    screen.draw(time.time(), force=True)
    except KeyboardInterrupt:
        return 0
    except BrokenPipeError:
        _quiet_stdout()
        return 0
    except (CandumpSyntaxError, ConfigError) as exc:
        print(f"gatewaylab: {exc}", file=sys.stderr)
        return 2
    except (EndpointError, GatewaylabError, can.CanError, ValueError) as exc:
        print(f"gatewaylab: {exc}", file=sys.stderr)
        return USAGE if isinstance(exc, TraceError) else exit_code(exc)
    finally:
        if bus is not None:
            bus.shutdown()
    return 0


def _quiet_stdout() -> None:
    """stdout went away (``| head``): no second error when Python flushes it at exit."""
    import os
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


def _first(frames: Iterator[Item], count: int) -> Iterator[Item]:
    """candump -n: stop after ``count`` frames (error frames included)."""
    seen = 0
    for item in frames:
        yield item
        if item is not None:
            seen += 1
            if seen >= count:
                return


def _decode(monitor: BusMonitor, item: Item, filters: FilterSet, watchers: list[_ControlPoller],
            live: bool) -> list[MonitorEvent]:
    """The events one item of the bus brings: the watchers' news, the frame's decoding (shown when it
    passes the filters; decoded anyway, so transfers stay whole), error frames, silent nodes."""
    events: list[MonitorEvent] = []
    if item is not None:
        obj, t = item
        if isinstance(obj, ErrorFrame):
            events += monitor.feed_error(obj, t)
        else:
            decoded = monitor.feed(obj, t)
            for w in watchers:
                w.saw(obj, t)
            if filters.accepts(obj):
                events += decoded
        events += monitor.tick(t)
    elif live:
        events += monitor.tick(time.time())
    for w in watchers:          # after the frame: a controller's news is dated by the frames before it
        events += w.poll(time.time())
    return events


def _replay_base(frames: Iterator[Item], absolute: bool) -> tuple[Iterator[Item], tuple[float, str]]:
    """The time base of a replay: a trace in Unix time (.log, .pcap, ...) counts from its first frame
    (the rig's start is not in the file); one already relative to the rig's start (.asc) stays."""
    first = next(frames, None)
    rest: Iterator[Item] = itertools.chain([first], frames) if first is not None else iter(())
    if absolute or first is None or first[1] < 1e8:
        return rest, (0.0, "as the trace has them" + ("" if absolute else " (seconds since the rig started)"))
    return rest, (first[1], f"seconds since the trace's first frame (Unix time {first[1]:.6f}; --absolute for "
                            "Unix time)")


#: How long the live decoded log holds an event back, to give out the frames and the rig's news in time
#: order (cli/monitor_order.py): a frame still on its way when the rig answered a poll ...
HOLD = 0.1
#: ... and, with the rig's controllers watched, a whole poll period more: a controller that came back is
#: dated before the first frame it sent since the last poll (its boot-up follows "plugged in again").
HOLD_WATCHED = 0.75


def _hold(live: bool, watchers: list[_ControlPoller]) -> float:
    """The reorder horizon: none for a replay (one source, in order), HOLD or HOLD_WATCHED live."""
    if not live:
        return 0.0
    return HOLD_WATCHED if watchers else HOLD


def _print_events(monitor: BusMonitor, frames: Iterator[Item], filters: FilterSet, as_json: bool,
                  watchers: list[_ControlPoller], stamps: Timestamps | None, base: float = 0.0,
                  live: bool = True) -> None:
    """One line (or JSON object) per event, in time order; times count from ``base`` (see the stderr
    header). Ended by a signal, it still prints what it held back."""
    out = sys.stdout
    order = TimeOrder(_hold(live, watchers))

    def write(events: list[MonitorEvent]) -> None:
        for event in events:
            if as_json:
                text = json.dumps({**event.to_json(), "t": round(event.t - base, 6)})
            elif stamps is not None:
                text = f"{stamps.text(event.t)} {event.text}"
            else:
                text = f"{event.t - base:.6f}  {event.text}"
            out.write(text + "\n")

    try:
        for item in frames:
            order.add(_decode(monitor, item, filters, watchers, live=True))
            events = order.due(time.time() if live else math.inf)
            if not events:
                out.flush()
                continue
            write(events)
    except BrokenPipeError:
        raise
    except BaseException:           # Ctrl-C, SIGTERM: what was held back still comes out
        write(order.flush())
        out.flush()
        raise
    write(order.flush())
    out.flush()


def _print_raw(frames: Iterator[Item], filters: FilterSet, stamps: Timestamps, channel: str,
               explain_errors: bool, signals: SignalDecoder | None = None) -> None:
    """candump: one line per frame (``-e``: error frames, decoded on the lines below); with ``--db``
    the frames the database defines get `` :: Message(Signal: value unit, ...)``, as
    ``candump | cantools decode --single-line`` prints them."""
    out = sys.stdout
    indent = False
    for item in frames:
        if item is None:
            out.flush()
            continue
        obj, t = item
        if isinstance(obj, ErrorFrame):
            if not filters.accepts_error(obj):
                continue
            body = long_error_frame(obj)
            if explain_errors:
                body += "\n\t" + describe(obj)
        else:
            if not filters.accepts(obj):
                continue
            indent = indent or obj.extended     # candump indents 11-bit ids once it saw a 29-bit one
            body = long_frame(obj, indent_sff=indent)
            message = signals.decode(obj) if signals is not None else None
            if message is not None and message.error:
                body += f" :: {message.error}"          # what cantools decode prints for it
            elif message is not None:
                body += f" :: {message.name}(" + ", ".join(
                    f"{n}: {repr(v) if isinstance(v, str) else v}" + (f" {u}" if u else "")
                    for n, v, u in message.signals) + ")"
        out.write(line(body, channel, stamps.text(t)) + "\n")
    out.flush()


def _viewer(frames: Iterator[Item], filters: FilterSet, title: str) -> None:
    """can.viewer: a table of identifiers, redrawn on a terminal, printed once at the end otherwise."""
    table = IdTable()
    errors = 0
    last = 0.0
    live = None
    if sys.stdout.isatty():
        from rich.live import Live
        live = Live(auto_refresh=False)
        live.__enter__()
    try:
        for item in frames:
            if item is not None:
                obj, t = item
                last = max(last, t)
                if isinstance(obj, ErrorFrame):
                    errors += 1
                elif filters.accepts(obj):
                    table.feed(obj, t)
            if live is not None:
                from rich.text import Text
                live.update(Text("\n".join([f"{title}   {errors} error frames", *table.lines(time.time())])),
                            refresh=True)
    finally:
        if live is not None:
            live.__exit__(None, None, None)
        else:          # also when the rig went away: the table so far
            now = time.time() if last > 1e9 else last
            print("\n".join([f"{title}   {errors} error frames", *table.lines(now)]), flush=True)


_COMMON_EPILOG = """filters (-f, can-utils' candump syntax, comma separated or repeated):
  123:7FF      id & mask == 123 & mask (11-bit 0x123, also as 29-bit id and remote frame)
  123:C00007FF only the 11-bit data frame 0x123;  12345678:DFFFFFFF only the 29-bit id 12345678
  400~7F0      everything but 0x400..0x40F;  #FFFFFFFF error frames of every class;  j  all must match
"""


def _add_common(p: argparse.ArgumentParser) -> None:
    p.add_argument("target", metavar="TARGET", help="bus endpoint, ready file, or with --replay a trace file")
    p.add_argument("--bus", default="can0", help="bus name in the ready file (default can0)")
    p.add_argument("-f", "--filter", action="append", metavar="ID:MASK",
                   help="candump filter: ID:MASK, ID~MASK (inverted), #ERRMASK, j (join); repeatable")
    p.add_argument("-e", "--errors", action="store_true",
                   help="error frames too, decoded as candump -e does (error frames are shown in the decoded "
                        "view always)")
    p.add_argument("-t", "--timestamp", choices=TIMESTAMP_MODES, default=None,
                   help="candump timestamps: a absolute, A absolute with date, d delta, z from the first frame")
    p.add_argument("-n", "--count", type=int, default=None, metavar="N", help="stop after N frames")
    p.add_argument("--absolute", action="store_true",
                   help="decoded view: Unix times instead of seconds since the rig started (stderr says which)")
    p.add_argument("--replay", action="store_true",
                   help="TARGET is a trace file the rig wrote (.asc .blf .csv .log .trc .txt .pcap .pcapng)")
    p.add_argument("--from", dest="window_from", metavar="T|+S", default=None,
                   help="--replay: from T seconds of trace time (the decoded view's times), or +S seconds after "
                        "the first frame (docs/cli.md)")
    p.add_argument("--to", dest="window_to", metavar="T|+D", default=None,
                   help="--replay: up to T seconds of trace time, or +D seconds after --from")
    p.add_argument("--bitrate", type=int, default=1_000_000, help="bit rate for the load figure of a replay")
    p.add_argument("--data-bitrate", type=int, default=None, help="CAN FD data bit rate of a replay")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds")
    p.add_argument("--eds", type=_eds_arg, action="append", metavar="NODE=FILE",
                   help="the dictionary of a node, for PDO values and object names (repeatable)")
    p.add_argument("--db", metavar="FILE", help="a signal database (DBC, KCD, ARXML, SYM; read by cantools): "
                   "the frames it defines are decoded into signals")


def add_subcommand(subparsers: Any) -> None:
    """Add ``monitor`` and ``dump`` (the raw monitor, like candump) to the gatewaylab CLI."""
    p = subparsers.add_parser("monitor", help="live decoded view of a rig's bus (listen-only)",
                              description=_DESCRIPTION, epilog=_COMMON_EPILOG,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    _add_common(p)
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--plain", action="store_true", help="one line per event (for pipes)")
    mode.add_argument("--json", action="store_true", help="one JSON object per event (for scripts)")
    mode.add_argument("--raw", action="store_true", help="one line per frame as candump prints it")
    mode.add_argument("--viewer", action="store_true", help="a table per identifier (count, period, data), "
                      "as python-can's can.viewer")
    p.set_defaults(func=cmd_monitor)
    d = subparsers.add_parser("dump", help="candump of a rig's bus (= monitor --raw)",
                              description="One line per frame as can-utils' candump prints it (listen-only). "
                                          "The same as `gatewaylab monitor --raw`; q (on a terminal) or Ctrl-C "
                                          "leaves.\n\nexamples:\n"
                                          "  gatewaylab dump ready.json -t z -e\n"
                                          "  gatewaylab dump unix:/tmp/gl/can0.sock -f 700:780\n"
                                          "  gatewaylab dump --replay run.pcapng -t a",
                              epilog=_COMMON_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    _add_common(d)
    d.set_defaults(func=cmd_monitor, raw=True, viewer=False, plain=False, json=False)
