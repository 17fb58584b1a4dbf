"""``gatewaylab migrate compare --wire``: the master side, one run of the application over SOEM.

``python -m gatewaylab.migrate.compare_wire IFNAME KIND BITRATE APP.py OUT.json [--seconds S]
[--cycle-us US]`` runs inside the network namespace holding the master's end of a veth pair (the
rig layer starts it there, ``gatewaylab/cli/migrate_rig.py``): an :class:`EthercatHost` on
:class:`PysoemBackend` (real time), the gateway of KIND found on the line by its identity, the
application's ``run(bus)`` with a :class:`~.compare_run.RecordingBus`. OUT.json gets the
application's events in Unix time (``clock.wall_epoch + clock.now()``), the one time base it shares
with the rig process that records the CAN bus. Exit 0, or 1 with the error on stderr.
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import subprocess
import sys
import tempfile
import threading
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.errors import GatewaylabError
from gatewaylab.ethercat.wire_netns import net_unavailable, veth_namespace
from gatewaylab.hosts.canhost.host import EthercatHost
from gatewaylab.hosts.ethercat.pysoem_backend import PysoemBackend
from gatewaylab.migrate.compare import AppEvent, AppEventKind, Frame, Recording
from gatewaylab.migrate.compare_run import (
    PDO_N,
    SETTLE_S,
    CanRecorder,
    Recorder,
    RecordingBus,
    Runner,
    load_app,
    position_of,
    to_frame,
)

#: SOEM waits this long for the process data frame (a loaded machine; never asserted)
PD_TIMEOUT_US = 50_000
#: attempts to bring the line up (a veth link just brought up may lose the first frames)
OPEN_ATTEMPTS = 3


#: seconds the master process may take at most (start-up, the application, shutdown) beyond --seconds
RUN_TIMEOUT = 600.0
_names = itertools.count()


class MasterProcessError(GatewaylabError):
    """The master child process of a wire run failed; the message is its last line on stderr."""


@dataclass
class WireLine:
    """The rig side of one wire run: the rig's CAN bus to record, its Unix time base, a stopper."""

    bus: CanRecorder
    wall_epoch: float
    stop: Callable[[], None]


#: ``open_rig(gateway_kind, interface)`` -> the rig with that gateway, running in real time with its
#: EtherCAT segment on ``interface`` (the rig layer's, gatewaylab/cli/migrate_rig.py)
RealtimeOpener = Callable[[str, str], WireLine]


def wire_unavailable() -> str | None:
    """None when this process may make a veth pair in a namespace and run SOEM, else why not."""
    return net_unavailable("pysoem")


def wire_runner(open_rig: RealtimeOpener) -> Runner:
    """Runs each gateway's copy of the rig in real time on a fresh veth pair and the application with
    SOEM as master in a child process inside the namespace (this module's :func:`main`)."""

    def run(gateway: tuple[str, str, str], app_path: Path, seconds: float | None, cycle_us: int) -> Recording:
        kind, _prefix, display = gateway
        frames: list[tuple[CanFrame, float]] = []
        with veth_namespace("gl-cmp-", "glcmp") as (ns, emu, mst), tempfile.TemporaryDirectory() as tmp:
            line = open_rig(kind, emu)
            epoch = line.wall_epoch

            def record(frame: CanFrame, t: float) -> None:
                frames.append((frame, epoch + t))

            line.bus.add_monitor(record)
            try:
                out = Path(tmp) / "app.json"
                cmd = ["ip", "netns", "exec", ns, sys.executable, "-m", "gatewaylab.migrate.compare_wire", mst, kind,
                       str(line.bus.bitrate), str(app_path), str(out), "--cycle-us", str(cycle_us)]
                if seconds is not None:
                    cmd += ["--seconds", repr(seconds)]
                proc = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                                      timeout=RUN_TIMEOUT + (seconds or 0.0), check=False)
                sys.stderr.write(proc.stderr)
                if proc.returncode != 0:
                    last = proc.stderr.strip().splitlines()[-1:] or [f"exit {proc.returncode}"]
                    raise MasterProcessError(f"the master process failed: {last[0]}")
                data = json.loads(out.read_text(encoding="utf-8"))
                threading.Event().wait(SETTLE_S)       # answers to the last frames reach the bus
            finally:
                line.bus.remove_monitor(record)
                line.stop()
        t0, duration = float(data["t0"]), float(data["duration"])
        # up to the end: the master process drains frames still in flight when run() returned
        bus = tuple(to_frame(f, t - t0) for f, t in frames if t >= t0)
        return Recording(display, bus, events_from_rows(data["events"], t0), duration)

    return run


def event_rows(events: list[AppEvent], offset: float) -> list[list[Any]]:
    """Events as JSON rows [kind, t + offset, id, extended, rtr, data hex]."""
    return [[e.kind.value, e.frame.t + offset, e.frame.can_id, e.frame.extended, e.frame.rtr, e.frame.data.hex()]
            for e in events]


def events_from_rows(rows: list[list[Any]], t0: float) -> tuple[AppEvent, ...]:
    """The inverse of :func:`event_rows`, times relative to ``t0``."""
    return tuple(AppEvent(AppEventKind(k), Frame(t - t0, i, bytes.fromhex(d), bool(x), bool(r)))
                 for k, t, i, x, r, d in rows)


def _open(ifname: str, kind: str, bitrate: int, cycle_us: int) -> EthercatHost:
    host = EthercatHost(PysoemBackend(ifname, pd_timeout_us=PD_TIMEOUT_US), cycle_us=cycle_us)
    try:
        pos = position_of(host.backend, kind)
        if kind == "esd_can_ethercat":
            host.add_esd(pos, bitrate, name="esd")
        else:
            host.add_ecanlite(pos, 0, bitrate, pdo_n=PDO_N, name="ecanlite")
        host.start(timeout=10.0)
    except BaseException:
        host.close()
        raise
    return host


def _start(ifname: str, kind: str, bitrate: int, cycle_us: int) -> EthercatHost:
    for _ in range(OPEN_ATTEMPTS - 1):
        with contextlib.suppress(Exception):
            return _open(ifname, kind, bitrate, cycle_us)
    return _open(ifname, kind, bitrate, cycle_us)     # the last attempt's error reaches the caller


def run(ifname: str, kind: str, bitrate: int, app_path: str, out: Path, seconds: float | None,
        cycle_us: int) -> None:
    """The child's work: the application through the gateway of ``kind`` with SOEM on ``ifname``;
    its events, in Unix time, into ``out``."""
    app = load_app(app_path)
    host = _start(ifname, kind, bitrate, cycle_us)
    name = next(iter(host.channels))
    clock = host.clock
    rec = Recorder(clock.now())
    bus = RecordingBus(host, name, rec)
    try:
        with contextlib.redirect_stdout(sys.stderr):
            if seconds is not None:
                app(bus, seconds=seconds)
            else:
                app(bus)
        duration = clock.now() - rec.t0
    finally:
        bus.shutdown()
        host.close()
    epoch = clock.wall_epoch
    out.write_text(json.dumps({"t0": epoch + rec.t0, "duration": duration,
                               "events": event_rows(rec.app, epoch + rec.t0)}), encoding="utf-8")


def main(argv: list[str] | None = None) -> int:
    """Entry point of the master child process (module docstring); exit 1 with the error on stderr."""
    p = argparse.ArgumentParser(prog="python -m gatewaylab.migrate.compare_wire")
    p.add_argument("ifname")
    p.add_argument("kind", choices=("esd_can_ethercat", "ecanlite"))
    p.add_argument("bitrate", type=int)
    p.add_argument("app")
    p.add_argument("out", type=Path)
    p.add_argument("--seconds", type=float)
    p.add_argument("--cycle-us", type=int, default=1000)
    args = p.parse_args(argv)
    try:
        run(args.ifname, args.kind, args.bitrate, args.app, args.out, args.seconds, args.cycle_us)
    except Exception as exc:
        traceback.print_exc()
        print(f"{type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
