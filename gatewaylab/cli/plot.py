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
import itertools
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gatewaylab.bus.errorframe import ErrorFrame
from gatewaylab.bus.frame import CanFrame
from gatewaylab.bus.signals import SignalDecoder, load_database
from gatewaylab.bus.timing import frame_duration
from gatewaylab.bus.transport.trace import TraceError
from gatewaylab.bus.transport.trace import read_trace as trace_items
from gatewaylab.canopen.cia402 import OpMode, Sw
from gatewaylab.canopen.monitor import BusMonitor
from gatewaylab.common.errors import ConfigError
from gatewaylab.devices.canopen_drive.objects import build_object_dictionary
from gatewaylab.od import ObjectDictionary
from gatewaylab.od.eds import import_eds

#: statusword bits drawn as step lines (CiA 402 table of 0x6041)
#: --db: at most this many signals get a panel (the first by name)
MAX_SIGNAL_PANELS = 12
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
               signals: SignalDecoder | None = None) -> TracePicture:
    """Decode ``path`` (any trace the rig writes) into bus load per ``bin_s`` and per-node series.

    Every node the trace shows that has no dictionary of its own is read with the project's CiA 402
    drive dictionary (``drives``): values decode with their types (a negative INTEGER32 position is
    negative) and the default TPDO mappings, and remappings seen by SDO, carry position, velocity and
    statusword."""
    items = trace_items(path)
    dicts = dict(dictionaries or {})
    if drives:
        for node_id in sorted(_nodes_in(items) - set(dicts)):
            dicts[node_id] = build_object_dictionary(0, node_id)
    monitor = BusMonitor(dicts, bitrate, data_bitrate)
    busy: dict[int, float] = {}
    nodes: dict[int, Series] = {}
    series_of: dict[str, list[tuple[float, float]]] = {}
    t0: float | None = None
    for obj, stamp in items:
        if isinstance(obj, ErrorFrame):
            continue
        t0 = stamp if t0 is None else t0
        t = stamp - t0
        slot = int(t / bin_s)
        busy[slot] = busy.get(slot, 0.0) + frame_duration(obj, bitrate, data_bitrate)
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
    load = [(slot * bin_s, 100.0 * busy.get(slot, 0.0) / bin_s) for slot in range(last + 1)]
    return TracePicture(load, {n: s for n, s in nodes.items() if s.position or s.velocity or s.statusword},
                        series_of)


def _steps(points: list[tuple[float, int]], end: float) -> tuple[list[float], list[float]]:
    xs = [t for t, _ in points] + ([end] if points else [])
    ys = [float(v) for _, v in points] + ([float(points[-1][1])] if points else [])
    return xs, ys


def _line(label: str, points: list[tuple[float, int]], end: float) -> tuple[str, tuple[float, ...], tuple[float, ...]]:
    xs, ys = _steps(points, end)
    return label, tuple(xs), tuple(ys)


def _derivative(points: list[tuple[float, int]]) -> list[tuple[float, float]]:
    """Velocity from position samples (increments per second), where no 0x606C was carried."""
    return [(t1, (p1 - p0) / (t1 - t0)) for (t0, p0), (t1, p1) in itertools.pairwise(points) if t1 > t0]


@dataclass(frozen=True, slots=True)
class Panel:
    """One axes of the figure: what matplotlib is handed (lines of x/y arrays), for tests to read."""

    ylabel: str
    lines: tuple[tuple[str, tuple[float, ...], tuple[float, ...]], ...]   # (label, xs, ys)
    title: str = ""
    yticks: tuple[tuple[float, str], ...] = ()


def panels(picture: TracePicture, only: int | None = None) -> list[Panel]:
    """The figure as data: bus load, then per node position, velocity and statusword bits."""
    end = picture.load[-1][0] if picture.load else 0.0
    out = [Panel("bus load %", (("load", tuple(t for t, _ in picture.load), tuple(v for _, v in picture.load)),))]
    for node in (n for n in sorted(picture.nodes) if only is None or n == only):
        s = picture.nodes[node]
        out.append(Panel(f"node {node}\nposition", (_line("position", s.position, end),)))
        if s.velocity:
            out.append(Panel("velocity", (_line("0x606C", s.velocity, end),)))
        else:
            derived = _derivative(s.position)
            out.append(Panel("velocity\n(from position)",
                             (("d position / dt", tuple(t for t, _ in derived), tuple(v for _, v in derived)),)))
        bits = []
        for k, bit in enumerate(_BITS):
            xs, ys = _steps([(t, 1 if v & bit else 0) for t, v in s.statusword], end)
            bits.append((str(bit.name).lower(), tuple(xs), tuple(k * 1.3 + y for y in ys)))
        title = "mode: " + ", ".join(sorted({_mode_name(v) for _, v in s.mode})) if s.mode else ""
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
        signals = load_database(args.db) if args.db else None
        picture = read_trace(trace, dictionaries, args.bitrate, args.data_bitrate, signals=signals)
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
                    "  gatewaylab plot run.asc --node 2 -o run.svg",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("trace", metavar="TRACE", help="trace file")
    p.add_argument("--node", type=int, default=None, help="draw this node only (every node is read with the "
                   "drive dictionary unless --eds gives its own)")
    p.add_argument("--eds", type=_eds, action="append", metavar="NODE=FILE", help="a node's dictionary")
    p.add_argument("--db", metavar="FILE", help="a signal database (DBC, KCD, ARXML, SYM; cantools): one panel per "
                   f"numeric signal (at most {MAX_SIGNAL_PANELS})")
    p.add_argument("-o", "--output", default=None, help="picture file, .png (default: TRACE with .png) or .svg")
    p.add_argument("--bitrate", type=int, default=1_000_000, help="bus bit rate for the load (default 1000000)")
    p.add_argument("--data-bitrate", type=int, default=None, help="CAN FD data bit rate")
    p.set_defaults(func=cmd_plot)
