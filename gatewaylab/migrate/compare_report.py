"""``gatewaylab migrate compare``: the traces (python-can CSV files) and the report (Markdown, HTML,
matplotlib plots on the Agg backend) of a :class:`~.compare.Comparison`.

Files in the report folder, per gateway (prefix ``esd`` / ``ecanlite``): ``PREFIX.bus.csv`` every
frame on the CAN bus, ``PREFIX.sent.csv`` the application's ``send()`` calls, ``PREFIX.received.csv``
the frames it received (python-can's CSV format, ``can.LogReader`` reads them; timestamps are
seconds since the application started). Then ``report.md``, ``report.html``, ``latency.png`` and
``timeline.png``. Same recordings in, byte-identical files out (no dates, no versions in them).
"""

from __future__ import annotations

import html
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can

from gatewaylab.migrate.compare import (
    MAX_LISTED,
    AppEvent,
    AppEventKind,
    Comparison,
    Frame,
    Latencies,
    Recording,
    Stats,
    by_identifier,
    ms,
)

#: report file names
REPORT_MD, REPORT_HTML, LATENCY_PNG, TIMELINE_PNG = "report.md", "report.html", "latency.png", "timeline.png"


def _message(f: Frame) -> can.Message:
    return can.Message(timestamp=f.t, arbitration_id=f.can_id, is_extended_id=f.extended,
                       is_remote_frame=f.rtr, data=None if f.rtr else f.data,
                       dlc=len(f.data), check=False)


def _frame(m: can.Message) -> Frame:
    return Frame(m.timestamp, m.arbitration_id, b"" if m.is_remote_frame else bytes(m.data),
                 m.is_extended_id, m.is_remote_frame)


def write_csv(path: Path, frames: Sequence[Frame]) -> None:
    """``frames`` with python-can's CSV writer."""
    writer = can.CSVWriter(str(path))
    try:
        for f in frames:
            writer.on_message_received(_message(f))
    finally:
        writer.stop()


def read_csv(path: Path) -> tuple[Frame, ...]:
    """The frames of a trace file :func:`write_csv` wrote (the report is made from these, as a reader sees them)."""
    return tuple(_frame(m) for m in can.CSVReader(str(path)))


def write_recording(folder: Path, prefix: str, rec: Recording) -> list[Path]:
    """The three trace files of one recording."""
    paths = [folder / f"{prefix}.bus.csv", folder / f"{prefix}.sent.csv", folder / f"{prefix}.received.csv"]
    write_csv(paths[0], rec.bus)
    write_csv(paths[1], [e.frame for e in rec.app if e.kind is AppEventKind.SEND])
    write_csv(paths[2], [e.frame for e in rec.app if e.kind is AppEventKind.RECV])
    return paths


def read_recording(folder: Path, prefix: str, gateway: str, duration: float = 0.0) -> Recording:
    """A recording back from its trace files (sends and receptions merged in time order)."""
    sent = [AppEvent(AppEventKind.SEND, f) for f in read_csv(folder / f"{prefix}.sent.csv")]
    got = [AppEvent(AppEventKind.RECV, f) for f in read_csv(folder / f"{prefix}.received.csv")]
    app = sorted(sent + got, key=lambda e: e.frame.t)
    return Recording(gateway, read_csv(folder / f"{prefix}.bus.csv"), tuple(app), duration)


# -- the report as blocks, rendered twice ------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Block:
    """One piece of the report, rendered alike to Markdown and HTML (``header`` holds an image's file)."""

    kind: str                 # h1, h2, p, table, img, code
    text: str = ""
    header: tuple[str, ...] = ()
    rows: tuple[tuple[str, ...], ...] = ()


def _stats_rows(c: Comparison) -> tuple[tuple[str, ...], ...]:
    rows = []
    for rec, lat in ((c.a, c.latency_a), (c.b, c.latency_b)):
        for direction, values in (("master -> CAN", lat.to_can), ("CAN -> master", lat.to_master)):
            s = Stats.of(values)
            rows.append((rec.gateway, direction, str(s.count) if s else "0", ms(s.p50 if s else None),
                         ms(s.p99 if s else None), ms(s.max if s else None), ms(s.mean if s else None)))
    return tuple(rows)


def blocks(c: Comparison, title: str, setup: Sequence[tuple[str, str]], traces: Sequence[str]) -> list[Block]:
    """The report's content: setup, verdict, traffic, differences, latencies, plots, files."""
    a, b = c.a.gateway, c.b.gateway
    out = [Block("h1", title),
           Block("table", header=("", ""), rows=tuple(setup)),
           Block("h2", "Verdict"),
           Block("p", ("**identical**" if c.identical else "**different**") + ": " + c.verdict()),
           Block("h2", "CAN traffic"),
           Block("table", header=("", a, b), rows=(
               ("frames on the bus", str(len(c.a.bus)), str(len(c.b.bus))),
               ("sent by the application", str(len(c.latency_a.sent_by_app)), str(len(c.latency_b.sent_by_app))),
               ("from other nodes", str(len(c.a.bus) - len(c.latency_a.sent_by_app)),
                str(len(c.b.bus) - len(c.latency_b.sent_by_app))),
               ("application ran for", f"{c.a.duration:.3f} s", f"{c.b.duration:.3f} s"),
               ("only in this trace", str(len(c.only_in(0))), str(len(c.only_in(1)))),
               ("in another order", str(len(c.moved)), str(len(c.moved))),
               ("other payload", str(len(c.payload)), str(len(c.payload))))),
           ]
    if c.identical:
        out.append(Block("p", "Both buses carried the same frames in the same order with the same payloads "
                              "(aligned with difflib on identifier, flags and data; times are not compared)."))
    else:
        out.append(Block("h2", "Differences"))
        out.append(Block("p", "By identifier (sent by: who sent that identifier's differing frames):"))
        out.append(Block("table", header=("identifier", f"only {a}", f"only {b}", "other order", "other payload",
                                          "sent by"),
                         rows=tuple((s.label(), str(s.only_a), str(s.only_b), str(s.moved), str(s.payload), s.sender)
                                    for s in by_identifier(c))))
        for side, name in ((0, a), (1, b)):
            rows = [(str(o.index), f"{o.frame.t * 1e3:.3f}", o.frame.label()) for o in c.only_in(side)]
            if rows:
                out.append(Block("p", f"Frames only through {name} ({len(rows)}):"))
                out.append(Block("table", header=("frame #", "t / ms", "frame"), rows=tuple(rows[:MAX_LISTED])))
                if len(rows) > MAX_LISTED:
                    out.append(Block("p", f"... and {len(rows) - MAX_LISTED} more."))
        if c.moved:
            out.append(Block("p", f"Frames in another order ({len(c.moved)}):"))
            out.append(Block("table", header=(f"# {a}", f"# {b}", "frame"),
                             rows=tuple((str(m.index_a), str(m.index_b), m.frame.label())
                                        for m in c.moved[:MAX_LISTED])))
        if c.payload:
            out.append(Block("p", f"Frames with other payload ({len(c.payload)}):"))
            out.append(Block("table", header=(f"# {a}", a, f"# {b}", b),
                             rows=tuple((str(p.index_a), p.a.label(), str(p.index_b), p.b.label())
                                        for p in c.payload[:MAX_LISTED])))
    out += [Block("h2", "Latency"),
            Block("p", "master -> CAN: from the application's `send()` call to the end of that frame on the "
                       "bus. CAN -> master: from the end of another node's frame on the bus to the moment "
                       "the host handed it to `recv()`. Nearest-rank percentiles."),
            Block("table", header=("gateway", "direction", "frames", "p50", "p99", "max", "mean"),
                  rows=_stats_rows(c))]
    lost = [(rec.gateway, lat) for rec, lat in ((c.a, c.latency_a), (c.b, c.latency_b))
            if lat.unmatched_sends or lat.unmatched_recvs]
    for name, lat in lost:
        out.append(Block("p", f"{name}: {lat.unmatched_sends} sent frames never appeared on the bus, "
                              f"{lat.unmatched_recvs} received frames matched no bus frame."))
    out += [Block("img", "latency histograms", header=(LATENCY_PNG,)),
            Block("img", "frame timeline of both buses", header=(TIMELINE_PNG,)),
            Block("h2", "Files"),
            Block("p", "Traces (python-can CSV, `can.LogReader` reads them; t = 0 is the application's start): "
                       + ", ".join(f"[{t}]({t})" for t in traces) + ".")]
    return out


def _md_cell(text: str) -> str:
    return text.replace("|", "\\|")


def markdown(bl: Sequence[Block]) -> str:
    """The report as Markdown (report.md)."""
    lines: list[str] = []
    for blk in bl:
        if blk.kind == "h1":
            lines += [f"# {blk.text}", ""]
        elif blk.kind == "h2":
            lines += [f"## {blk.text}", ""]
        elif blk.kind == "p":
            lines += [blk.text, ""]
        elif blk.kind == "table":
            lines.append("| " + " | ".join(_md_cell(h) for h in blk.header) + " |")
            lines.append("|" + "---|" * len(blk.header))
            lines += ["| " + " | ".join(_md_cell(x) for x in row) + " |" for row in blk.rows]
            lines.append("")
        elif blk.kind == "img":
            lines += [f"![{blk.text}]({blk.header[0]})", ""]
    return "\n".join(lines)


def _inline_html(text: str) -> str:
    """Markdown's **bold**, `code` and [text](link) in a paragraph, escaped."""
    out = html.escape(text, quote=False)
    out = re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", out)
    out = re.sub(r"`(.+?)`", r"<code>\1</code>", out)
    return re.sub(r"\[([^\]]+)\]\(([^)]+)\)", r'<a href="\2">\1</a>', out)


def to_html(bl: Sequence[Block], title: str) -> str:
    """The report as a standalone HTML page (report.html) for readers without a Markdown viewer."""
    parts = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
             f"<title>{html.escape(title)}</title>",
             "<style>body{font-family:sans-serif;max-width:60em;margin:auto}table{border-collapse:collapse}"
             "td,th{border:1px solid #aaa;padding:2px 6px;font-family:monospace}img{max-width:100%}</style>",
             "</head><body>"]
    for blk in bl:
        if blk.kind in ("h1", "h2"):
            parts.append(f"<{blk.kind}>{html.escape(blk.text)}</{blk.kind}>")
        elif blk.kind == "p":
            parts.append(f"<p>{_inline_html(blk.text)}</p>")
        elif blk.kind == "table":
            head = "".join(f"<th>{html.escape(h)}</th>" for h in blk.header)
            body = "".join("<tr>" + "".join(f"<td>{html.escape(x)}</td>" for x in row) + "</tr>" for row in blk.rows)
            parts.append(f"<table><tr>{head}</tr>{body}</table>")
        elif blk.kind == "img":
            parts.append(f'<p><img src="{html.escape(blk.header[0])}" alt="{html.escape(blk.text)}"></p>')
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"


# -- plots ---------------------------------------------------------------------------------------
def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig: Any, path: Path) -> None:
    fig.savefig(path, dpi=90, metadata={"Software": None})   # no version in the file: same bytes every run


def plot_latency(c: Comparison, path: Path) -> None:
    """Histograms of both directions, both gateways on each."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    pairs: list[tuple[str, list[tuple[str, tuple[float, ...]]]]] = [
        ("master -> CAN", [(c.a.gateway, c.latency_a.to_can), (c.b.gateway, c.latency_b.to_can)]),
        ("CAN -> master", [(c.a.gateway, c.latency_a.to_master), (c.b.gateway, c.latency_b.to_master)])]
    for ax, (direction, series) in zip(axes, pairs):
        values = [v * 1e3 for _, vs in series for v in vs]
        if values:
            lo, hi = min(values), max(values)
            width = max((hi - lo) / 40, 0.001)
            bins = [lo + k * width for k in range(42)]
            for name, vs in series:
                if vs:
                    ax.hist([v * 1e3 for v in vs], bins=bins, histtype="step", linewidth=1.5, label=name)
            ax.legend(fontsize=8)
        else:
            ax.text(0.5, 0.5, "no frames", ha="center", va="center", transform=ax.transAxes)
        ax.set_title(direction)
        ax.set_xlabel("latency / ms")
        ax.set_ylabel("frames")
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


def _diff_indexes(c: Comparison) -> tuple[set[int], set[int]]:
    da = {o.index for o in c.only_in(0)} | {m.index_a for m in c.moved} | {p.index_a for p in c.payload}
    db = {o.index for o in c.only_in(1)} | {m.index_b for m in c.moved} | {p.index_b for p in c.payload}
    return da, db


def _hex_formatter() -> Any:
    from matplotlib.ticker import FuncFormatter

    return FuncFormatter(lambda v, _pos: f"0x{int(v):03X}" if v >= 0 else "")


def plot_timeline(c: Comparison, path: Path) -> None:
    """Both buses over time (identifier against time since the application started): frames the
    application sent, frames of other nodes, differences in red."""
    plt = _pyplot()
    fig, axes = plt.subplots(2, 1, figsize=(10, 5), sharex=True, sharey=True)
    diffs = _diff_indexes(c)
    for ax, rec, lat, diff in zip(axes, (c.a, c.b), (c.latency_a, c.latency_b), diffs):
        groups: list[tuple[str, str, str, list[Frame]]] = [
            ("sent by the application", "^", "tab:blue",
             [f for i, f in enumerate(rec.bus) if i in lat.sent_by_app and i not in diff]),
            ("from other nodes", "o", "tab:green",
             [f for i, f in enumerate(rec.bus) if i not in lat.sent_by_app and i not in diff]),
            ("differs", "x", "tab:red", [f for i, f in enumerate(rec.bus) if i in diff])]
        for label, marker, color, fs in groups:
            if fs:
                ax.scatter([f.t * 1e3 for f in fs], [f.can_id for f in fs], s=9, marker=marker, color=color,
                           label=label, linewidths=0.8)
        ax.set_title(f"{rec.gateway}: {len(rec.bus)} frames", fontsize=10)
        ax.set_ylabel("CAN identifier")
        ax.yaxis.set_major_formatter(_hex_formatter())
        if rec.bus:
            ax.legend(fontsize=7, loc="upper right")
    axes[-1].set_xlabel("time since the application started / ms")
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


def write_report(folder: Path, c: Comparison, title: str, setup: Sequence[tuple[str, str]],
                 traces: Sequence[str]) -> Path:
    """report.md, report.html and the two plots into ``folder``; returns the Markdown path."""
    bl = blocks(c, title, setup, traces)
    md = folder / REPORT_MD
    md.write_text(markdown(bl), encoding="utf-8")
    (folder / REPORT_HTML).write_text(to_html(bl, title), encoding="utf-8")
    plot_latency(c, folder / LATENCY_PNG)
    plot_timeline(c, folder / TIMELINE_PNG)
    return md


def latency_summary(lat: Latencies) -> dict[str, Any]:
    """p50/p99/max/mean/count per direction in seconds (for --json)."""
    out: dict[str, Any] = {}
    for key, values in (("master_to_can", lat.to_can), ("can_to_master", lat.to_master)):
        s = Stats.of(values)
        out[key] = None if s is None else {"count": s.count, "p50": s.p50, "p99": s.p99, "max": s.max,
                                           "mean": s.mean}
    return out


__all__ = ["LATENCY_PNG", "REPORT_HTML", "REPORT_MD", "TIMELINE_PNG", "blocks", "latency_summary", "markdown",
           "plot_latency", "plot_timeline", "read_csv", "read_recording", "to_html", "write_csv",
           "write_recording", "write_report"]
