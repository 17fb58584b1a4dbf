"""Soak: the default rig under load for minutes (held under load and faults, ``make soak``).

``gatewaylab run`` (the default rig: CAN FD bus ``can0``, IDX, three drives) in its own process; three
client processes on the python-can ``gatewaylab`` interface send 2,000 frames/s together (each its
own CAN id, a sequence number in the data) and listen to each other; a fourth process runs a
canopen SDO loop against drive ``axis2`` (node 2): download + upload of 0x30B0, upload of 0x1018:04
(expedited) and 0x1008 (segmented).

Printed: frames sent per client and received of it by every other client (must be equal, in order),
SDO transfers and failures (0), RSS of the rig at start (after a warm-up) and at the end (growth
< 10 MB), and the p99 round trip a client sees (send -> its own echo). Exit status 1 when a bound is
violated. Clients wait for the echo of their last frame before closing (frames still queued in a
closing client are not the soak's subject).

    python -m benchmarks.soak --minutes 10      # make soak (SOAK_MINUTES=60 make soak)
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import sys
import tempfile
import time
from dataclasses import dataclass, field
from multiprocessing.synchronize import Barrier, Event
from pathlib import Path
from typing import Any

from gatewaylab.rig.process import RigProcess

BASE_ID = 0x110  # free in the CANopen predefined connection set (between TIME 0x100 and TPDO1 0x181)
RSS_GROWTH_LIMIT = 10 * 1024 * 1024
DRAIN_TIMEOUT = 20.0
SDO_NODE = 2


@dataclass
class SoakResult:
    seconds: float
    sent: dict[int, int] = field(default_factory=dict)
    #: received[k][j]: frames of client k that client j received (j != k)
    received: dict[int, dict[int, int]] = field(default_factory=dict)
    out_of_order: int = 0
    echoes_missing: int = 0
    sdo_transfers: int = 0
    sdo_failures: int = 0
    sdo_errors: list[str] = field(default_factory=list)
    rss_start: int = 0
    rss_end: int = 0
    rtt_p99: float = 0.0
    rtt_median: float = 0.0
    violations: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.violations

    def report(self) -> str:
        lines = [f"soak: {self.seconds:.0f} s, {len(self.sent)} clients, {sum(self.sent.values())} frames"]
        for k in sorted(self.sent):
            got = ", ".join(f"client {j}: {n}" for j, n in sorted(self.received.get(k, {}).items()))
            lines.append(f"  client {k}: sent {self.sent[k]}, received by {got}")
        lines.append(f"  out of order: {self.out_of_order}, own echoes missing: {self.echoes_missing}")
        lines.append(f"  SDO transfers: {self.sdo_transfers}, failures: {self.sdo_failures}")
        for err in self.sdo_errors[:5]:
            lines.append(f"    {err}")
        lines.append(f"  rig RSS: start {self.rss_start / 1e6:.1f} MB, end {self.rss_end / 1e6:.1f} MB, "
                     f"growth {(self.rss_end - self.rss_start) / 1e6:+.1f} MB (limit 10 MB)")
        lines.append(f"  client round trip: median {self.rtt_median * 1e3:.2f} ms, p99 {self.rtt_p99 * 1e3:.2f} ms")
        lines.append("  OK" if self.ok else "  VIOLATED: " + "; ".join(self.violations))
        return "\n".join(lines)


def _rss(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    return 0


def _percentile(values: list[float], q: float) -> float:
    if not values:
        return 0.0
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


# -- child processes ------------------------------------------------------------------------------
def _client(k: int, endpoint: str, rate: float, seconds: float, clients: int, start: Barrier,
            totals: Any, totals_known: Event, results: Any) -> None:
    """Send ``rate`` frames/s for ``seconds`` and count the others' frames until their totals arrived."""
    import can

    bus = can.Bus(interface="gatewaylab", channel=endpoint, receive_own_messages=True, name=f"soak-{k}")
    my_id = BASE_ID + k
    sent_at: list[float] = []
    rtts: list[float] = []
    counts = dict.fromkeys(range(clients), 0)
    next_seq = dict.fromkeys(range(clients), 0)
    out_of_order = 0

    def take(msg: can.Message | None) -> None:
        nonlocal out_of_order
        if msg is None or not BASE_ID <= msg.arbitration_id < BASE_ID + clients:
            return
        j = msg.arbitration_id - BASE_ID
        seq = int.from_bytes(msg.data[:4], "little")
        if seq != next_seq[j]:
            out_of_order += 1
        next_seq[j] = seq + 1
        counts[j] += 1
        if j == k and seq < len(sent_at):
            rtts.append(time.perf_counter() - sent_at[seq])

    try:
        start.wait(60)
        t0 = time.perf_counter()
        period = 1.0 / rate
        while True:
            now = time.perf_counter()
            if now - t0 >= seconds:
                break
            due = int((now - t0) / period) + 1
            while len(sent_at) < due:
                seq = len(sent_at)
                sent_at.append(time.perf_counter())
                bus.send(can.Message(arbitration_id=my_id, is_extended_id=False,
                                     data=seq.to_bytes(4, "little") + bytes(4)), timeout=5.0)
            take(bus.recv(timeout=min(period, max(0.0, t0 + seconds - time.perf_counter()))))
        results.put(("sent", k, len(sent_at)))
        deadline = time.monotonic() + DRAIN_TIMEOUT
        while counts[k] < len(sent_at) and time.monotonic() < deadline:  # own echo of the last frame
            take(bus.recv(timeout=0.1))
        totals_known.wait(DRAIN_TIMEOUT + 60)
        deadline = time.monotonic() + DRAIN_TIMEOUT
        while any(counts[j] < totals[j] for j in range(clients)) and time.monotonic() < deadline:
            take(bus.recv(timeout=0.1))
        results.put(("done", k, {"counts": counts, "out_of_order": out_of_order, "rtts": rtts}))
    finally:
        bus.shutdown()


def _sdo_loop(endpoint: str, start: Barrier, stop: Event, results: Any) -> None:
    import canopen

    network = canopen.Network()
    network.connect(interface="gatewaylab", channel=endpoint, name="soak-sdo")
    transfers = failures = 0
    errors: list[str] = []
    try:
        node = network.add_node(SDO_NODE, canopen.ObjectDictionary())  # type: ignore[no-untyped-call]
        node.sdo.RESPONSE_TIMEOUT = 2.0
        start.wait(60)
        i = 0
        while not stop.is_set():
            i += 1
            value = (i * 7919) & 0x7FFFFFFF
            steps = (
                ("download 0x30B0", lambda v=value: node.sdo.download(0x30B0, 0, v.to_bytes(4, "little")), None),
                ("upload 0x30B0", lambda: node.sdo.upload(0x30B0, 0), value.to_bytes(4, "little")),
                ("upload 0x1018:04", lambda: node.sdo.upload(0x1018, 4), (0x1002).to_bytes(4, "little")),
                ("upload 0x1008", lambda: node.sdo.upload(0x1008, 0), None),
            )
            for what, call, expected in steps:
                transfers += 1
                try:
                    got = call()  # type: ignore[no-untyped-call]
                    if expected is not None and got != expected:
                        raise ValueError(f"got {got!r}, expected {expected!r}")
                    if what == "upload 0x1008" and not got:
                        raise ValueError("empty device name")
                except Exception as exc:
                    failures += 1
                    if len(errors) < 20:
                        errors.append(f"{what}: {type(exc).__name__}: {exc}")
    finally:
        results.put(("sdo", 0, {"transfers": transfers, "failures": failures, "errors": errors}))
        network.disconnect()


# -- the rig ---------------------------------------------------------------------------------------
def run_soak(seconds: float, *, rate: float = 2000.0, clients: int = 3, rig_file: str | None = None,
             bus: str = "can0", warmup: float | None = None) -> SoakResult:
    """Run the soak for ``seconds`` and return the figures (``result.violations`` lists broken bounds)."""
    ctx = mp.get_context("spawn")
    result = SoakResult(seconds)
    with tempfile.TemporaryDirectory(prefix="gatewaylab-soak-") as tmp:
        rig = RigProcess(rig_file, workdir=tmp)
        proc = rig.proc
        procs: list[Any] = []
        try:
            endpoint = rig.endpoint(bus)
            start = ctx.Barrier(clients + 2)
            totals = ctx.Array("q", clients)
            totals_known = ctx.Event()
            stop_sdo = ctx.Event()
            results = ctx.Queue()
            for k in range(clients):
                procs.append(ctx.Process(target=_client, name=f"soak-client-{k}", args=(
                    k, endpoint, rate / clients, seconds, clients, start, totals, totals_known, results)))
            procs.append(ctx.Process(target=_sdo_loop, name="soak-sdo", args=(endpoint, start, stop_sdo, results)))
            for p in procs:
                p.start()
            start.wait(120)
            t0 = time.monotonic()
            warm = min(10.0, seconds * 0.1) if warmup is None else warmup
            time.sleep(warm)
            result.rss_start = _rss(proc.pid)
            done: dict[int, dict[str, Any]] = {}
            sdo: dict[str, Any] | None = None
            deadline = t0 + seconds + DRAIN_TIMEOUT * 3 + 60
            while (len(done) < clients or sdo is None) and time.monotonic() < deadline:
                try:
                    kind, k, payload = results.get(timeout=1.0)
                except Exception:
                    if len(result.sent) == clients:
                        stop_sdo.set()
                    continue
                if kind == "sent":
                    result.sent[k] = payload
                    totals[k] = payload
                    if len(result.sent) == clients:
                        totals_known.set()
                        stop_sdo.set()
                elif kind == "done":
                    done[k] = payload
                elif kind == "sdo":
                    sdo = payload
            result.rss_end = _rss(proc.pid)
            rtts: list[float] = []
            for k, payload in done.items():
                rtts.extend(payload["rtts"])
                result.out_of_order += payload["out_of_order"]
                result.echoes_missing += result.sent.get(k, 0) - payload["counts"][k]
                for j in range(clients):
                    if j != k:
                        result.received.setdefault(j, {})[k] = payload["counts"][j]
            result.rtt_p99 = _percentile(rtts, 0.99)
            result.rtt_median = _percentile(rtts, 0.5)
            if sdo is not None:
                result.sdo_transfers = sdo["transfers"]
                result.sdo_failures = sdo["failures"]
                result.sdo_errors = sdo["errors"]
            if proc.poll() is not None:
                result.violations.append(f"the rig exited with {proc.returncode}")
        finally:
            for p in procs:
                p.join(30)
                if p.is_alive():
                    p.kill()
            rig.stop()
    _check(result, clients)
    return result


def _check(r: SoakResult, clients: int) -> None:
    v = r.violations
    if len(r.sent) != clients or len(r.received) != clients:
        v.append(f"{clients - len(r.sent)} clients did not report")
    for k, n in r.sent.items():
        for j, got in r.received.get(k, {}).items():
            if got != n:
                v.append(f"client {j} received {got} of client {k}'s {n} frames")
    if r.out_of_order:
        v.append(f"{r.out_of_order} frames out of order")
    if r.echoes_missing:
        v.append(f"{r.echoes_missing} own echoes missing")
    if r.sdo_transfers == 0 or r.sdo_failures:
        v.append(f"SDO: {r.sdo_failures} failures in {r.sdo_transfers} transfers")
    if r.rss_end - r.rss_start >= RSS_GROWTH_LIMIT:
        v.append(f"rig RSS grew by {(r.rss_end - r.rss_start) / 1e6:.1f} MB")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.soak", description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=float(os.environ.get("SOAK_MINUTES", "10")))
    parser.add_argument("--rate", type=float, default=2000.0, help="frames/s of all clients together")
    parser.add_argument("--clients", type=int, default=3)
    parser.add_argument("--rig", default=None, help="rig file (default: gatewaylab's default rig)")
    args = parser.parse_args(argv)
    print(f"soak: {args.rig or 'default rig'}, {args.clients} clients, {args.rate:.0f} frames/s, "
          f"{args.minutes:g} min", flush=True)
    result = run_soak(args.minutes * 60, rate=args.rate, clients=args.clients, rig_file=args.rig)
    print(result.report())
    return 0 if result.ok else 1


if __name__ == "__main__":
    sys.exit(main())
