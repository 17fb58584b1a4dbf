"""The EtherCAT wire's tail under load, stalls and bring-ups, each figure beside the C echo measured in the
same run under the same load. Printed, never asserted.

Every part runs twice: ``quiet`` (the machine as it is) and ``loaded`` (one more process spinning on a CPU,
a CI runner's ordinary background load; GL_BENCH_LOADS=quiet or =loaded runs one). The rig is started as a
user starts it (``gatewaylab run`` on a veth end, default settings: no busy polling), the masters run in a
namespace on the other end.

1. **Residence**: the mixed segment (ECAN-Lite N = 3 with 4 CAN FD channels, 1,000 frames/s each way on
   each; an esd CAN-EtherCAT; 8 ``ethercat_drive`` in CSP; 8 ``ethercat_io``) cycled by SOEM at 1 kHz with
   its 2 ms timeout; a kernel-timestamped capture on the emulator's veth end gives request in -> reply out:
   p50 / p99 / p99.9 / max (targets: p99.9 < 500 us quiet, < 1 ms loaded). Before the rig, the C echo
   (benchmarks/echo.c) is paced the same way on the same pair: its residence and the frames its raw
   master lost (2 ms) are the floor of this machine in this run.
2. **SOEM**: that run's wrong working counters, beside the frames the C echo lost (target: no more).
3. **KickCAT bring-up** with its default timeouts and no retries (``bus.init`` with KickCAT's default
   watchdog, ``create_mapping``) of an ECAN-Lite, an esd and an ``ethercat_io``, each alone on a rig:
   successes of GL_BENCH_TRIES (default 100) tries (targets: >= 99 quiet, >= 97 loaded); every failure
   explained from captures on both ends: the request never reached the emulator (lost by the VM), the
   emulator answered late or dropped it, or it answered in time and the VM delivered late.
4. **Stall**: the soak segment under SOEM, the rig stopped (SIGSTOP) for 200 ms: replies older than the
   rig's ``max_residence_ms`` that reach the master (target 0; a rig without that key is measured
   against 5 ms). The master writes its cycle number into the first output bytes of every LRW
   (capture.cycle_tag), so each reply is paired with exactly its own request (capture.pairs).

GL_BENCH_CYCLES_TAIL sets the cycles of parts 1-2 (default 100,000; else GL_BENCH_SECONDS x 1,000 when
that is set), GL_BENCH_TRIES the KickCAT tries, GL_BENCH_TAIL_PARTS the parts run (comma-separated of
``residence`` (1 and 2), ``kickcat``, ``stall``; default all). Needs root (namespace + veth), pysoem and
kickcat.
"""

from __future__ import annotations

import contextlib
import json
import os
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from benchmarks.capture import Capture, Pair, Tail, pairs, read_records
from benchmarks.soak_ethercat import (
    SOAK_PLAN,
    SOEM_TIMEOUT_US,
    STALL_LEAD_NS,
    LineResult,
    Plan,
    fmt_us,
    residence_limit_ms,
    rig_toml,
    run_line,
    wire_counters,
)
from benchmarks.targets import record
from benchmarks.wire import CpuHog, env_int, loads, run_master, skip_reason, veth_namespace

#: the mixed segment of the residence and SOEM rows
MIXED_PLAN = Plan(drives=8, ios=8, ecan_n=3, ecan_channels=4, esd=True, can_drive=False, frames_per_ms=4,
                  peer_rate=1000.0, can_rate=0.0)
#: targets: p99.9 residence (us) by load
RESIDENCE_P999_US = {"quiet": 500.0, "loaded": 1000.0}
#: targets: KickCAT bring-ups that must succeed of 100, by load
KICKCAT_OK_OF_100 = {"quiet": 99, "loaded": 97}
#: KickCAT's own defaults: the link's frame timeout (Link.h) and Bus::init's watchdog (Bus.h)
KICKCAT_LINK_TIMEOUT_US = 2000.0
KICKCAT_WATCHDOG_S = 0.1
#: the devices brought up by KickCAT, each alone on a rig
KICKCAT_KINDS = ("ecanlite", "esd", "io")
STALL_S = 0.2
#: the parts of GL_BENCH_TAIL_PARTS
PARTS = ("residence", "kickcat", "stall")


def parts() -> tuple[str, ...]:
    """The parts to run (GL_BENCH_TAIL_PARTS, comma-separated, default all of :data:`PARTS`)."""
    wanted = tuple(w.strip() for w in os.environ.get("GL_BENCH_TAIL_PARTS", ",".join(PARTS)).split(",") if w.strip())
    unknown = [w for w in wanted if w not in PARTS]
    if unknown:
        raise ValueError(f"GL_BENCH_TAIL_PARTS: unknown part(s) {', '.join(unknown)} (known: {', '.join(PARTS)})")
    return wanted


def cycles() -> int:
    """Cycles of the residence / SOEM run."""
    if "GL_BENCH_CYCLES_TAIL" in os.environ:
        return env_int("GL_BENCH_CYCLES_TAIL", 100_000)
    if "GL_BENCH_SECONDS" in os.environ:
        return max(100, int(float(os.environ["GL_BENCH_SECONDS"]) * 1000))
    return 100_000


# ------------------------------------------------------------------------------------- 1 + 2: residence
@dataclass
class EchoFloor:
    """The C echo paced like the master on the same pair: frames its raw master lost (2 ms), its residence."""

    cycles: int = 0
    lost: int = 0
    residence: Tail | None = None
    note: str = ""


def echo_floor(ns: str, emu: str, mst: str, n: int, folder: str) -> EchoFloor:
    """benchmarks/echo.c on ``emu`` (built here), bench_ethercat's raw master paced at 1 kHz for ``n`` cycles
    with a 2 ms timeout, a capture on the echo's end."""
    from benchmarks.bench_ethercat import CEcho, build_c_echo

    program, why = build_c_echo(folder)
    if program is None:
        return EchoFloor(note=f"no C echo: {why}")
    echo = CEcho(program, emu)
    cap = Capture(emu, Path(folder) / "echo.cap")
    try:
        t0 = time.time_ns()
        raw = run_master(ns, "benchmarks.bench_ethercat", ["--master", "raw", mst, "1", str(n / 1000.0)],
                         n / 1000.0 * 3 + 120)
        t1 = time.time_ns()
    finally:
        path = cap.stop()
        echo.stop()
    tail = Tail((float(SOEM_TIMEOUT_US),))
    for p in pairs(read_records(path), False):
        if t0 <= p.t_request < t1:
            tail.add(p)
    return EchoFloor(raw["paced"]["cycles"], raw["paced"]["lost"], tail)


def residence_line(tail: Tail | None) -> str:
    if tail is None or not tail.delays_us:
        return "no frames"
    p = tail.percentiles()
    return (f"p50 {fmt_us(p['p50_us'])} p99 {fmt_us(p['p99_us'])} p99.9 {fmt_us(p['p999_us'])} "
            f"max {fmt_us(p['max_us'])} (of {tail.requests} frames, {tail.unanswered} not answered)")


@dataclass
class TailRun:
    """Parts 1 and 2 under one load."""

    load: str
    line: LineResult
    echo: EchoFloor


def residence_run(load: str, n: int) -> TailRun:
    """The C echo, then the mixed segment under SOEM, both under ``load`` on one veth pair."""
    floor: list[EchoFloor] = []
    with tempfile.TemporaryDirectory(prefix="gl-bench-tail-") as folder:
        line = run_line(MIXED_PLAN, n, load, residence=True, keep=True,
                        before_rig=lambda ns, emu, mst: floor.append(echo_floor(ns, emu, mst, n, folder)))
    return TailRun(load, line, floor[0] if floor else EchoFloor(note="the echo did not run"))


def print_residence(run: TailRun) -> tuple[bool, bool]:
    """The lines of parts 1 and 2; (residence target met, SOEM target met)."""
    line, echo = run.line, run.echo
    p999 = line.residence.percentiles()["p999_us"] if line.residence and line.residence.delays_us else float("inf")
    limit = RESIDENCE_P999_US[run.load]
    wrong = line.master.get("wrong_wkc", -1)
    print(f"[{run.load}] {MIXED_PLAN.describe()}, SOEM 1 kHz x {line.master.get('cycles', line.cycles)}, "
          f"{SOEM_TIMEOUT_US} us timeout")
    print(f"  residence, emulator:  {residence_line(line.residence)}")
    print(f"  residence, C echo:    {residence_line(echo.residence)}{'  ' + echo.note if echo.note else ''}")
    print(f"  SOEM wrong working counters {wrong}; C echo's raw master lost {echo.lost} of {echo.cycles}; "
          f"replies after 2 ms on the master's wire {line.late}, never answered "
          f"{line.master_tail.unanswered if line.master_tail else '?'}; dropped late by the rig "
          f"{line.counters.get('frames_dropped_late', 'not reported')} (reached the idle wire thread already late: "
          f"{line.counters.get('frames_late_on_arrival', 'not reported')})")
    print(f"  SOEM's own longest pause between two cycles {fmt_us(line.master.get('gap_max_us', float('nan')))} "
          f"({line.master.get('gaps_over_100ms', '?')} over 100 ms)")
    print("  slaves that left OP while SOEM cycled: "
          + (", ".join(f"{n} {st}" for n, st in line.left_op.items()) if line.left_op else "none"))
    ecan = line.master.get("ecan") or {}
    print(f"  CAN: master -> ECAN-Lite {ecan.get('sent', 0)}, ECAN-Lite -> master {ecan.get('received', 0)}; "
          f"peers sent {line.can.get('sent', '?')}, heard {line.can.get('heard', '?')} of the master's; TX FIFO "
          f"drops {ecan.get('tx_fifo_drops', '?')}, RX cache drops {ecan.get('rx_cache_drops', '?')}"
          + (f" (not read: {ecan['counters_error'][:100]})" if "counters_error" in ecan else ""))
    for note in line.errors:
        print(f"  note: {note}")
    met_res, met_soem = p999 < limit, 0 <= wrong <= echo.lost
    print(f"  targets: p99.9 residence < {fmt_us(limit)}: {'met' if met_res else 'NOT met'}; "
          f"wrong WKC <= C echo lost: {'met' if met_soem else 'NOT met'}")
    return met_res, met_soem


# -------------------------------------------------------------------------------------------- 3: KickCAT
def kickcat_tries(iface: str, tries: int) -> list[dict[str, Any]]:
    """In the namespace: ``tries`` bring-ups, each on a fresh link with KickCAT's defaults; per try
    whether it passed, the error, and its kernel-comparable time window (ns)."""
    import kickcat

    # SCHED_FIFO 3, as KickCAT's README runs a master (`chrt -f 80`): its Socket::read sleeps between polls
    # and gives up once a sleep overran the deadline without a last look (docs/decisions.md)
    with contextlib.suppress(OSError):
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(3))
    out = []
    for i in range(tries):
        t0 = time.time_ns()
        error = ""
        link: Any = None
        bus: Any = None
        try:
            link = kickcat.create_link(iface, "")
            bus = kickcat.Bus(link)
            bus.init(KICKCAT_WATCHDOG_S)
            bus.create_mapping(4096)
        except RuntimeError as exc:
            error = " ".join(str(exc).split())
        t1 = time.time_ns()
        out.append({"try": i, "ok": not error, "error": error, "t0": t0, "t1": t1})
        bus = link = None      # the link's socket closes before the next try opens one
        time.sleep(0.05)
    return out


def classify(t0: int, t1: int, master: Sequence[Pair], emulator: Sequence[Pair],
             timeout_us: float = KICKCAT_LINK_TIMEOUT_US) -> str:
    """Why a bring-up between kernel times ``t0`` and ``t1`` failed, from the pairs of the master's capture
    and of the emulator's: the first request the master saw unanswered or answered later than its timeout,
    followed to the emulator's end (same datagram header, the first one after it was sent)."""
    bad = next((p for p in master if t0 <= p.t_request < t1
                and (p.t_reply is None or (p.delay_us or 0.0) > timeout_us)), None)
    if bad is None:
        slowest = max((p.delay_us or 0.0 for p in master if t0 <= p.t_request < t1), default=0.0)
        return (f"no frame lost or late on the wire (slowest reply {fmt_us(slowest)}): the master's own timing (its "
                f"process not scheduled in time) or an answer it refused (a working counter, an EEPROM or state poll "
                f"that ran out)")
    seen = next((e for e in emulator if e.key == bad.key and bad.t_request <= e.t_request < bad.t_request + 50_000_000),
                None)
    if seen is None:
        return "lost by the VM: the request never reached the emulator"
    if seen.t_reply is None:
        return "dropped by the emulator: the request arrived, no reply left"
    residence = seen.delay_us or 0.0
    if residence > timeout_us:
        return f"late from the emulator: residence {fmt_us(residence)}"
    got = "never" if bad.delay_us is None else f"after {fmt_us(bad.delay_us)}"
    return f"late in the VM: the emulator answered in {fmt_us(residence)}, the master's end saw it {got}"


@dataclass
class KickcatResult:
    kind: str
    load: str
    tries: int = 0
    ok: int = 0
    failures: list[str] = field(default_factory=list)
    dropped_late: int | None = None


def kickcat_run(kind: str, load: str, tries: int) -> KickcatResult:
    """``kind`` alone on a rig, ``tries`` KickCAT bring-ups under ``load``, captures on both ends."""
    from gatewaylab.rig.process import RigProcess

    plan = {"ecanlite": Plan(drives=0, ios=0, ecan_channels=1, can_drive=False, can_rate=0.0),
            "esd": Plan(drives=0, ios=0, ecan_channels=0, esd=True, can_drive=False, can_rate=0.0),
            "io": Plan(drives=0, ios=1, ecan_channels=0, can_drive=False, can_rate=0.0)}[kind]
    result = KickcatResult(kind, load)
    with tempfile.TemporaryDirectory(prefix="gl-bench-kc-") as tmp, \
            veth_namespace("gl-kc-", "glq") as (ns, emu, mst), CpuHog(load):
        path = Path(tmp) / "rig.toml"
        path.write_text(rig_toml(plan, emu, residence_limit_ms()))
        with RigProcess(path, workdir=tmp, timeout=120) as rig:
            caps = [Capture(mst, Path(tmp) / "m.cap", ("ip", "netns", "exec", ns)), Capture(emu, Path(tmp) / "e.cap")]
            try:
                answer = run_master(ns, "benchmarks.bench_ethercat_tail", ["--kickcat", mst, str(tries)],
                                    tries * 30 + 120)
            finally:
                files = [c.stop() for c in caps]
            result.dropped_late = wire_counters(rig.ready_file).get("frames_dropped_late")
        master = list(pairs(read_records(files[0]), True))
        emulator = list(pairs(read_records(files[1]), False))
    for t in answer["tries"]:
        result.tries += 1
        if t["ok"]:
            result.ok += 1
        else:
            why = classify(t["t0"], t["t1"], master, emulator)
            result.failures.append(f"try {t['try']}: {t['error'][:120]} -- {why}")
    return result


def print_kickcat(r: KickcatResult) -> bool:
    need = KICKCAT_OK_OF_100[r.load] * r.tries / 100.0
    met = r.ok >= need
    dropped = "" if r.dropped_late is None else f"; dropped late by the rig {r.dropped_late}"
    print(f"[{r.load}] KickCAT bring-up of {r.kind} (default timeouts, no retries): {r.ok}/{r.tries} "
          f"(target >= {need:g}: {'met' if met else 'NOT met'}){dropped}")
    for f in r.failures:
        print(f"    {f}")
    return met


# ------------------------------------------------------------------------------------------------ 4: stall
def stall_run(load: str) -> LineResult:
    """The soak segment under SOEM, the rig stopped for 200 ms one second into the counted cycles."""
    return run_line(SOAK_PLAN, 3000, load, residence=True, keep=False, stall_after_s=1.0, stall_s=STALL_S)


def print_stall(r: LineResult) -> bool:
    """The stall's lines: replies older than the limit of the frames of its window (LineResult.stall_window:
    from just before it to a second after it, the backlog), each explained, and in the whole run; True when
    none reached the master in the window and every pair there was exact (capture.pairs)."""
    limit = r.limit_text()
    w = r.stall_tail
    stale = w.over.get(r.limit_ms * 1000.0, 0) if w is not None else -1
    unsure = w.ambiguous if w is not None else -1
    met = stale == 0 and unsure == 0
    print(f"[{r.load}] {STALL_S * 1000:.0f} ms stall (SIGSTOP) under SOEM at 1 kHz, {SOAK_PLAN.describe()}: "
          f"replies older than {limit} that reached the master, of the frames sent from {STALL_LEAD_NS / 1e6:g} ms "
          f"before the stall to a second after it: {stale} of {w.requests if w else '?'} (never answered "
          f"{w.unanswered if w else '?'}, oldest reply {fmt_us(w.worst_us) if w else '?'}; target 0: "
          f"{'met' if met else 'NOT met'}); in the whole run of {r.master.get('cycles', '?')} cycles: {r.stale}")
    m = r.master_tail
    if unsure or (m is not None and m.ambiguous):
        print(f"    NOT exact: {unsure} pairs of the stall's window, {m.ambiguous if m else '?'} of the run, had "
              f"another request with the same key waiting (the cycle tag did not reach the first data bytes)")
    print(f"    SOEM wrong working counters {r.master.get('wrong_wkc', '?')}; never answered "
          f"{m.unanswered if m else '?'}; oldest reply {fmt_us(m.worst_us) if m else '?'}; dropped late by the rig "
          f"{r.counters.get('frames_dropped_late', 'not reported')}; left OP: "
          + (", ".join(f"{n} {st}" for n, st in r.left_op.items()) if r.left_op else "none"))
    for note in r.errors:
        print(f"    note: {note}")
    return met


# ---------------------------------------------------------------------------------------------------- run
def _record(key: str, parts: dict[str, tuple[str, bool]]) -> None:
    if parts:
        record(key, "; ".join(f"{load}: {text}" for load, (text, _) in parts.items()),
               all(ok for _, ok in parts.values()))


def main() -> None:
    skip = skip_reason("pysoem", "kickcat")
    if skip:
        print(skip)
        return
    n, tries, wanted = cycles(), env_int("GL_BENCH_TRIES", 100), parts()
    residence: dict[str, tuple[str, bool]] = {}
    soem: dict[str, tuple[str, bool]] = {}
    kick: dict[str, tuple[str, bool]] = {}
    stall: dict[str, tuple[str, bool]] = {}
    for load in loads():
        if "residence" in wanted:
            try:
                run = residence_run(load, n)
                met_res, met_soem = print_residence(run)
                p = run.line.residence.percentiles() if run.line.residence else {"p999_us": float("nan")}
                echo_p = run.echo.residence.percentiles() if run.echo.residence else {"p999_us": float("nan")}
                residence[load] = (f"p99.9 {fmt_us(p['p999_us'])} (C echo {fmt_us(echo_p['p999_us'])})", met_res)
                soem[load] = (f"{run.line.master.get('wrong_wkc')} wrong WKC, C echo lost {run.echo.lost}", met_soem)
            except RuntimeError as exc:
                print(f"[{load}] residence run failed: {' '.join(str(exc).split())[-600:]}")
                residence[load] = soem[load] = ("the run failed", False)
        if "kickcat" in wanted:
            results = [kickcat_run(kind, load, tries) for kind in KICKCAT_KINDS]
            met = [print_kickcat(r) for r in results]
            kick[load] = (", ".join(f"{r.kind} {r.ok}/{r.tries}" for r in results), all(met))
        if "stall" in wanted:
            try:
                s = stall_run(load)
                ok = print_stall(s)
                w = s.stall_tail
                stall[load] = (f"{w.over.get(s.limit_ms * 1000.0, 0) if w else '?'} stale replies after the stall"
                               + (f" ({w.ambiguous} pairs not exact)" if w and w.ambiguous else ""), ok)
            except RuntimeError as exc:
                print(f"[{load}] stall run failed: {' '.join(str(exc).split())[-600:]}")
                stall[load] = ("the run failed", False)
    _record("residence", residence)
    _record("wkc_echo", soem)
    _record("kickcat", kick)
    _record("stall", stall)


def targets() -> None:
    """The whole benchmark is the targets' measurement."""
    main()


if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[1] == "--kickcat":
        print(json.dumps({"tries": kickcat_tries(sys.argv[2], int(sys.argv[3]))}))
    else:
        main()
