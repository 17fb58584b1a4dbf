"""``gatewaylab play TARGET TRACE``: a recorded trace sent back onto a rig's bus, as can-utils' ``canplayer``.

The frames of TRACE (every format the rig reads: :func:`~gatewaylab.bus.transport.trace.read_trace`) go
to the bus with their original spacing (``--speed X`` runs X times faster, ``-t`` ignores the timestamps),
``--loop N`` times, through a candump-style id filter (``-f ID:MASK``, the syntax of ``dump -f``), from a
time window (``--from`` / ``--to``, as ``dump --replay``), to one bus (``--bus NAME``) or, ``canplayer -I``
style, channel by channel (``--map CHANNEL=BUS``, repeatable: then only mapped channels are played). Error
frames are not sent (a client cannot send one). The command waits until every frame was acknowledged on
the bus (its own echo): exit 0; 1 when frames were not acknowledged or the rig refused one (CAN FD on a
classic bus) or went away; 2 on a usage error (bad trace, filter, map, window, unknown bus).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can

from gatewaylab.bus.candump import CandumpSyntaxError, FilterSet, parse_filters
from gatewaylab.bus.errorframe import ErrorFrame
from gatewaylab.bus.frame import CanFrame
from gatewaylab.bus.transport.trace import TraceError, read_trace
from gatewaylab.bus.transport.trace_window import TimeWindow
from gatewaylab.cli.target import bus_target
from gatewaylab.common.endpoint import EndpointError
from gatewaylab.common.errors import ConfigError

__all__ = ["Playlist", "add_subcommand", "cmd_play", "playlist"]

#: seconds the end of a play waits for the last frames' acknowledgements (beyond the trace's own time)
ACK_TIMEOUT = 5.0

_DESCRIPTION = """\
Send the frames of a trace file onto a bus of a running rig, as can-utils' canplayer does: with the
trace's own timing (--speed, -t), --loop times, filtered (-f, candump syntax) and from a time window
(--from/--to, as dump --replay). TARGET is the rig's ready file or a bus endpoint (unix:PATH,
tcp:HOST:PORT). The trace's channels go to --bus, or with --map CHANNEL=BUS (canplayer -I) channel by
channel: CHANNEL as the trace names it (candump .log, .txt, pcapng: can0; Vector .asc/.blf, .trc: 1, 2,
...); with --map, unmapped channels are not played. Waits until every frame was acknowledged (exit 0);
exit 1 when frames were not acknowledged (a lone client: run the rig with --acker) or refused; 2 on a
usage error.

examples:
  gatewaylab play ready.json run.log                       # original timing, onto can0
  gatewaylab play ready.json run.asc --speed 10 --loop 3   # ten times faster, three times
  gatewaylab play ready.json run.log -f 180:780 --map can0=can1
  gatewaylab play unix:/tmp/gl/can0.sock run.pcapng -t --from +2.5 --to +0.3
"""


@dataclass(frozen=True, slots=True)
class Playlist:
    """What a play sends: ``(offset in trace seconds from the first frame sent, bus name, frame)`` in
    trace order, and what it leaves out (error frames, frames the filter refused, unmapped channels)."""

    frames: tuple[tuple[float, str, CanFrame], ...]
    error_frames: int
    filtered: int
    unmapped: Counter[str]

    @property
    def span(self) -> float:
        """Trace seconds from the first frame to the last one sent."""
        return self.frames[-1][0] if self.frames else 0.0


def playlist(path: Path, bus: str, mapping: dict[str, str], filters: FilterSet,
             window: TimeWindow | None = None) -> Playlist:
    """The frames of ``path`` to send (pure: no bus touched); :class:`TraceError` / ``ConfigError``."""
    channels: list[str] = []
    items = read_trace(path, channels)
    low, high = window.bounds(items[0][1]) if window and items else (-float("inf"), float("inf"))
    frames: list[tuple[float, str, CanFrame]] = []
    errors = filtered = 0
    unmapped: Counter[str] = Counter()
    first: float | None = None
    for (obj, stamp), channel in zip(items, channels, strict=True):
        if not low <= stamp < high:
            continue
        if isinstance(obj, ErrorFrame):
            errors += 1
            continue
        target = mapping.get(channel) if mapping else bus
        if target is None:
            unmapped[channel or "(none)"] += 1
            continue
        if not filters.accepts(obj):
            filtered += 1
            continue
        first = stamp if first is None else first
        frames.append((stamp - first, target, obj))
    return Playlist(tuple(frames), errors, filtered, unmapped)


def _map_arg(text: str) -> tuple[str, str]:
    channel, sep, bus = text.partition("=")
    if not sep or not channel or not bus:
        raise argparse.ArgumentTypeError(f"--map wants CHANNEL=BUS (canplayer -I style, e.g. can0=can1 or "
                                         f"1=can0), got {text!r}")
    return channel, bus


def _speed_arg(text: str) -> float:
    try:
        speed = float(text)
    except ValueError:
        speed = float("nan")
    if not 0 < speed < float("inf"):
        raise argparse.ArgumentTypeError(f"--speed wants a factor > 0 (2: twice as fast), got {text!r}")
    return speed


def _loop_arg(text: str) -> int:
    if not text.isdigit() or int(text) < 1:
        raise argparse.ArgumentTypeError(f"--loop wants a number of times >= 1, got {text!r}")
    return int(text)


class _Player:
    """The open buses of a play and the acknowledgements (own echoes) counted on them."""

    def __init__(self, endpoints: dict[str, str]) -> None:
        self.buses: dict[str, can.BusABC] = {}
        self.sent: Counter[str] = Counter()
        self.acked: Counter[str] = Counter()
        for name, endpoint in endpoints.items():
            try:
                self.buses[name] = can.Bus(interface="gatewaylab", channel=endpoint, receive_own_messages=True,
                                           name="gatewaylab-play", shutdown_timeout=0.5)
            except (can.CanError, OSError) as exc:
                self.close()
                raise can.CanOperationError(f"cannot open bus {name} ({endpoint}): {exc}") from None

    def drain(self, until: float) -> None:
        """Count own echoes until the monotonic time ``until`` (at least one look at every bus)."""
        while True:
            for name, bus in self.buses.items():
                while (msg := bus.recv(0)) is not None:
                    if not msg.is_rx and not msg.is_error_frame:
                        self.acked[name] += 1
            left = until - time.monotonic()
            if left <= 0:
                return
            if len(self.buses) == 1:
                (name, bus), = self.buses.items()
                msg = bus.recv(min(left, 0.05))
                if msg is not None and not msg.is_rx and not msg.is_error_frame:
                    self.acked[name] += 1
            else:
                time.sleep(min(left, 0.002))

    def send(self, name: str, frame: CanFrame) -> None:
        self.buses[name].send(frame.to_message(), timeout=ACK_TIMEOUT)
        self.sent[name] += 1

    def hopeless(self) -> str | None:
        """Why waiting for acknowledgements would not help (a bus not acknowledging), or None."""
        for name, bus in self.buses.items():
            state = getattr(bus, "controller_state", None)
            if getattr(bus, "tx_errors", 0) or (state is not None and state.name in ("BUS_OFF", "ERROR_PASSIVE")):
                how = f"controller {state.name.lower().replace('_', '-')}" if state is not None else "errors"
                return f"bus {name}: {how}"
        return None

    def all_acked(self) -> bool:
        return all(self.acked[name] >= self.sent[name] for name in self.buses)

    def close(self) -> None:
        for bus in self.buses.values():
            bus.shutdown()


def _play(player: _Player, plays: Playlist, speed: float, loops: int, timing: bool) -> None:
    """Send ``plays`` ``loops`` times; loop k starts where loop k-1's last frame was due."""
    start = time.monotonic()
    for loop in range(loops):
        base = loop * plays.span
        for offset, name, frame in plays.frames:
            if timing:
                player.drain(start + (base + offset) / speed)
            player.send(name, frame)


def cmd_play(args: argparse.Namespace) -> int:
    """``gatewaylab play TARGET TRACE``."""
    trace = Path(args.trace)
    try:
        filters = parse_filters(args.filter or [])
        window = TimeWindow.parse(args.window_from, args.window_to)
        mapping = dict(args.map or ())
        if not trace.is_file():
            raise TraceError(f"{trace}: no such trace file")
        plays = playlist(trace, args.bus, mapping, filters, window)
        endpoints = {name: bus_target(args.target, name) for name in sorted({n for _, n, _ in plays.frames})}
    except (CandumpSyntaxError, ConfigError, EndpointError) as exc:
        print(f"gatewaylab: {exc}", file=sys.stderr)
        return 2
    skipped = _skipped(plays)
    if not plays.frames:
        print(f"{trace.name}: no frame to send{skipped}")
        return 0
    try:
        player = _Player(endpoints)
    except can.CanError as exc:
        print(f"gatewaylab: {exc}", file=sys.stderr)
        return 1
    try:
        _play(player, plays, args.speed, args.loop, not args.no_timing)
        deadline = time.monotonic() + ACK_TIMEOUT
        while not player.all_acked() and time.monotonic() < deadline and player.hopeless() is None:
            player.drain(time.monotonic() + 0.05)
        sent = sum(player.sent.values())
        per_bus = ", ".join(f"{name}: {player.sent[name]}" for name in sorted(player.sent))
        if not player.all_acked():
            missing = sum(max(0, player.sent[n] - player.acked[n]) for n in player.sent)
            why = player.hopeless()
            print(f"gatewaylab: {missing} of {sent} frames were not acknowledged"
                  + (f" ({why})" if why else f" within {ACK_TIMEOUT} s")
                  + ": is another node on the bus? (a lone client: run the rig with --acker)", file=sys.stderr)
            return 1
        loops = f" in {args.loop} loops" if args.loop > 1 else ""
        print(f"{trace.name}: {sent} frame{'' if sent == 1 else 's'} sent{loops} ({per_bus}){skipped}")
        return 0
    except KeyboardInterrupt:
        print(f"{trace.name}: interrupted after {sum(player.sent.values())} frames", file=sys.stderr)
        return 130
    except can.CanError as exc:
        print(f"gatewaylab: {exc}", file=sys.stderr)
        return 1
    finally:
        player.close()


def _skipped(plays: Playlist) -> str:
    parts = []
    if plays.error_frames:
        parts.append(f"{plays.error_frames} error frames")
    if plays.filtered:
        parts.append(f"{plays.filtered} filtered out")
    for channel, count in sorted(plays.unmapped.items()):
        parts.append(f"{count} of channel {channel} (not in --map)")
    return f"; not sent: {', '.join(parts)}" if parts else ""


def add_subcommand(subparsers: Any) -> None:
    """Add ``play`` to the gatewaylab CLI."""
    p = subparsers.add_parser("play", help="send a trace file onto a rig's bus (canplayer)",
                              description=_DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("target", metavar="TARGET", help="the rig's ready file or a bus endpoint")
    p.add_argument("trace", metavar="TRACE", help="trace file (.asc .blf .csv .log .trc .txt .pcap .pcapng)")
    p.add_argument("--bus", default="can0", help="the bus (ready file) every frame goes to without --map "
                   "(default can0)")
    p.add_argument("--map", type=_map_arg, action="append", metavar="CHANNEL=BUS",
                   help="send the trace's channel CHANNEL to bus BUS (canplayer -I); repeatable; then only "
                        "mapped channels are played")
    p.add_argument("--speed", type=_speed_arg, default=1.0, metavar="X", help="X times the trace's pace (default 1)")
    p.add_argument("-t", "--no-timing", action="store_true", help="ignore the timestamps: send back to back")
    p.add_argument("--loop", type=_loop_arg, default=1, metavar="N", help="play the trace N times (default 1)")
    p.add_argument("-f", "--filter", action="append", metavar="ID:MASK",
                   help="candump filter, as `dump -f`: ID:MASK, ID~MASK (inverted), j (join); repeatable")
    p.add_argument("--from", dest="window_from", metavar="T|+S", default=None,
                   help="play from T seconds of trace time (as `dump --replay` counts), or +S after the first frame")
    p.add_argument("--to", dest="window_to", metavar="T|+D", default=None,
                   help="play up to T seconds of trace time, or +D seconds after --from")
    p.set_defaults(func=cmd_play)
