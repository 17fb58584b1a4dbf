"""EtherCAT CiA 402 drives per segment at 1 kHz over a veth pair with SOEM (pysoem), CSP.

For 1, 2, 4, 8, 16 drives: SOEM brings the line to OP, enables every drive (0x06 / 0x07 / 0x0F)
and runs a CSP ramp paced at 1 kHz; then the same number of ``ethercat_io`` slaves in the same
run. Reported: wrong working counters (a frame later than SOEM's 2 ms counts as one), median /
p99 / max cycle round trip, and the largest number of drives with 0 wrong working counters and
p99 < 500 us. Then the segment search: 8, 16, 24, 32, 40 drives, each with
8 ethercat_io in the same segment, upward until the first segment that fails (wrong working counter,
p99 >= 500 us, a drive fault, a failed bring-up); target: >= 32 drives + 8 io. ``--max-drives N``
(GL_BENCH_MAX_DRIVES) ends it at N drives. Printed, never asserted.

Needs root (network namespace + veth); prints why and returns otherwise. GL_BENCH_SECONDS sets the
paced run per line (default 30 s). The master runs in a subprocess inside the namespace on CPU 0,
the emulator's wire thread on CPU 1, busy polling (the rig's ``busy_poll = true``, the setting for
latency work on a dedicated CPU: docs/decisions.md); ``GL_BENCH_BUSY_POLL=0`` measures the
rig's default instead (blocking in select, 200 us spin after each frame).
"""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
import time
from collections.abc import Sequence
from typing import Any

from benchmarks.targets import record
from benchmarks.wire import (
    bench_seconds,
    go_init,
    last_json,
    pin,
    request_op,
    rtt_summary,
    run_in_namespace,
    ticks,
    veth_namespace,
)

COUNTS = (1, 2, 4, 8, 16)
#: the segment search: these many drives, each time with IO_WITH ethercat_io
SEARCH = (8, 16, 24, 32, 40)
IO_WITH = 8
P99_LIMIT_US = 500.0
RX = struct.Struct("<HiihB")     # the drive's default RxPDO 0x1600


# ---------------------------------------------------------------------------------- master side
def _bring_up(m: Any, count: int) -> str:
    """INIT -> PREOP -> SAFEOP -> OP; an error text or ''."""
    import pysoem

    try:
        found = m.config_init()
        if found != count:
            return f"config_init found {found} slaves, expected {count}"
        m.config_map()
    except (pysoem.ConfigMapError, pysoem.WkcError, pysoem.SdoError) as exc:   # a mailbox frame came too late
        return f"{type(exc).__name__}"
    if m.state_check(pysoem.SAFEOP_STATE, 50_000) != pysoem.SAFEOP_STATE:
        return "SAFEOP not reached"
    for s in m.slaves:
        s.output = bytes(len(s.output))
    return "" if request_op(m, 20_000, 400) else "OP not reached"


def enable_drives(m: Any, drives: Sequence[Any], timeout_us: int = 20_000) -> int:
    """Shutdown / switch on / enable operation (0x06, 0x07, 0x0F) in CSP on every slave of ``drives``
    (the others keep their outputs), 20 cycles each; how many report 'operation enabled'."""
    for cw in (0x06, 0x07, 0x0F):
        for s in drives:
            s.output = RX.pack(cw, 0, 0, 0, 8)
        for _ in range(20):
            m.send_processdata()
            m.receive_processdata(timeout_us)
    return sum(1 for s in drives if _statusword(s) & 0x6F == 0x27)


def _statusword(slave: Any) -> int:
    """The statusword, first in the default TxPDO 0x1A00; 0 when SOEM mapped fewer than 2 input bytes."""
    return int.from_bytes(bytes(slave.input)[:2], "little")


def csp_output(i: int) -> bytes:
    """Cycle ``i``'s RxPDO for every drive: enabled, CSP, +-40000 increment ramps of 2000 cycles."""
    return RX.pack(0x0F, 20 * (i % 2000 if (i // 2000) % 2 == 0 else 2000 - i % 2000), 0, 0, 8)


def drive_faults(drives: Sequence[Any]) -> int:
    """How many of ``drives`` report a fault in their statusword."""
    return sum(1 for s in drives if _statusword(s) & 0x08)


def master(iface: str, drives: int, ios: int, seconds: float) -> dict[str, Any]:
    """SOEM on a segment of ``drives`` drives then ``ios`` ethercat_io: bring-up, the drives enabled in CSP,
    then ``seconds`` paced at 1 kHz."""
    import pysoem

    pin(0)
    m = pysoem.Master()
    m.open(iface)
    error = ""
    for _attempt in range(3):   # bring-up again when a register access came later than SOEM's 2 ms
        error = _bring_up(m, drives + ios)
        if not error:
            break
        time.sleep(0.5)     # a scan that found no slave: the emulator side was stalled for a moment
    if error:
        return {"error": error}
    expected = m.expected_wkc
    drive_slaves, io_slaves = m.slaves[:drives], m.slaves[drives:]
    enabled = enable_drives(m, drive_slaves)
    period = 0.001
    n = int(seconds / period)
    rtts: list[float] = []
    wrong = 0
    for i in ticks(n, period):
        data = csp_output(i)
        for s in drive_slaves:
            s.output = data
        for s in io_slaves:
            s.output = bytes([i & 0xFF]) * len(s.output)
        t0 = time.perf_counter()
        m.send_processdata()
        wkc = m.receive_processdata(2000)
        rtts.append(time.perf_counter() - t0)
        if wkc != expected:
            wrong += 1
    faults = drive_faults(drive_slaves)
    go_init(m)
    out: dict[str, Any] = {"cycles": n, "wrong_wkc": wrong, **rtt_summary(rtts), "faults": faults}
    if drives:
        out["enabled"], out["drives"] = enabled, drives
    return out


# ---------------------------------------------------------------------------------- emulator side
def _run_line(ns: str, emu: str, mst: str, drives: int, ios: int, seconds: float) -> dict[str, Any]:
    """One segment (``drives`` EtherCAT drives, then ``ios`` ethercat_io) against the master subprocess."""
    from gatewaylab.common.clock import RealTimeClock
    from gatewaylab.devices.ethercat_drive import EthercatDrive
    from gatewaylab.devices.ethercat_io.device import create_io_slave
    from gatewaylab.ethercat.segment import Segment
    from gatewaylab.ethercat.wire import WireTransport

    clock = RealTimeClock()
    devices = [EthercatDrive(clock, f"GL-Drive #{i}", serial=0x3001 + i) for i in range(drives)]
    slaves = [d.slave for d in devices] + [create_io_slave(clock, f"GL-IO #{i}", revision=i + 1) for i in range(ios)]
    wire = WireTransport(Segment(slaves), emu, clock, drive_clock=True, cpu=1,
                         busy_poll=busy_poll())
    wire.start()
    cpu_s = 0.0
    try:
        proc = run_in_namespace(ns, "benchmarks.bench_ethercat_drive",
                                ["--master", mst, str(drives), str(ios), str(seconds)], seconds * 3 + 120,
                                python_flags=("-X", "faulthandler"))
    except subprocess.TimeoutExpired:
        return {"error": "the master did not finish"}
    finally:
        cpu_s = wire_thread_cpu(wire)
        wire.stop()
        with clock.lock:
            for d in devices:
                d.stop()
    if proc.returncode != 0:
        lines = [ln.strip() for ln in proc.stderr.strip().splitlines() if ln.strip()]
        if any(ln.startswith("Timeout (") for ln in lines):     # faulthandler: the master hung
            frames = [ln for ln in lines if ln.startswith("File ") and "benchmarks" in ln]
            return {"error": "master hung at " + (frames[0].split(", ")[-1] if frames else "?")}
        return {"error": lines[-1] if lines else "master failed"}
    result = last_json(proc)
    if wire.frames_in:  # the wire thread's CPU time per frame (bring-up included): independent of the load
        result["wire_cpu_us"] = 1e6 * cpu_s / wire.frames_in
    return result


def busy_poll() -> bool:
    """The wire thread busy polls (``busy_poll = true``) unless GL_BENCH_BUSY_POLL=0."""
    return os.environ.get("GL_BENCH_BUSY_POLL", "1") != "0"


def wire_thread_cpu(wire: Any) -> float:
    """CPU seconds the wire thread has used so far (0.0 where the platform cannot tell)."""
    thread = getattr(wire, "_thread", None)
    if thread is None or thread.ident is None or not hasattr(time, "pthread_getcpuclockid"):
        return 0.0
    try:
        return time.clock_gettime(time.pthread_getcpuclockid(thread.ident))
    except OSError:
        return 0.0


def _ok(r: dict[str, Any]) -> bool:
    """0 wrong working counters, p99 under the limit, no drive faulted, every drive enabled."""
    return ("error" not in r and r["wrong_wkc"] == 0 and r["p99_us"] < P99_LIMIT_US and not r.get("faults")
            and r.get("enabled") == r.get("drives"))


def _cell(r: dict[str, Any]) -> str:
    if "error" in r:
        return f"{r['error'][:44]:<44}"
    cpu = f"  wire CPU {r['wire_cpu_us']:5.0f} us/frame" if "wire_cpu_us" in r else ""
    return (f"wrong wkc {r['wrong_wkc']:>4}  median {r['median_us']:6.1f}  p99 {r['p99_us']:7.1f}  "
            f"max {r['max_us']:8.1f} us{cpu}")


def search(ns: str, emu: str, mst: str, seconds: float, max_drives: int) -> list[tuple[int, dict[str, Any]]]:
    """Segments of SEARCH drives + IO_WITH ethercat_io, upward, up to ``max_drives`` drives, until the first
    one that fails (a wrong working counter, p99 >= 500 us, a fault or a failed bring-up)."""
    rows: list[tuple[int, dict[str, Any]]] = []
    for drives in SEARCH:
        if drives > max_drives:
            break
        r = _run_line(ns, emu, mst, drives, IO_WITH, seconds)
        rows.append((drives, r))
        print(f"{drives:>2} drives + {IO_WITH} io: {_cell(r)}" +
              (f" enabled {r.get('enabled', 0)}/{drives}" if "error" not in r else ""), flush=True)
        if not _ok(r):
            break
    return rows


def _search_and_record(ns: str, emu: str, mst: str, seconds: float) -> None:
    max_drives = int(os.environ.get("GL_BENCH_MAX_DRIVES", str(SEARCH[-1])))
    print(f"segment search: drives (CSP) + {IO_WITH} ethercat_io, pysoem over veth, {seconds:g} s at 1 kHz each, "
          f"up to {max_drives} drives (--max-drives), stopping at the first failure; wire thread "
          f"{'busy polling (busy_poll = true)' if busy_poll() else 'blocking (the default, GL_BENCH_BUSY_POLL=0)'}")
    rows = search(ns, emu, mst, seconds, max_drives)
    best = max((d for d, r in rows if _ok(r)), default=0)
    failed = [(d, r) for d, r in rows if not _ok(r)]
    text = f"{best} drives + {IO_WITH} io (p99 {dict(rows)[best]['p99_us']:.0f} us)" if best else "none"
    if failed:
        text += f"; {failed[0][0]} drives + {IO_WITH} io: {' '.join(_cell(failed[0][1]).split())}"
    elif rows and rows[-1][0] < SEARCH[-1]:
        text += f" (search stopped at --max-drives {max_drives})"
    print(f"largest segment with 0 wrong working counters and p99 < {P99_LIMIT_US:.0f} us: {text}")
    record("segment", text + ("" if busy_poll() else " (wire thread blocking: GL_BENCH_BUSY_POLL=0)"), best >= 32)


def targets() -> None:
    """The segment search alone (target: >= 32 drives + 8 ethercat_io)."""
    seconds = bench_seconds(30)
    if seconds is None:
        return
    with veth_namespace("gl-bd-", "glbd") as (ns, emu, mst):
        _search_and_record(ns, emu, mst, seconds)


def main() -> None:
    seconds = bench_seconds(30)
    if seconds is None:
        return
    rows: list[tuple[int, dict[str, Any], dict[str, Any]]] = []
    with veth_namespace("gl-bd-", "glbd") as (ns, emu, mst):
        for count in COUNTS:
            drive = _run_line(ns, emu, mst, count, 0, seconds)
            io = _run_line(ns, emu, mst, 0, count, seconds)
            rows.append((count, drive, io))
        print(f"CiA 402 drives (CSP) vs ethercat_io slaves per segment, pysoem over veth, {seconds:.0f} s at 1 kHz "
              "each")
        for count, drive, io in rows:
            enabled = f" enabled {drive.get('enabled', 0)}/{count}" if "error" not in drive else ""
            print(f"{count:>2} drives: {_cell(drive)}{enabled}")
            print(f"{count:>2} io:     {_cell(io)}")
        best_drive = max((c for c, d, _ in rows if _ok(d)), default=0)
        best_io = max((c for c, _, i in rows if _ok(i)), default=0)
        print(f"largest segment with 0 wrong working counters and p99 < {P99_LIMIT_US:.0f} us: "
              f"{best_drive} drives, {best_io} ethercat_io (same run)")
        _search_and_record(ns, emu, mst, seconds)


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--max-drives":
        os.environ["GL_BENCH_MAX_DRIVES"] = sys.argv[2]
    if len(sys.argv) >= 6 and sys.argv[1] == "--master":
        import faulthandler

        faulthandler.dump_traceback_later(float(sys.argv[5]) * 3 + 100, exit=True)   # where a master hangs
        print(json.dumps(master(sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), float(sys.argv[5]))))
    else:
        main()
