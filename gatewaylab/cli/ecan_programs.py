"""``gatewaylab ecan simple-loop | sdo-probe | cia402``: the IgH package's programs (15.4, 15.6).

Each runs on a real line through SOEM (``-i IFNAME``, root) or in process on a rig file
(``--rig RIG.toml``: simulated clock; the axes and bit rates come from the rig unless given).
They print master_period statistics, working-counter and parse errors and their own results;
``--json`` prints one JSON object instead. Exit codes: 0 ok, 1 the run failed (an axis missed its
target, WKC / parse errors, a refused SDO, no answer), 2 a wrong command line.
"""

from __future__ import annotations

import argparse
import json
import struct
import sys
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from typing import IO, TYPE_CHECKING, Any

from gatewaylab.cli.ec import open_line
from gatewaylab.common.errors import GatewaylabError, LocalError
from gatewaylab.hosts.ecanlite.adapter import AdapterConfig, EcanAdapter, SlaveConfig, find_ecanlite
from gatewaylab.hosts.ecanlite.cia402 import Axis, Cia402, parse_axes
from gatewaylab.hosts.ecanlite.demo import rig_axes, rig_channel_bitrates
from gatewaylab.hosts.ecanlite.port import ChannelConfig, McanPort, PortConfig, RxFrame
from gatewaylab.hosts.ethercat.backend import MasterBackend
from gatewaylab.od import SdoAbort

if TYPE_CHECKING:
    from gatewaylab.rig.runtime import Rig

__all__ = ["add_host_commands"]


class Usage(LocalError):
    """A wrong command line (exit 2)."""


@dataclass(frozen=True, slots=True)
class Line:
    """The line a host program runs on: its master backend and, with ``--rig``, the rig in process."""

    backend: MasterBackend
    rig: Rig | None


@contextmanager
def _line(args: argparse.Namespace) -> Iterator[Line]:
    if bool(args.interface) == bool(args.rig):
        raise Usage("give the line: -i IFNAME (real interface, root) or --rig RIG.toml (in process)")
    with open_line(args.interface, args.rig, Usage) as (backend, rig):
        yield Line(backend, rig)


def _positions(line: Line, count: int | None) -> list[int]:
    found = [s.position for s in find_ecanlite(line.backend)]
    if not found:
        raise GatewaylabError("no ECAN-Lite on the line")
    if count is not None:
        if count > len(found):
            raise Usage(f"--slaves {count}: the line has {len(found)} ECAN-Lite(s)")
        found = found[:count]
    return found


def _channel(line: Line, args: argparse.Namespace, slave: int, ch: int) -> ChannelConfig:
    """Channel setup from --bitrate/--data-bitrate, else the rig's bus, else 1 Mbit/s classic."""
    bitrate, data = args.bitrate, getattr(args, "data_bitrate", None)
    if bitrate is None and line.rig is not None:
        bitrate, data_r = rig_channel_bitrates(line.rig).get(slave, {}).get(ch, (1_000_000, None))
        data = data if data is not None else data_r
    bitrate = bitrate or 1_000_000
    return ChannelConfig.canfd(bitrate, data) if data else ChannelConfig.classic(bitrate)


def _build(line: Line, args: argparse.Namespace, positions: list[int], channels: dict[int, set[int]],
           tx_result: bool = False) -> tuple[EcanAdapter, McanPort]:
    cfg = AdapterConfig(tuple(SlaveConfig(p, args.pdo_n) for p in positions), cycle_us=args.cycle_us,
                        dc_sync0=getattr(args, "dc_sync0", False), dc_cycle_us=getattr(args, "dc_cycle_us", 0) or 0,
                        dc_shift_us=getattr(args, "dc_shift_us", 0) or 0,
                        skip_sdo_config=getattr(args, "skip_sdo_config", False))
    adapter = EcanAdapter(line.backend, cfg)
    ports = {k: PortConfig({ch: _channel(line, args, k, ch) for ch in sorted(chs)}, profile=getattr(args, "profile", 0),
                           tx_result=tx_result, align4=getattr(args, "align4", False))
             for k, chs in channels.items()}
    port = McanPort(adapter, ports)
    adapter.start(op_timeout=10.0)
    return adapter, port


def _errors(adapter: EcanAdapter, port: McanPort) -> dict[str, Any]:
    diag = port.last_parse_diag
    return {"cycles": adapter.cycles, "wkc_errors": adapter.wkc_errors, "parse_errors": port.parse_errors,
            "torn_images": port.torn_images, "lost_images": port.lost_images,
            "incomplete_images": port.incomplete_images, "last_parse_diag": asdict(diag) if diag else None}


def _print_common(report: dict[str, Any], out: IO[str]) -> None:
    p = report["master_period"]
    print(f"master_period: {p['count']} periods, min {p['min_us']:.1f} us, max {p['max_us']:.1f} us, "
          f"mean {p['mean_us']:.1f} us, p99 {p['p99_us']:.1f} us, max error {p['max_error_us']:.1f} us", file=out)
    e = report["errors"]
    print(f"cycles {e['cycles']}, WKC errors {e['wkc_errors']}, parse errors {e['parse_errors']}, "
          f"torn images {e['torn_images']}, lost images {e['lost_images']}", file=out)
    if e["last_parse_diag"]:
        print(f"last parse_diag: {e['last_parse_diag']}", file=out)


@contextmanager
def _progress(args: argparse.Namespace, total: int, what: str) -> Iterator[Callable[[int], None] | None]:
    show = args.progress if args.progress is not None else (sys.stderr.isatty() and total >= 1000)
    if not show:
        yield None
        return
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                  console=Console(stderr=True)) as bar:
        task = bar.add_task(what, total=total)

        def advance(done: int) -> None:
            if done % 50 == 0 or done == total:
                bar.update(task, completed=done)
        yield advance


def _emit(args: argparse.Namespace, report: dict[str, Any], text: Callable[[IO[str]], None], out: IO[str]) -> None:
    if args.json:
        print(json.dumps(report, indent=None, sort_keys=True), file=out)
    else:
        text(out)


# ------------------------------------------------------------------------------------ simple-loop
def cmd_simple_loop(args: argparse.Namespace, out: IO[str]) -> int:
    """15.4 ``igh_simple_loop``: one frame per cycle on every channel, TX_RESULT, what came back."""
    channels = sorted(ch for ch in range(4) if args.channels >> ch & 1)
    if not channels:
        raise Usage("--channels selects no channel")
    with _line(args) as line:
        positions = _positions(line, 1 if args.slave is None else args.slave + 1)
        k = len(positions) - 1 if args.slave is not None else 0
        positions = [positions[k]]
        adapter, port = _build(line, args, positions, {0: set(channels)}, tx_result=True)
        sent = dict.fromkeys(channels, 0)
        ok = dict.fromkeys(channels, 0)
        failed = dict.fromkeys(channels, 0)
        received = dict.fromkeys(channels, 0)

        def tally(frames: Iterable[RxFrame]) -> None:
            """Count what came back: received frames and TX results (ok or failed) per channel."""
            for r in frames:
                received[r.channel] = received.get(r.channel, 0) + 1
            for res in port.take_tx_results():
                if res.request > 0 and res.code <= 1:
                    ok[res.channel] = ok.get(res.channel, 0) + 1
                else:
                    failed[res.channel] = failed.get(res.channel, 0) + 1

        with _progress(args, args.cycles, "simple-loop") as progress:
            for i in range(args.cycles):
                port.cycle_begin()
                tally(port.receive())
                for ch in channels:
                    port.send_can(0, ch, args.id + ch, struct.pack("<Q", i))
                    sent[ch] += 1
                port.cycle_end()
                adapter.wait_period()
                if progress:
                    progress(i + 1)
        for _ in range(5):      # the last TX results and frames
            tally(port.exchange())
        adapter.stop()
        report: dict[str, Any] = {"command": "simple-loop", "slave": positions[0],
                  "master_period": adapter.master_period.summary(adapter.period), "errors": _errors(adapter, port),
                  "channels": {str(ch): {"sent": sent[ch], "tx_ok": ok[ch], "tx_failed": failed.get(ch, 0),
                                         "received": received.get(ch, 0)} for ch in channels}}

    def text(o: IO[str]) -> None:
        _print_common(report, o)
        for ch, c in report["channels"].items():
            print(f"CAN{ch}: sent {c['sent']}, TX_RESULT ok {c['tx_ok']}, failed {c['tx_failed']}, "
                  f"received {c['received']}", file=o)
    _emit(args, report, text, out)
    bad = report["errors"]["wkc_errors"] or report["errors"]["parse_errors"] or any(
        c["tx_ok"] != c["sent"] for c in report["channels"].values())
    return 1 if bad else 0


# ------------------------------------------------------------------------------------ sdo-probe
def cmd_sdo_probe(args: argparse.Namespace, out: IO[str]) -> int:
    """15.4 ``igh_canopen_sdo_probe``: one SDO upload from a CANopen node behind the gateway."""
    with _line(args) as line:
        positions = _positions(line, args.slave + 1)
        positions = [positions[args.slave]]
        adapter, port = _build(line, args, positions, {0: {args.channel}})
        cia = Cia402(port, [Axis(0, args.channel, args.node)], sdo_timeout=args.timeout)
        try:
            (value,) = cia.sdo_transfer([(cia.axes[0].axis, args.index, args.sub, None)], args.timeout + 1.0)
        except SdoAbort as exc:
            adapter.stop()
            print(f"gatewaylab ecan sdo-probe: node {args.node} 0x{args.index:04X}:{args.sub:02X}: SDO abort "
                  f"0x{exc.code:08X} {exc}", file=sys.stderr)
            return 1
        adapter.stop()
        number = int.from_bytes(value[:8], "little") if 0 < len(value) <= 8 else None
        report = {"command": "sdo-probe", "node": args.node, "index": args.index, "sub": args.sub,
                  "channel": args.channel, "slave": positions[0], "data": value.hex(), "value": number,
                  "master_period": adapter.master_period.summary(adapter.period), "errors": _errors(adapter, port)}

    def text(o: IO[str]) -> None:
        shown = f"0x{number:0{2 * len(value)}x} {number}" if number is not None else repr(value)
        print(f"node {args.node} 0x{args.index:04X}:{args.sub:02X} = {shown} [{value.hex(' ')}]", file=o)
        _print_common(report, o)
    _emit(args, report, text, out)
    return 0


# ------------------------------------------------------------------------------------ cia402
def cmd_cia402(args: argparse.Namespace, out: IO[str]) -> int:
    """15.6 ``igh_cia402_10axis_demo``: startup, ``--cycles`` of CSP motion by ``--step``, results."""
    given: list[Axis] = []
    if args.axes:
        try:
            given = parse_axes(args.axes, args.step)
        except LocalError as exc:
            raise Usage(f"--axes: {exc}") from None
    with _line(args) as line:
        if given:
            axes = given
            positions = _positions(line, args.slaves)
        elif line.rig is not None:
            rig_pos, axes = rig_axes(line.rig, args.step)
            if args.slaves is not None and args.slaves > len(rig_pos):
                raise Usage(f"--slaves {args.slaves}: the rig has {len(rig_pos)} ECAN-Lite(s)")
            positions = rig_pos[:args.slaves] if args.slaves else rig_pos
            axes = [a for a in axes if a.slave < len(positions)]
            if not axes:
                raise Usage("the rig has no drives on the ECAN-Lite channels: give --axes")
        else:
            axes = [Axis(0, 0, 1, args.step)]
            positions = _positions(line, args.slaves)
        for a in axes:
            if a.slave >= len(positions):
                raise Usage(f"axis node {a.node_id} on slave {a.slave}: only {len(positions)} ECAN-Lite(s) in use")
        channels: dict[int, set[int]] = {k: set() for k in range(len(positions))}
        for a in axes:
            channels[a.slave].add(a.channel)
        for chs in channels.values():
            if not chs:
                chs.add(0)
        adapter, port = _build(line, args, positions, channels)
        cia = Cia402(port, axes, motion_div=args.motion_div, sdo_timeout=args.sdo_timeout)
        if args.sched_rpdo_us is not None or args.sched_sync_us is not None:
            cia.set_scheduled_tx(None if args.sched_rpdo_us is None else args.sched_rpdo_us * 1000,
                                 None if args.sched_sync_us is None else args.sched_sync_us * 1000)
        try:
            cia.startup(configure=True, timeout=max(5.0, 10 * args.sdo_timeout))
        except SdoAbort as exc:
            adapter.stop()
            print(f"gatewaylab ecan cia402: SDO abort 0x{exc.code:08X} {exc}", file=sys.stderr)
            return 1
        with _progress(args, args.cycles, "cia402") as progress:
            cia.run(args.cycles, progress)
        settled = cia.settle(args.settle_s)
        results = cia.results()
        cia.disable_all()
        adapter.stop()
        report = {"command": "cia402", "slaves": positions, "pdo_n": args.pdo_n, "cycle_us": args.cycle_us,
                  "master_period": adapter.master_period.summary(adapter.period), "errors": _errors(adapter, port),
                  "sdo_errors": cia.sdo_errors, "settled": settled,
                  "axes": [dict(asdict(r), error=r.error, reached=r.reached()) for r in results]}

    def text(o: IO[str]) -> None:
        _print_common(report, o)
        for r in results:
            print(f"axis slave {r.slave} CAN{r.channel} node {r.node_id}: start {r.start} target {r.target} "
                  f"actual {r.actual} error {r.error} statusword 0x{r.statusword:04X} TPDOs {r.tpdos} "
                  f"{'reached' if r.reached() else 'NOT reached'}", file=o)
    _emit(args, report, text, out)
    bad = report["errors"]["wkc_errors"] or report["errors"]["parse_errors"] or not all(r.reached() for r in results)
    return 1 if bad else 0


# ------------------------------------------------------------------------------------ registration
def _int(text: str) -> int:
    try:
        return int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None


def _run(func: Callable[[argparse.Namespace, IO[str]], int]) -> Callable[[argparse.Namespace], int]:
    def run(args: argparse.Namespace) -> int:
        try:
            return func(args, sys.stdout)
        except Usage as exc:
            print(f"gatewaylab ecan {args.ecan_command}: {exc}", file=sys.stderr)
            return 2
        except (GatewaylabError, TimeoutError) as exc:
            print(f"gatewaylab ecan {args.ecan_command}: {exc}", file=sys.stderr)
            return 1
    return run


def _line_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("-i", "--interface", metavar="IFNAME", help="EtherCAT interface (SOEM through pysoem, root)")
    p.add_argument("--rig", metavar="RIG.toml", help="run the rig file in process on a simulated clock")
    p.add_argument("--pdo-n", type=int, default=3, choices=range(1, 25), metavar="1..24",
                   help="PDO size multiplier N, 128*N bytes each way (default 3)")
    p.add_argument("--cycle-us", type=int, default=1000, metavar="N", help="process data cycle (default 1000)")
    p.add_argument("--bitrate", type=int, default=None, metavar="BPS",
                   help="nominal bit rate (default: the rig's bus, else 1000000)")
    p.add_argument("--json", action="store_true", help="one JSON object on stdout")
    p.add_argument("--progress", action="store_true", default=None, help="progress bar even when not a terminal")
    p.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")


_EPILOG = {
    "simple-loop": "examples:\n  gatewaylab ecan simple-loop --rig rig.toml --cycles 100\n"
                   "  gatewaylab ecan simple-loop -i eth1 --channels 0x01 --bitrate 500000 --json",
    "sdo-probe": "examples:\n  gatewaylab ecan sdo-probe --rig rig.toml --node 1 --index 0x1000 --sub 0\n"
                 "  gatewaylab ecan sdo-probe -i eth1 --node 1 --index 0x1000 --sub 0 --bitrate 1000000",
    "cia402": "examples:\n  gatewaylab ecan cia402 --rig rig.toml --cycles 2000 --step 20\n"
              "  gatewaylab ecan cia402 -i eth1 --slaves 1 --axes 0:0:1,0:1:2 --pdo-n 3 --cycle-us 1000 "
              "--cycles 10000 --dc-sync0 --dc-cycle-us 1000 --dc-shift-us 700",
}


def add_host_commands(ecan_sub: Any) -> None:
    """Register simple-loop, sdo-probe and cia402 under ``gatewaylab ecan``."""
    fmt = argparse.RawDescriptionHelpFormatter
    p = ecan_sub.add_parser("simple-loop", help="send and receive on every channel (15.4 igh_simple_loop)",
                            description=cmd_simple_loop.__doc__, epilog=_EPILOG["simple-loop"], formatter_class=fmt)
    _line_args(p)
    p.add_argument("--slave", type=int, default=None, metavar="K", help="the K-th ECAN-Lite of the line (default 0)")
    p.add_argument("--channels", type=_int, default=0x0F, metavar="MASK", help="channels to use (default 0x0F)")
    p.add_argument("--data-bitrate", type=int, default=None, metavar="BPS", help="CAN FD data bit rate")
    p.add_argument("--cycles", type=int, default=100, metavar="N", help="cycles to run (default 100)")
    p.add_argument("--id", type=_int, default=0x100, metavar="ID", help="CAN id of channel 0; channel k sends id+k")
    p.set_defaults(func=_run(cmd_simple_loop))

    p = ecan_sub.add_parser("sdo-probe", help="SDO upload from a CANopen node behind the gateway (15.4)",
                            description=cmd_sdo_probe.__doc__, epilog=_EPILOG["sdo-probe"], formatter_class=fmt)
    _line_args(p)
    p.add_argument("--slave", type=int, default=0, metavar="K", help="the K-th ECAN-Lite of the line (default 0)")
    p.add_argument("--channel", type=int, default=0, choices=range(4), metavar="0..3", help="MCAN channel")
    p.add_argument("--node", type=int, required=True, choices=range(1, 128), metavar="1..127", help="node id")
    p.add_argument("--index", type=_int, required=True, metavar="INDEX")
    p.add_argument("--sub", type=_int, default=0, metavar="SUB")
    p.add_argument("--timeout", type=float, default=1.0, metavar="S", help="SDO timeout in seconds (default 1)")
    p.set_defaults(func=_run(cmd_sdo_probe))

    p = ecan_sub.add_parser("cia402", help="CiA 402 axes in CSP through the gateway (15.6 demo)",
                            description=cmd_cia402.__doc__, epilog=_EPILOG["cia402"], formatter_class=fmt)
    _line_args(p)
    p.add_argument("--slaves", type=int, default=None, metavar="N", help="ECAN-Lites taking part (default all)")
    p.add_argument("--axes", default=None, metavar="S:C:N[:STEP],...",
                   help="axis table: slave:channel:node[:step] (default: the rig's drives, or 0:0:1)")
    p.add_argument("--cycles", type=int, default=1000, metavar="N", help="motion cycles (default 1000)")
    p.add_argument("--step", type=int, default=0, metavar="S", help="target increments per motion cycle (default 0)")
    p.add_argument("--motion-div", type=int, default=1, metavar="N", help="targets every N cycles (default 1)")
    p.add_argument("--profile", type=int, default=0, choices=(0, 1, 4, 5), help="PDO encapsulation profile")
    p.add_argument("--align4", action="store_true", help="4-byte aligned frame packets (8.3.1)")
    p.add_argument("--skip-sdo-config", action="store_true", help="skip the gateway's startup SDOs")
    p.add_argument("--dc-sync0", action="store_true", help="enable DC SYNC0")
    p.add_argument("--dc-cycle-us", type=int, default=0, metavar="N", help="SYNC0 cycle (default --cycle-us)")
    p.add_argument("--dc-shift-us", type=int, default=0, metavar="N", help="SYNC0 shift")
    p.add_argument("--sched-rpdo-us", type=int, default=None, metavar="N",
                   help="send the RPDOs N us after SYNC0 (8.4 scheduled transmit; needs --dc-sync0)")
    p.add_argument("--sched-sync-us", type=int, default=None, metavar="N", help="send SYNC N us after SYNC0")
    p.add_argument("--sdo-timeout", type=float, default=0.5, metavar="S",
                   help="SDO timeout per transfer to a drive in seconds (default 0.5)")
    p.add_argument("--settle-s", type=float, default=1.0, metavar="S", help="time to reach the final targets")
    p.set_defaults(func=_run(cmd_cia402))
