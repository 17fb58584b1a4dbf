"""The kit of the wire benchmarks (EtherCAT over a veth pair, pysoem in a network namespace).

bench_ethercat, bench_ecanlite, bench_esd_can_ethercat and bench_ethercat_drive all run the same way:
the emulator's busy-polling wire thread on one end of a veth pair (CPU 1), SOEM through pysoem in a
subprocess inside a namespace on the other end (CPU 0), the subprocess printing its result as one JSON
line. This module holds that set-up once: why a run must be skipped, the namespace + veth pair, the
master subprocess, the 1 kHz pacing, the SOEM bring-up to OP and the mailbox retry, percentiles.

Not imported by ``gatewaylab``: the benchmarks are the only users (the tests have tests/wire_kit.py).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from gatewaylab.ethercat.wire_netns import net_unavailable
from gatewaylab.ethercat.wire_netns import veth_namespace as veth_namespace  # the benches take it from here

#: the project root: the master subprocess runs ``python -m benchmarks.X`` from there
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: how long before its tick the pacer stops sleeping and starts spinning
SPIN_S = 0.0003


def skip_reason(*modules: str) -> str | None:
    """None when this process may create a namespace and a veth pair (and can import ``modules``), else
    the line the benchmark prints instead of running."""
    reason = net_unavailable(*modules)
    return f"skipped: {reason}" if reason else None


def bench_seconds(default: float, *modules: str) -> float | None:
    """The paced run's length (GL_BENCH_SECONDS, else ``default``), or None after printing why this
    benchmark cannot run here (``skip_reason``)."""
    skip = skip_reason(*modules)
    if skip:
        print(skip)
        return None
    return float(os.environ.get("GL_BENCH_SECONDS", str(default)))


def pin(cpu: int) -> None:
    """Pin this process (thread) to ``cpu`` modulo the CPUs there are; nothing where that is not possible."""
    try:
        os.sched_setaffinity(0, {cpu % (os.cpu_count() or 1)})
    except (AttributeError, OSError):
        pass


def pct(values: Sequence[float], q: float) -> float:
    """The ``q`` quantile (nearest rank below); NaN for no values."""
    if not values:
        return float("nan")
    s = sorted(values)
    return s[min(len(s) - 1, int(q * len(s)))]


def run_in_namespace(ns: str, module: str, args: Sequence[str], timeout: float,
                     python_flags: Sequence[str] = ()) -> subprocess.CompletedProcess[str]:
    """``python -m <module> <args>`` inside the namespace, from the project root, output captured."""
    return subprocess.run(["ip", "netns", "exec", ns, sys.executable, *python_flags, "-m", module, *args],
                          capture_output=True, text=True, timeout=timeout, check=False, cwd=ROOT)


def last_json(proc: subprocess.CompletedProcess[str]) -> dict[str, Any]:
    """The master's result (its last stdout line); RuntimeError with its stderr when it failed."""
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr[-2000:])
    result: dict[str, Any] = json.loads(proc.stdout.strip().splitlines()[-1])
    return result


def run_master(ns: str, module: str, args: Sequence[str], timeout: float) -> dict[str, Any]:
    """The master subprocess's JSON result (``run_in_namespace`` + ``last_json``)."""
    return last_json(run_in_namespace(ns, module, args, timeout))


def ticks(n: int, period: float = 0.001) -> Iterator[int]:
    """Yield 0..n-1, each at its tick: the master sleeps between cycles like a real-time task would, then
    spins the last ``SPIN_S`` so the cycle starts on time."""
    t_next = time.perf_counter() + period
    for i in range(n):
        slack = t_next - time.perf_counter() - SPIN_S
        if slack > 0:
            time.sleep(slack)
        while time.perf_counter() < t_next:
            pass
        t_next += period
        yield i


def paced(rate: float, seconds: float, cycle: Callable[[], bool], failed_key: str = "lost") -> dict[str, Any]:
    """``cycle`` at ``rate`` for ``seconds``: cycle count, how many returned False (under ``failed_key``),
    median / p99 / max round trip in us."""
    rtts: list[float] = []
    failed = 0
    for _ in ticks(int(seconds * rate), 1.0 / rate):
        t0 = time.perf_counter()
        ok = cycle()
        rtts.append(time.perf_counter() - t0)
        if not ok:
            failed += 1
    return {"cycles": len(rtts), failed_key: failed, **rtt_summary(rtts)}


def rtt_summary(rtts: Sequence[float]) -> dict[str, float]:
    """Median / p99 / max of round trips given in seconds, in us."""
    import statistics

    return {"median_us": 1e6 * statistics.median(rtts), "p99_us": 1e6 * pct(rtts, 0.99),
            "max_us": 1e6 * max(rtts)}


def request_op(master: Any, timeout_us: int, tries: int) -> bool:
    """From SAFEOP: request OP while exchanging process data (the slave needs valid outputs first), until
    the slave reports OP or ``tries`` checks passed."""
    import pysoem

    master.state = pysoem.OP_STATE
    master.send_processdata()
    master.receive_processdata(timeout_us)
    master.write_state()
    for _ in range(tries):
        master.send_processdata()
        master.receive_processdata(timeout_us)
        if master.state_check(pysoem.OP_STATE, 5000) == pysoem.OP_STATE:
            return True
    return False


def retry(fn: Callable[..., Any], *args: Any, attempts: int = 5, pause: float = 0.05,
          errors: tuple[str, ...] = ("WkcError", "MailboxError", "PacketError")) -> Any:
    """An idempotent mailbox service again when its answer came later than SOEM's timeout (shared machine);
    ``errors`` names the pysoem exceptions that mean 'try again'."""
    import pysoem

    kinds = tuple(getattr(pysoem, name) for name in errors)
    for attempt in range(attempts):
        try:
            return fn(*args)
        except kinds:
            if attempt == attempts - 1:
                raise
            time.sleep(pause)
    return None


def go_init(master: Any) -> None:
    """Leave the line in INIT and close the master."""
    import pysoem

    master.state = pysoem.INIT_STATE
    master.write_state()
    master.close()


#: the two conditions every tail figure is measured under: the machine as it is, and with one more process
#: busy on a CPU (a CI runner's ordinary background load)
LOADS = ("quiet", "loaded")


def loads() -> tuple[str, ...]:
    """The conditions to run (GL_BENCH_LOADS, comma-separated, default both of :data:`LOADS`)."""
    wanted = tuple(w.strip() for w in os.environ.get("GL_BENCH_LOADS", ",".join(LOADS)).split(",") if w.strip())
    unknown = [w for w in wanted if w not in LOADS]
    if unknown:
        raise ValueError(f"GL_BENCH_LOADS: unknown condition(s) {', '.join(unknown)} (known: {', '.join(LOADS)})")
    return wanted


class CpuHog:
    """``loaded``: one process spinning on whatever CPU the scheduler gives it, unpinned, as another job of
    a CI runner; ``quiet``: nothing. A context manager; the process is ended by its own id."""

    def __init__(self, load: str) -> None:
        self.load = load
        self.proc: subprocess.Popen[bytes] | None = None

    def __enter__(self) -> CpuHog:
        if self.load == "loaded":
            self.proc = subprocess.Popen([sys.executable, "-c", "while True: pass"])
        return self

    def __exit__(self, *exc: object) -> None:
        if self.proc is not None:
            self.proc.kill()
            self.proc.wait()
            self.proc = None


def env_int(name: str, default: int) -> int:
    """An integer setting of a benchmark (GL_BENCH_*), else ``default``."""
    return int(os.environ.get(name, str(default)))
