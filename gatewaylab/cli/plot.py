"""``gatewaylab plot TRACE``: a picture of a recorded bus (matplotlib, PNG or SVG).

Bus load over time, and for each drive the values the monitor decodes from its PDOs and SDO
transfers: position, velocity (or, where no 0x606C was carried, the derivative of position),
statusword bits and mode of operation. The decoding is :class:`~.monitor.BusMonitor`'s (the one
``gatewaylab monitor`` uses); every node the trace shows without ``--eds`` is read with the
project's CiA 402 drive dictionary, so values decode with their types. :func:`panels` is the
figure as data (what matplotlib is handed); :func:`draw` only renders it.
"""

from __future__ import annotations

import argparse
import bisect
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

from gatewaylab.bus.errorframe import ErrorFrame
from gatewaylab.bus.frame import CanFrame
from gatewaylab.bus.signals import SignalDecoder, load_database
from gatewaylab.bus.timing import frame_duration
from gatewaylab.bus.transport.trace import TimeWindow, TraceError, trace_origin
from gatewaylab.bus.transport.trace import read_trace as trace_items
from gatewaylab.canopen.cia402 import OpMode, Sw
from gatewaylab.canopen.monitor import BusMonitor
from gatewaylab.common.errors import ConfigError
from gatewaylab.devices.canopen_drive.device import build_object_dictionary
from gatewaylab.od import ObjectDictionary
from gatewaylab.od.eds import import_eds

#: --db: at most this many signals get a panel (the first by name)
MAX_SIGNAL_PANELS = 12
#: seconds of position a derived velocity spans at least (:func:`derivative`)
DERIVATIVE_WINDOW = 0.05
#: statusword bits drawn as step lines (CiA 402 table of 0x6041)
_BITS = (Sw.READY_TO_SWITCH_ON, Sw.SWITCHED_ON, Sw.OPERATION_ENABLED, Sw.FAULT, Sw.SWITCH_ON_DISABLED,
         Sw.WARNING, Sw.TARGET_REACHED)


@dataclass
class Series:
    """Time series of one node's decoded values (t in seconds from the trace's first frame)."""

    position: list[tuple[float, int]] = field(default_factory=list)
    velocity: list[tuple[float, int]] = field(default_factory=list)
    statusword: list[tuple[float, int]] = field(default_factory=list)
    mode: list[tuple[float, int]] = field(default_factory=list)


@dataclass
class TracePicture:
    """What a trace says: bus load per bin and the series of each node."""

    load: list[tuple[float, float]]
    nodes: dict[int, Series]
    #: --db: "Message.Signal [unit]" -> (t, value) of every numeric signal the database decodes
    signals: dict[str, list[tuple[float, float]]] = field(default_factory=dict)
    #: the trace time the picture starts at (``--from``; None: the trace's start); the series hold
    #: the values before it too (the figure starts with the values they left there)
    start: float | None = None
    #: the trace time of the last frame drawn (None: the last load bin's)
    end: float | None = None


def _nodes_in(items: list[tuple[CanFrame | ErrorFrame, float]]) -> set[int]:
    """The CANopen nodes a trace shows: boot-up / heartbeat senders and SDO servers that answered."""
    nodes: set[int] = set()
    for obj, _ in items:
        if isinstance(obj, CanFrame) and not obj.extended and not obj.fd and not obj.rtr:
            cid = obj.can_id
            if 0x701 <= cid <= 0x77F and len(obj.data) == 1:
                nodes.add(cid - 0x700)
            elif 0x581 <= cid <= 0x5FF and len(obj.data) == 8:
                nodes.add(cid - 0x580)
    return nodes


def read_trace(path: Path, dictionaries: dict[int, ObjectDictionary] | None = None, bitrate: int = 1_000_000,
               data_bitrate: int | None = None, bin_s: float = 0.01, drives: bool = True,
               signals: SignalDecoder | None = None, window: TimeWindow | None = None) -> TracePicture:
    """Decode ``path`` (any trace the rig writes) into bus load per ``bin_s`` and per-node series.

    Every node the trace shows that has no dictionary of its own is read with the project's CiA 402
    drive dictionary (``drives``): values decode with their types (a negative INTEGER32 position is
    negative) and the default TPDO mappings, and remappings seen by SDO, carry position, velocity and
    statusword. Times are trace time (:func:`~gatewaylab.bus.transport.trace.trace_origin`: what
    ``monitor --replay`` prints). ``window``: only its frames are drawn; the frames before it are
    decoded too (without being drawn), so the window starts with the states, PDO mappings and values
    they left."""
    items = trace_items(path)
    low, high = -float("inf"), float("inf")
    if window and items:
        low, high = window.bounds(items[0][1])
        if not any(low <= stamp < high for _, stamp in items):
            origin = trace_origin(items[0][1])
            raise ConfigError(f"{path}: no frame between --from and --to ({low - origin:.6f} .. "
                              f"{high - origin:.6f} s of trace time); the trace spans "
                              f"{items[0][1] - origin:.6f} .. {items[-1][1] - origin:.6f} s")
    dicts = dict(dictionaries or {})
    if drives:
        for node_id in sorted(_nodes_in(items) - set(dicts)):
            dicts[node_id] = build_object_dictionary(0, node_id)
    monitor = BusMonitor(dicts, bitrate, data_bitrate)
    busy: dict[int, float] = {}
    nodes: dict[int, Series] = {}
    series_of: dict[str, list[tuple[float, float]]] = {}
    t0 = trace_origin(items[0][1]) if items else 0.0
    end: float | None = None
    for obj, stamp in items:
        if isinstance(obj, ErrorFrame) or stamp >= high:
            continue
        t = stamp - t0
        if stamp >= low:         # before the window: decoded for the values it leaves, no load
            slot = int(t / bin_s)
            busy[slot] = busy.get(slot, 0.0) + frame_duration(obj, bitrate, data_bitrate)
            end = t
        message = signals.decode(obj) if signals is not None else None
        if message is not None:
            units = {n: u for n, _, u in message.signals}
            for name, value in message.numbers().items():
                key = f"{message.name}.{name}" + (f" [{units[name]}]" if units.get(name) else "")
                series_of.setdefault(key, []).append((t, value))
            continue
        monitor.feed(obj, t)
        for node_id, view in monitor.nodes.items():
            series = nodes.setdefault(node_id, Series())
            for name in ("position", "velocity", "statusword", "mode"):
                value = getattr(view, name)
                points: list[tuple[float, int]] = getattr(series, name)
                if value is not None and (not points or points[-1][1] != value):
                    points.append((t, value))
    last = max(busy) if busy else 0
    first_slot = min(busy) if busy and window else 0
    load = [(slot * bin_s, 100.0 * busy.get(slot, 0.0) / bin_s) for slot in range(first_slot, last + 1)]
    return TracePicture(load, {n: s for n, s in nodes.items() if s.position or s.velocity or s.statusword},
                        series_of, start=low - t0 if window and window.start is not None else None, end=end)


def _steps(points: list[tuple[float, int]], end: float) -> tuple[list[float], list[float]]:
    xs = [t for t, _ in points] + ([end] if points else [])
    ys = [float(v) for _, v in points] + ([float(points[-1][1])] if points else [])
    return xs, ys


def _line(label: str, points: list[tuple[float, int]], end: float) -> tuple[str, tuple[float, ...], tuple[float, ...]]:
    xs, ys = _steps(points, end)
    return label, tuple(xs), tuple(ys)


_V = TypeVar("_V", int, float)


def _clip(points: list[tuple[float, _V]], start: float | None) -> list[tuple[float, _V]]:
    """The points from ``start`` on, led by the value that holds at ``start`` (None: all of them)."""
    if start is None:
        return points
    at = bisect.bisect_left(points, start, key=lambda p: p[0])
    return ([(start, points[at - 1][1])] if at else []) + points[at:]


def derivative(points: list[tuple[float, int]], window: float = DERIVATIVE_WINDOW) -> list[tuple[float, float]]:
    """Velocity from position samples (increments per second), where no 0x606C was carried.

    ``points`` are the instants the position changed (a TPDO with a new value, stamped when it left
    the bus). TPDOs queued behind other frames leave back to back, ~115 us apart at 1 Mbit/s, with
    positions sampled a control period (1 ms) apart: the change between neighbours divided by their
    distance on the bus is up to ~9x too high. So each point's velocity is the least-squares slope of
    the points of the last ``window`` seconds (three or more): the bus's delays are a small part of
    that span and average out. With fewer points there (a slow move, or the first change after the
    axis held still) it is the change since the latest point at least ``window`` before, over their
    distance; a point after a gap longer than ``window`` gets that mean velocity from the gap's start
    (a stop reads as 0 over the stop, not as a ramp)."""
    out: list[tuple[float, float]] = []
    first = anchor = 0
    for i in range(1, len(points)):
        t1, p1 = points[i]
        while t1 - points[first][0] > window:
            first += 1
        if i - first >= 2:
            span = points[first:i + 1]
            mean_t = sum(t - t1 for t, _ in span) / len(span)
            mean_p = sum(p - p1 for _, p in span) / len(span)
            var = sum((t - t1 - mean_t) ** 2 for t, _ in span)
            if var > 0:
                out.append((t1, sum((t - t1 - mean_t) * (p - p1 - mean_p) for t, p in span) / var))
                continue
        while anchor + 1 < i and t1 - points[anchor + 1][0] >= window:
            anchor += 1
        t0, p0 = points[anchor]
        if t1 <= t0:
            continue
        velocity = (p1 - p0) / (t1 - t0)
        before = points[i - 1][0]
        if t1 - before > window and out:
            out.append((before, velocity))
        out.append((t1, velocity))
    return out


@dataclass(frozen=True, slots=True)
class Panel:
    """One axes of the figure: what matplotlib is handed (lines of x/y arrays), for tests to read."""

    ylabel: str
    lines: tuple[tuple[str, tuple[float, ...], tuple[float, ...]], ...]   # (label, xs, ys)
    title: str = ""
    yticks: tuple[tuple[float, str], ...] = ()


def panels(picture: TracePicture, only: int | None = None) -> list[Panel]:
    """The figure as data: bus load, then per node position, velocity and statusword bits."""
    end = picture.end if picture.end is not None else picture.load[-1][0] if picture.load else 0.0
    start = picture.start
    out = [Panel("bus load %", (("load", tuple(t for t, _ in picture.load), tuple(v for _, v in picture.load)),))]
    for node in (n for n in sorted(picture.nodes) if only is None or n == only):
        s = picture.nodes[node]
        out.append(Panel(f"node {node}\nposition", (_line("position", _clip(s.position, start), end),)))
        if s.velocity:
            out.append(Panel("velocity", (_line("0x606C", _clip(s.velocity, start), end),)))
        else:
            derived = _clip(derivative(s.position), start)
            out.append(Panel("velocity\n(from position)",
                             (("d position / dt", tuple(t for t, _ in derived), tuple(v for _, v in derived)),)))
        bits = []
        for k, bit in enumerate(_BITS):
            xs, ys = _steps([(t, 1 if v & bit else 0) for t, v in _clip(s.statusword, start)], end)
            bits.append((str(bit.name).lower(), tuple(xs), tuple(k * 1.3 + y for y in ys)))
        modes = _clip(s.mode, start)
        title = "mode: " + ", ".join(sorted({_mode_name(v) for _, v in modes})) if modes else ""
        out.append(Panel("statusword", tuple(bits), title,
                         tuple((k * 1.3 + 0.5, str(b.name).lower().replace("_", " ")) for k, b in enumerate(_BITS))))
    if only is None:
        for key, points in sorted(picture.signals.items())[:MAX_SIGNAL_PANELS]:
            xs, ys = [t for t, _ in points] + ([end] if points else []), [v for _, v in points] + (
                [points[-1][1]] if points else [])
            out.append(Panel(key.replace(" [", "\n["), ((key, tuple(xs), tuple(ys)),)))
    return out


def _mode_name(value: int) -> str:
    try:
        return OpMode(value).name
    except ValueError:
        return str(value)


def draw(picture: TracePicture, out: Path, title: str, only: int | None = None) -> list[int]:
    """Write the figure of :func:`panels` to ``out`` (.png or .svg); returns the nodes drawn."""
    import matplotlib
    matplotlib.use("Agg")      # no screen needed
    import matplotlib.pyplot as plt

    nodes = [n for n in sorted(picture.nodes) if only is None or n == only]
    figure = panels(picture, only)
    fig, axes = plt.subplots(len(figure), 1, figsize=(10, 2.2 * len(figure)), sharex=True, squeeze=False)
    for ax, panel in zip((row[0] for row in axes), figure, strict=True):
        for label, xs, ys in panel.lines:
            if panel.ylabel == "bus load %" or "from position" in panel.ylabel:
                ax.plot(xs, ys, lw=0.8, label=label)
            else:
                ax.step(xs, ys, where="post", lw=0.9, label=label)
        ax.set_ylabel(panel.ylabel)
        if panel.yticks:
            ax.set_yticks([y for y, _ in panel.yticks], [name for _, name in panel.yticks], fontsize=6)
        if panel.title:
            ax.set_title(panel.title, fontsize=7, loc="right")
    axes[0][0].set_title(title)
    axes[-1][0].set_xlabel("time (s)")
    fig.tight_layout()
    fig.savefig(out)
    plt.close(fig)
    return nodes


def cmd_plot(args: argparse.Namespace) -> int:
    """``gatewaylab plot TRACE``."""
    trace = Path(args.trace)
    out = Path(args.output) if args.output else trace.with_suffix(".png")
    if out.suffix.lower() not in (".png", ".svg"):
        print(f"gatewaylab: {out}: the picture is .png or .svg", file=sys.stderr)
        return 2
    if not trace.is_file():
        print(f"gatewaylab: {trace}: no such trace file", file=sys.stderr)
        return 2
    dictionaries: dict[int, ObjectDictionary] = {}
    try:
        for node_id, path in args.eds or ():
            dictionaries[node_id] = import_eds(Path(path).read_text(), node_id)
    except (OSError, ValueError) as exc:
        print(f"gatewaylab: --eds: {exc}", file=sys.stderr)
        return 2
    try:
        window = TimeWindow.parse(args.window_from, args.window_to)
        signals = load_database(args.db) if args.db else None
        picture = read_trace(trace, dictionaries, args.bitrate, args.data_bitrate, signals=signals, window=window)
    except (TraceError, ConfigError) as exc:
        print(f"gatewaylab: {exc}", file=sys.stderr)
        return 2
    drawn = draw(picture, out, f"{trace.name}", args.node)
    print(f"{out}: bus load over {len(picture.load)} x 10 ms"
          + (f", node(s) {', '.join(map(str, drawn))}" if drawn else ", no drive values decoded")
          + (f", {min(len(picture.signals), MAX_SIGNAL_PANELS)} signal(s)" if picture.signals else ""))
    return 0


def _eds(text: str) -> tuple[int, str]:
    node, sep, path = text.partition("=")
    if not sep or not node.isdigit() or not 1 <= int(node) <= 127:
        raise argparse.ArgumentTypeError(f"--eds wants NODE=FILE, got {text!r}")
    return int(node), path


def add_subcommand(subparsers: Any) -> None:
    """Add ``plot`` to the gatewaylab CLI."""
    p = subparsers.add_parser(
        "plot", help="PNG/SVG of a trace: bus load and decoded drive values",
        description="Draw bus load over time and, per drive, position, velocity, statusword bits and mode "
                    "decoded from a trace file (any python-can format: .asc .log .blf .csv .trc ...).\n\n"
                    "example:\n  gatewaylab run --trace can0=run.asc     # record\n"
                    "  gatewaylab plot run.asc --node 2 -o run.svg\n"
                    "  gatewaylab plot run.asc --from +2.5 --to +0.3     # 0.3 s from 2.5 s after the first frame",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("trace", metavar="TRACE", help="trace file")
    p.add_argument("--node", type=int, default=None, help="draw this node only (every node is read with the "
                   "drive dictionary unless --eds gives its own)")
    p.add_argument("--eds", type=_eds, action="append", metavar="NODE=FILE", help="a node's dictionary")
    p.add_argument("--db", metavar="FILE", help="a signal database (DBC, KCD, ARXML, SYM; cantools): one panel per "
                   f"numeric signal (at most {MAX_SIGNAL_PANELS})")
    p.add_argument("-o", "--output", default=None, help="picture file, .png (default: TRACE with .png) or .svg")
    p.add_argument("--from", dest="window_from", metavar="T|+S", default=None,
                   help="draw from T seconds of trace time (what `monitor --replay` prints), or +S seconds after "
                        "the first frame")
    p.add_argument("--to", dest="window_to", metavar="T|+D", default=None,
                   help="draw up to T seconds of trace time, or +D seconds after --from")
    p.add_argument("--bitrate", type=int, default=1_000_000, help="bus bit rate for the load (default 1000000)")
    p.add_argument("--data-bitrate", type=int, default=None, help="CAN FD data bit rate")
    p.set_defaults(func=cmd_plot)
