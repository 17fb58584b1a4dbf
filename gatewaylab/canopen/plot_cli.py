"""``gatewaylab plot TRACE``: a picture of a recorded bus (matplotlib, PNG or SVG).

Bus load over time, and for each drive the values the monitor decodes from its PDOs and SDO
transfers: position, velocity, statusword bits and mode of operation. The decoding is
:class:`~.monitor.BusMonitor`'s (the one ``gatewaylab monitor`` and ``explain`` use); a node
without ``--eds`` is read with the project's CiA 402 drive dictionary when asked for by ``--node``.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can

from ..bus.frame import CanFrame
from ..bus.timing import frame_duration
from ..od import ObjectDictionary
from ..od.eds import import_eds
from .cia402 import Sw
from .drive import build_object_dictionary
from .monitor import BusMonitor

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


def read_trace(path: Path, dictionaries: dict[int, ObjectDictionary], bitrate: int = 1_000_000,
               data_bitrate: int | None = None, bin_s: float = 0.01) -> TracePicture:
    """Decode ``path`` (any python-can log format) into bus load per ``bin_s`` and per-node series."""
    monitor = BusMonitor(dictionaries, bitrate, data_bitrate)
    busy: dict[int, float] = {}
    nodes: dict[int, Series] = {}
    t0: float | None = None
    for msg in can.LogReader(str(path)):
        if msg.is_error_frame:
            continue
        frame = CanFrame.from_message(msg)
        t0 = msg.timestamp if t0 is None else t0
        t = msg.timestamp - t0
        slot = int(t / bin_s)
        busy[slot] = busy.get(slot, 0.0) + frame_duration(frame, bitrate, data_bitrate)
        monitor.feed(frame, t)
        for node_id, view in monitor.nodes.items():
            series = nodes.setdefault(node_id, Series())
            for name in ("position", "velocity", "statusword", "mode"):
                value = getattr(view, name)
                points: list[tuple[float, int]] = getattr(series, name)
                if value is not None and (not points or points[-1][1] != value):
                    points.append((t, value))
    last = max(busy) if busy else 0
    load = [(slot * bin_s, 100.0 * busy.get(slot, 0.0) / bin_s) for slot in range(last + 1)]
    return TracePicture(load, {n: s for n, s in nodes.items() if s.position or s.velocity or s.statusword})


def _steps(points: list[tuple[float, int]], end: float) -> tuple[list[float], list[int]]:
    xs = [t for t, _ in points] + ([end] if points else [])
    ys = [v for _, v in points] + ([points[-1][1]] if points else [])
    return xs, ys


def draw(picture: TracePicture, out: Path, title: str, only: int | None = None) -> list[int]:
    """Write the figure to ``out`` (.png or .svg); returns the nodes drawn."""
    import matplotlib
    matplotlib.use("Agg")      # no screen needed
    import matplotlib.pyplot as plt

    nodes = [n for n in sorted(picture.nodes) if only is None or n == only]
    end = picture.load[-1][0] if picture.load else 0.0
    rows = 1 + 3 * len(nodes)
    fig, axes = plt.subplots(rows, 1, figsize=(10, 2.2 * rows), sharex=True, squeeze=False)
    ax = axes[0][0]
    ax.plot([t for t, _ in picture.load], [v for _, v in picture.load], lw=0.8)
    ax.set_ylabel("bus load %")
    ax.set_title(title)
    for i, node in enumerate(nodes):
        s = picture.nodes[node]
        pos, vel, sw = axes[1 + 3 * i][0], axes[2 + 3 * i][0], axes[3 + 3 * i][0]
        pos.step(*_steps(s.position, end), where="post", lw=0.9)
        pos.set_ylabel(f"node {node}\nposition")
        vel.step(*_steps(s.velocity, end), where="post", lw=0.9, color="tab:orange")
        vel.set_ylabel("velocity")
        for k, bit in enumerate(_BITS):
            xs, ys = _steps([(t, 1 if v & bit else 0) for t, v in s.statusword], end)
            sw.step(xs, [k * 1.3 + y for y in ys], where="post", lw=0.9, label=str(bit.name).lower())
        sw.set_yticks([k * 1.3 + 0.5 for k in range(len(_BITS))],
                      [str(b.name).lower().replace("_", " ") for b in _BITS], fontsize=6)
        if s.mode:
            sw.set_title("mode: " + ", ".join(sorted({str(v) for _, v in s.mode})), fontsize=7, loc="right")
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
        print(f"error: {out}: the picture is .png or .svg", file=sys.stderr)
        return 2
    if not trace.is_file():
        print(f"error: {trace}: no such trace file", file=sys.stderr)
        return 2
    dictionaries: dict[int, ObjectDictionary] = {}
    if args.node is not None:
        dictionaries[args.node] = build_object_dictionary(0, args.node)
    for node_id, path in args.eds or ():
        dictionaries[node_id] = import_eds(Path(path).read_text(), node_id)
    try:
        picture = read_trace(trace, dictionaries, args.bitrate, args.data_bitrate)
    except (ValueError, OSError) as exc:
        print(f"error: {trace}: {exc}", file=sys.stderr)
        return 1
    drawn = draw(picture, out, f"{trace.name}", args.node)
    print(f"{out}: bus load over {len(picture.load)} x 10 ms"
          + (f", node(s) {', '.join(map(str, drawn))}" if drawn else ", no drive values decoded"))
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
    p.add_argument("--node", type=int, default=None, help="draw this node only (read with the drive dictionary "
                   "unless --eds gives its own)")
    p.add_argument("--eds", type=_eds, action="append", metavar="NODE=FILE", help="a node's dictionary")
    p.add_argument("-o", "--output", default=None, help="picture file, .png (default: TRACE with .png) or .svg")
    p.add_argument("--bitrate", type=int, default=1_000_000, help="bus bit rate for the load (default 1000000)")
    p.add_argument("--data-bitrate", type=int, default=None, help="CAN FD data bit rate")
    p.set_defaults(func=cmd_plot)
