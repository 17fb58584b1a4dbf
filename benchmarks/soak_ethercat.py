"""Soak of the EtherCAT wire under CAN load (``make soak-ethercat``): does a master's 1 kHz cycle stay clean?

``gatewaylab run`` (as a user starts it) serves a mixed segment on one end of a veth pair: 2 ``ethercat_io``,
an ECAN-Lite (channel 0 on ``can0``, N = 1) with a CANopen drive (node 2) behind it on ``can0`` and 2
``ethercat_drive``. SOEM (pysoem) in a namespace on the other end brings the line to OP, configures the
ECAN-Lite over CoE (manual 5.4.3), enables the drives and runs them in CSP, and cycles at 1 kHz with
SOEM's default 2 ms receive timeout and no retries, sending a SYNC through the ECAN-Lite every cycle. A
python-can client on the rig's ``can0`` endpoint starts the CAN drive (NMT) and sends it RPDO1 at
``--can-rate`` frames/s; the drive answers with TPDO1, which reaches the master through the ECAN-Lite.

Printed at the end: wrong working counters (SOEM's view), late replies (a kernel-timestamped capture on
the master's interface: replies later than 2 ms, and requests never answered), the emulator's dropped-late
frames (the rig's wire counter ``frames_dropped_late``, where the rig has it), and the CAN traffic.
Exit status 1 when a cycle had a wrong working counter or a reply came late. Needs root (namespace + veth).

    python -m benchmarks.soak_ethercat --minutes 10      # make soak-ethercat (SOAK_MINUTES=60 for an hour)

The same machinery runs bench_ethercat_tail (the mixed segment of 8 drives + 8 io + ECAN-Lite N = 3 + esd):
:class:`Plan` says what the segment holds, :func:`run_line` runs it once, :func:`master_main` is the master.
"""

from __future__ import annotations

import argparse
import json
import os
import select
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import IO, Any

from benchmarks.capture import Capture, Tail, cycle_tag, explain_late, tail_of
from benchmarks.soak_can import CAN_NODE, SYNC_ID, CanLoad
from benchmarks.wire import ROOT, CpuHog, pin, veth_namespace

#: SOEM's default process-data receive timeout (EC_TIMEOUTRET, us): a later reply is a lost cycle
SOEM_TIMEOUT_US = 2000
#: the limit replies are counted against where the rig has no ``max_residence_ms`` key (ms)
FALLBACK_RESIDENCE_MS = 5.0
#: how long the parent waits for the master's bring-up (scan, CoE configuration, OP) on a loaded machine
BRING_UP_S = 180.0
#: whole bring-ups tried before the run gives up (each after a scan or mailbox answer lost to a stall)
BRING_UP_ATTEMPTS = 10
#: how long the master may take to read the ECAN-Lite's counters after the run
COUNTERS_S = 60.0
#: the stall's window (LineResult.stall_window) starts this long before the SIGSTOP
STALL_LEAD_NS = 100_000_000


# ------------------------------------------------------------------------------------------------ the plan
@dataclass(frozen=True)
class Plan:
    """A mixed segment: the io first (their outputs start the image and carry the master's cycle number,
    capture.cycle_tag), then the ECAN-Lite (``ecan_n`` chunks on ``ecan_channels`` CAN FD buses), the esd
    and the drives; ``can_drive`` puts a CANopen drive on ``can0`` behind the ECAN-Lite; ``frames_per_ms``:
    CAN frames the master puts in the ECAN-Lite's RxPDO per ms (one per channel; 0 = a SYNC on channel 0),
    ``peer_rate``: frames/s each python-can peer sends on each ECAN-Lite bus."""

    drives: int = 2
    ios: int = 2
    ecan_n: int = 1
    ecan_channels: int = 1
    esd: bool = False
    can_drive: bool = True
    frames_per_ms: int = 0
    peer_rate: float = 0.0
    #: RPDO1 frames/s to the CAN drive (the drive answers each with TPDO1)
    can_rate: float = 500.0

    def kinds(self) -> list[str]:
        """The slaves in segment order."""
        return (["io"] * self.ios + ["ecanlite"] * bool(self.ecan_channels) + ["esd"] * self.esd
                + ["drive"] * self.drives)

    def describe(self) -> str:
        parts = [f"{self.ios} ethercat_io"]
        if self.ecan_channels:
            parts.append(f"ECAN-Lite N={self.ecan_n} on {self.ecan_channels} CAN FD bus(es)"
                         + (" with a CANopen drive behind it" if self.can_drive else ""))
        if self.esd:
            parts.append("esd CAN-EtherCAT")
        parts.append(f"{self.drives} ethercat_drive")
        return " + ".join(parts)


#: make soak-ethercat: 2 io, 1 ECAN-Lite with a CAN drive behind it, 2 drives (the issue's failing segment)
SOAK_PLAN = Plan()


def residence_limit_ms() -> float | None:
    """The rig's ``[ethercat] max_residence_ms`` default, None where this gatewaylab has no such key."""
    from gatewaylab.rig.segment import SEGMENT_KEYS

    key = SEGMENT_KEYS.get("max_residence_ms")
    return None if key is None else float(key.default) if key.default is not None else None


def rig_toml(plan: Plan, interface: str, max_residence_ms: float | None = None,
             ethercat: Mapping[str, str] = MappingProxyType({})) -> str:
    """The rig file of ``plan`` on ``interface`` (``max_residence_ms`` written only when given; ``ethercat``:
    more ``[ethercat]`` keys, values as TOML text)."""
    lines = ['clock = "realtime"', ""]
    buses = [f"can{k}" for k in range(plan.ecan_channels)]
    for name in buses:
        lines += ["[[bus]]", f'name = "{name}"', "bitrate = 1000000", "data_bitrate = 5000000", ""]
    if plan.esd:
        lines += ["[[bus]]", 'name = "esd0"', "bitrate = 500000", ""]
    for i in range(plan.ios):
        lines += ["[[device]]", 'kind = "ethercat_io"', f'name = "io{i + 1}"', f"revision = {i + 1}", ""]
    if plan.ecan_channels:
        lines += ["[[device]]", 'kind = "ecanlite"', 'name = "ecan"', f"channels = {json.dumps(buses)}", ""]
    if plan.esd:
        lines += ["[[device]]", 'kind = "esd_can_ethercat"', 'name = "esd"', 'bus = "esd0"', ""]
    for i in range(plan.drives):
        lines += ["[[device]]", 'kind = "ethercat_drive"', f'name = "axis{i + 1}"', f"serial = {0x3001 + i}", ""]
    if plan.can_drive and plan.ecan_channels:
        lines += ["[[drive]]", 'bus = "can0"', f"node_id = {CAN_NODE}", "serial = 0x1002", 'name = "candrive"', ""]
    lines += ["[ethercat]", f'interface = "{interface}"']
    if max_residence_ms is not None and "max_residence_ms" not in ethercat:
        lines.append(f"max_residence_ms = {max_residence_ms:g}")
    lines += [f"{key} = {value}" for key, value in ethercat.items()]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------------- the rig's counters
#: the wire counters read from the rig, where its control endpoint reports them
WIRE_COUNTERS = ("frames_dropped_late", "frames_late_on_arrival", "frames_in", "frames_out", "frame_errors")


def _collect(obj: Any, found: dict[str, int]) -> None:
    if isinstance(obj, dict):
        for key, value in obj.items():
            if key in WIRE_COUNTERS and isinstance(value, int) and not isinstance(value, bool):
                found[key] = found.get(key, 0) + value
            else:
                _collect(value, found)
    elif isinstance(obj, list):
        for value in obj:
            _collect(value, found)


def wire_counters(ready_file: str | Path) -> dict[str, int]:
    """The rig's wire counters (:data:`WIRE_COUNTERS`) wherever an EtherCAT status request of its control
    endpoint reports them (summed over wires); {} where none does (a rig without them)."""
    from gatewaylab.cli.fault import send_request

    names = ["ethercat-states"]
    try:       # the requests the rig knows, from its refusal of an unknown one
        refusal = str(send_request(str(ready_file), {"fault": "?"}).get("error", ""))
        listed = refusal.partition("(faults:")[2].rstrip(")").split(",")
        names += [n.strip() for n in listed if n.strip().startswith("ethercat") and n.strip() not in names
                  and not n.strip().endswith(("unplug", "replug"))]
    except Exception:
        pass
    found: dict[str, int] = {}
    for name in names:
        try:
            _collect(send_request(str(ready_file), {"fault": name}), found)
        except Exception:
            continue
    return found


# ------------------------------------------------------------------------------------------------ master
def emit(event: str, **fields: Any) -> None:
    """One JSON event line of the master to the parent."""
    print(json.dumps({"event": event, **fields}), flush=True)


class EcanStream:
    """The ECAN-Lite's frame stream as the master drives it: ``frames`` CAN frames per cycle into the RxPDO
    (a new header sequence each cycle, published again after a lost cycle), every new TxPDO image parsed."""

    def __init__(self, slave: Any, n: int, channels: int, frames_per_ms: int) -> None:
        from gatewaylab.devices.ecanlite.stream import Direction, StreamLayout

        self.slave = slave
        mask = (1 << channels) - 1     # as configure_ecan writes 0x8010/0x8011:04
        self.rx = StreamLayout(multiplier=n, channel_mask=mask, direction=Direction.RX)
        self.tx = StreamLayout(multiplier=n, channel_mask=mask, direction=Direction.TX)
        self.channels = channels
        self.frames_per_ms = frames_per_ms
        self.seq = 0
        self.previous: bytes | None = None
        self.sent = self.received = self.parse_errors = 0

    def outputs(self, cycle: int) -> None:
        from gatewaylab.devices.ecanlite.stream import CanPacket, encode_stream

        self.seq = (self.seq + 1) & 0xFFFF
        if self.frames_per_ms:
            packets = [CanPacket.of(ch, 0x100 + ch, data=struct.pack("<HHI", ch, self.seq, 0))
                       for ch in range(min(self.frames_per_ms, self.channels))]
        else:
            packets = [CanPacket.of(0, SYNC_ID, data=b"")]
        self.slave.output = encode_stream(self.rx, self.seq, packets)
        self._pending = len(packets)

    def inputs(self, ok: bool) -> None:
        from gatewaylab.devices.ecanlite.stream import Commit, StreamError, commit_state, decode_stream

        if not ok:
            self.seq = (self.seq - 1) & 0xFFFF    # the image did not arrive: publish it again
            return
        self.sent += self._pending
        image = bytes(self.slave.input)
        if commit_state(image, self.previous) is not Commit.NEW:
            return
        self.previous = image
        try:
            self.received += len(decode_stream(image, self.tx).frames)
        except StreamError:
            self.parse_errors += 1


def soem_errors() -> tuple[type[BaseException], ...]:
    """What a bring-up raises when an answer came too late (a stall of the machine): pysoem's exceptions,
    the benchmarks' own RuntimeError / SystemExit."""
    import pysoem

    return (RuntimeError, SystemExit, pysoem.ConfigMapError, pysoem.MailboxError, pysoem.WkcError,
            pysoem.PacketError, pysoem.SdoError)


def _bring_up(iface: str, kinds: Sequence[str], plan: Plan) -> tuple[Any, EcanStream | None, int]:
    """SOEM to OP with the ECAN-Lite configured and the drives enabled; (master, stream, scans it took).
    The bring-up is the master's own (its mailbox timeouts); a scan or mailbox answer lost to a stall of the
    machine starts the whole bring-up again, counted."""
    import pysoem

    from benchmarks.bench_ecanlite import configure_ecan
    from benchmarks.bench_ethercat_drive import enable_drives
    from benchmarks.wire import request_op

    errors = soem_errors()
    for attempt in range(1, BRING_UP_ATTEMPTS + 1):
        master = pysoem.Master()
        master.sdo_read_timeout = master.sdo_write_timeout = 3_000_000
        master.open(iface)
        try:
            if master.config_init() != len(kinds):
                raise RuntimeError(f"scan found {len(master.slaves)} slaves, expected {len(kinds)}")
            stream = None
            if "ecanlite" in kinds:
                s0 = master.slaves[kinds.index("ecanlite")]
                configure_ecan(s0, plan.ecan_n, plan.ecan_channels)
                stream = EcanStream(s0, plan.ecan_n, plan.ecan_channels, plan.frames_per_ms)
            master.config_map()
            if master.state_check(pysoem.SAFEOP_STATE, 50_000) != pysoem.SAFEOP_STATE:
                raise RuntimeError("SAFEOP not reached")
            for s in master.slaves:
                s.output = bytes(len(s.output))
            if not request_op(master, 20_000, 400):
                raise RuntimeError("OP not reached")
            drives = [s for s, k in zip(master.slaves, kinds, strict=True) if k == "drive"]
            enabled = enable_drives(master, drives)
            if enabled != len(drives):
                raise RuntimeError(f"{enabled}/{len(drives)} drives enabled")
            return master, stream, attempt
        except errors as exc:
            master.close()
            emit("retry", attempt=attempt, error=f"{type(exc).__name__}: {exc}")
            if attempt == BRING_UP_ATTEMPTS:
                raise
            time.sleep(1.0)
    raise AssertionError("unreachable")


def master_main(iface: str, plan: Plan, cycles: int) -> dict[str, Any]:
    """In the namespace: bring-up, 'op', wait for the parent's 'go' line, ``cycles`` at 1 kHz (2 ms timeout,
    no retries), 'done' with the counts."""
    from benchmarks.bench_ethercat_drive import csp_output, drive_faults
    from benchmarks.wire import go_init, ticks

    pin(0)
    kinds = plan.kinds()
    master, stream, scans = _bring_up(iface, kinds, plan)
    drives = [s for s, k in zip(master.slaves, kinds, strict=True) if k == "drive"]
    ios = [s for s, k in zip(master.slaves, kinds, strict=True) if k == "io"]
    expected = master.expected_wkc
    emit("op", expected_wkc=expected, scans=scans)
    # the parent's 'go' (its captures are up) is read aside: the line keeps cycling meanwhile, or the slaves'
    # SM watchdogs expire before the counted cycles start
    go = threading.Event()

    def wait_go() -> None:
        sys.stdin.readline()
        go.set()
    threading.Thread(target=wait_go, daemon=True).start()
    wrong = 0
    first_wrong: list[int] = []
    rtts: list[float] = []

    def exchange(i: int) -> bool:
        if stream is not None:
            stream.outputs(i)
        data = csp_output(i)
        for s in drives:
            s.output = data
        for s in ios:        # first in the image: the cycle makes the LRW's key unique (capture.pairs)
            s.output = cycle_tag(i, len(s.output))
        master.send_processdata()
        ok = bool(master.receive_processdata(SOEM_TIMEOUT_US) == expected)
        if stream is not None:
            stream.inputs(ok)
        return ok

    warm = 0
    for warm in ticks(1 << 62):
        if go.is_set():
            break
        exchange(warm)
    t_start = time.time_ns()
    gaps = {"max_s": 0.0, "over_100ms": 0}    # the master's own pauses between two cycles
    previous = time.perf_counter()
    for i in ticks(cycles):      # a fresh schedule: cycles the warm-up fell behind are not made up for
        t0 = time.perf_counter()
        gap, previous = t0 - previous, t0
        gaps["max_s"] = max(gaps["max_s"], gap)
        gaps["over_100ms"] += gap > 0.1
        ok = exchange(warm + i)
        rtts.append(time.perf_counter() - t0)
        if not ok:
            wrong += 1
            if len(first_wrong) < 20:
                first_wrong.append(i)
    t_end = time.time_ns()
    emit("cycled")
    rtts.sort()
    out: dict[str, Any] = {
        "cycles": cycles, "wrong_wkc": wrong, "first_wrong": first_wrong, "t_start_ns": t_start, "t_end_ns": t_end,
        "rtt_p50_us": 1e6 * rtts[len(rtts) // 2], "rtt_p99_us": 1e6 * rtts[int(0.99 * len(rtts))],
        "rtt_max_us": 1e6 * rtts[-1], "drive_faults": drive_faults(drives), "scans": scans,
        "gap_max_us": 1e6 * gaps["max_s"], "gaps_over_100ms": gaps["over_100ms"],
        "ecan": {} if stream is None else {"sent": stream.sent, "received": stream.received,
                                           "parse_errors": stream.parse_errors}}
    go_init(master)
    if stream is not None:
        try:
            out["ecan"].update(ecan_counters(iface, kinds))
        except soem_errors() as exc:     # a scan lost to a stall: the counts stay out
            out["ecan"]["counters_error"] = f"{type(exc).__name__}: {exc}"
    return out


def ecan_counters(iface: str, kinds: Sequence[str]) -> dict[str, int]:
    """The ECAN-Lite's own counts after the run, read over CoE in a fresh PREOP session: RxPDO errors
    (0x8011:15), TX FIFO full / stale drops (0x9020..:11/12), RX cache drops (0x9020..:06/07)."""
    from benchmarks.bench_ecanlite import preop_session
    from benchmarks.wire import retry

    deadline = time.monotonic() + COUNTERS_S
    master = preop_session(iface, len(kinds))
    s0 = master.slaves[kinds.index("ecanlite")]

    def u(index: int, sub: int) -> int:
        if time.monotonic() > deadline:
            raise RuntimeError(f"the counters took longer than {COUNTERS_S:g} s to read (a loaded machine)")
        return int.from_bytes(retry(s0.sdo_read, index, sub), "little")
    try:
        return {"pdo_errors": u(0x8011, 15), "last_pdo_error": u(0x8011, 16),
                "tx_fifo_drops": sum(u(0x9020 + k, sub) for k in range(4) for sub in (11, 12)),
                "rx_cache_drops": sum(u(0x9020 + k, sub) for k in range(4) for sub in (6, 7))}
    finally:
        master.close()


# ------------------------------------------------------------------------------------------------ a run
@dataclass
class LineResult:
    """One run of a plan: the master's counts, the captures' tails, the rig's counters, the CAN client's."""

    plan: Plan
    load: str
    cycles: int
    limit_ms: float
    #: whether the rig has ``max_residence_ms`` (else replies are counted against FALLBACK_RESIDENCE_MS)
    limit_configurable: bool
    #: ``max_residence_ms = 0``: the rig's limit is off (counted against FALLBACK_RESIDENCE_MS)
    limit_off: bool = False
    master: dict[str, Any] = field(default_factory=dict)
    #: round trips on the master's interface (replies later than SOEM's timeout and than the limit counted)
    master_tail: Tail | None = None
    #: request in -> reply out on the emulator's interface
    residence: Tail | None = None
    counters: dict[str, int] = field(default_factory=dict)
    can: dict[str, int] = field(default_factory=dict)
    #: with a stall: its kernel-time span, and the master's round trips of the frames of :meth:`stall_window`
    stall: tuple[int, int] | None = None
    stall_tail: Tail | None = None
    #: slaves the rig reported out of OP while the master cycled: name -> state and when
    left_op: dict[str, str] = field(default_factory=dict)
    errors: list[str] = field(default_factory=list)

    def stall_window(self) -> tuple[int, int] | None:
        """The requests the stall counts (kernel ns): from just before it (a frame the rig held when it stopped
        is answered after it) to a second after it (the backlog)."""
        return None if self.stall is None else (self.stall[0] - STALL_LEAD_NS, self.stall[1] + 1_000_000_000)

    def limit_text(self) -> str:
        """The limit the stale replies are counted against, and where it comes from."""
        if not self.limit_configurable:
            return f"{self.limit_ms:g} ms (this rig has no max_residence_ms)"
        if self.limit_off:
            return f"{self.limit_ms:g} ms (max_residence_ms = 0: the rig's limit is off)"
        return f"max_residence_ms {self.limit_ms:g}"

    @property
    def late(self) -> int:
        """Replies that reached the master after SOEM's 2 ms."""
        return 0 if self.master_tail is None else self.master_tail.over.get(float(SOEM_TIMEOUT_US), 0)

    @property
    def stale(self) -> int:
        """Replies older than the residence limit that reached the master."""
        return 0 if self.master_tail is None else self.master_tail.over.get(self.limit_ms * 1000.0, 0)


class StateWatch:
    """The rig's AL states polled (``ethercat-states``, every ``period`` s) while the master cycles: every slave
    seen out of OP, first time and state -- a slave that left OP by itself (SM watchdog after a stall) and
    whose outputs no longer count shows here even where the working counter stays full."""

    def __init__(self, ready_file: str | Path, period: float = 0.5) -> None:
        self.ready_file = str(ready_file)
        self.period = period
        self.t0 = time.monotonic()
        self.left_op: dict[str, str] = {}
        self.stop_event = threading.Event()
        self.thread = threading.Thread(target=self._run, name="soak-ethercat-states", daemon=True)
        self.thread.start()

    def _run(self) -> None:
        from gatewaylab.cli.fault import send_request

        while not self.stop_event.wait(self.period):
            try:
                devices = send_request(self.ready_file, {"fault": "ethercat-states"}).get("devices", {})
            except Exception:
                continue
            for name, st in devices.items():
                if name not in self.left_op and st.get("state") != "OP":
                    error = f" + error 0x{int(st.get('code', 0)):04X}" if st.get("error") else ""
                    self.left_op[name] = f"{st.get('state')}{error} at {time.monotonic() - self.t0:.1f} s"

    def stop(self) -> dict[str, str]:
        """End the polling; slave name -> its first state out of OP and when."""
        self.stop_event.set()
        self.thread.join(5)
        return dict(self.left_op)


class MasterProcess:
    """The master (:func:`master_main`) inside the namespace, its events read as they come."""

    def __init__(self, ns: str, iface: str, plan: Plan, cycles: int) -> None:
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (ROOT, os.environ.get("PYTHONPATH", "")) if p)}
        self.proc = subprocess.Popen(
            ["ip", "netns", "exec", ns, sys.executable, "-m", "benchmarks.soak_ethercat", "--master", iface,
             "--plan", json.dumps(asdict(plan)), "--cycles", str(cycles)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT, env=env)
        self.retries: list[str] = []

    def wait(self, event: str, timeout: float) -> dict[str, Any]:
        """The next event named ``event`` (retries noted on the way); RuntimeError when the master ends first."""
        out: IO[str] | None = self.proc.stdout
        assert out is not None
        deadline = time.monotonic() + timeout
        last = ""
        while time.monotonic() < deadline:
            if not select.select([out], [], [], 1.0)[0]:
                continue
            line = out.readline()
            if not line:
                break
            last = line.strip()
            try:
                ev: dict[str, Any] = json.loads(line)
            except ValueError:
                continue
            if ev.get("event") == "retry":
                self.retries.append(str(ev.get("error")))
            if ev.get("event") == event:
                return ev
        self.kill()
        err = self.proc.stderr.read() if self.proc.stderr is not None else ""
        why = err.strip()[-1500:] or f"no error; its last line: {last[:300] or 'none'}"
        raise RuntimeError(f"the master gave no '{event}' within {timeout:.0f} s (exit {self.proc.returncode}): {why}")

    def go(self) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write("go\n")
        self.proc.stdin.flush()

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()


def run_line(plan: Plan, cycles: int, load: str = "quiet", *, residence: bool = True, keep: bool = True,
             stall_after_s: float | None = None, stall_s: float = 0.2,
             before_rig: Callable[[str, str, str], None] | None = None,
             ethercat: Mapping[str, str] = MappingProxyType({})) -> LineResult:
    """``plan`` through ``gatewaylab run`` on a fresh veth pair, SOEM cycling ``cycles`` times under ``load``
    (:class:`CpuHog`), captures on the master's end (and with ``residence`` on the emulator's); with
    ``stall_after_s`` the rig is stopped (SIGSTOP) for ``stall_s`` that long after the cycles started.
    ``before_rig(ns, emu, mst)`` runs first on the same pair under the same load (the C echo); ``ethercat``:
    more ``[ethercat]`` keys of the rig (TOML values), e.g. ``{"busy_poll": "true"}``."""
    from gatewaylab.rig.process import RigProcess

    limit = residence_limit_ms()
    if "max_residence_ms" in ethercat:
        limit = float(ethercat["max_residence_ms"])
    result = LineResult(plan, load, cycles, limit or FALLBACK_RESIDENCE_MS, limit is not None, limit == 0)
    limits = (float(SOEM_TIMEOUT_US), result.limit_ms * 1000.0)
    with tempfile.TemporaryDirectory(prefix="gl-soak-ecat-") as tmp, \
            veth_namespace("gl-sk-", "gls") as (ns, emu, mst), CpuHog(load):
        if before_rig is not None:
            before_rig(ns, emu, mst)
        path = Path(tmp) / "rig.toml"
        path.write_text(rig_toml(plan, emu, limit, ethercat))
        with RigProcess(path, workdir=tmp, timeout=120) as rig:
            master = MasterProcess(ns, mst, plan, cycles)
            can: CanLoad | None = None
            try:
                master.wait("op", BRING_UP_S)
                # the peers start once the ECAN-Lite's channels run: before, no node on can1.. acknowledges
                can = CanLoad(plan, [rig.endpoint(f"can{k}") for k in range(plan.ecan_channels)])
                result.errors += [f"bring-up again after: {r}" for r in master.retries]
                caps = [Capture(mst, Path(tmp) / "master.cap", ("ip", "netns", "exec", ns))]
                if residence:
                    caps.append(Capture(emu, Path(tmp) / "emulator.cap"))
                try:
                    master.go()
                    watch = StateWatch(rig.ready_file)
                    if stall_after_s is not None:
                        time.sleep(stall_after_s)
                        t0 = time.time_ns()
                        os.kill(rig.pid, signal.SIGSTOP)
                        try:
                            time.sleep(stall_s)
                        finally:
                            os.kill(rig.pid, signal.SIGCONT)
                        result.stall = (t0, time.time_ns())
                    result.master = master.wait("cycled", cycles / 1000.0 * 3 + 240)
                    result.left_op = watch.stop()
                    result.master = master.wait("done", COUNTERS_S + 120)
                finally:
                    files = [c.stop() for c in caps]
                t0_ns, t1_ns = result.master["t_start_ns"], result.master["t_end_ns"]
                result.master_tail = tail_of(files[0], True, limits, keep, t0_ns, t1_ns)
                if (window := result.stall_window()) is not None:
                    result.stall_tail = tail_of(files[0], True, limits, False, *window)
                    result.errors += explain_late(files[0], files[1] if residence else None, limits[1], *window,
                                                  window[0] + STALL_LEAD_NS)
                if residence:
                    result.residence = tail_of(files[1], False, limits, keep, t0_ns, t1_ns)
                result.counters = wire_counters(rig.ready_file)
            finally:
                master.kill()
                if can is not None:
                    result.can = can.stop()
            if rig.proc.poll() is not None:
                result.errors.append(f"the rig exited with {rig.proc.returncode}: {rig.log_text()[-500:]}")
            logged = [line for line in rig.log_text().splitlines() if line.startswith(("WARNING", "ERROR"))]
            result.errors += [f"the rig logged: {line[:300]}" for line in logged[:5]]
    return result


# ------------------------------------------------------------------------------------------------ report
def fmt_us(value: float) -> str:
    """A time in us, as ms from 10 ms up."""
    return f"{value / 1000:.1f} ms" if value >= 10_000 else f"{value:.0f} us"


def report(r: LineResult) -> str:
    """The soak's lines: the cycle's counts, the late replies, the rig's dropped-late frames, the CAN side."""
    m = r.master
    lines = [f"soak-ethercat ({r.load}): {r.plan.describe()}; SOEM at 1 kHz, {SOEM_TIMEOUT_US} us timeout, "
             f"{m.get('cycles', r.cycles)} cycles"]
    lines.append(f"  wrong working counters: {m.get('wrong_wkc', '?')}"
                 + (f" (first at cycles {m['first_wrong'][:5]})" if m.get("first_wrong") else ""))
    lines.append("  slaves that left OP while the master cycled (the rig's AL states): "
                 + (", ".join(f"{n} {s}" for n, s in r.left_op.items()) if r.left_op else "none"))
    if r.master_tail is not None:
        t = r.master_tail
        stale = "" if r.limit_ms * 1000.0 == SOEM_TIMEOUT_US else f", {r.stale} after {r.limit_ms:g} ms"
        lines.append(f"  late replies (master's capture): {r.late} after {SOEM_TIMEOUT_US / 1000:g} ms{stale}; "
                     f"never answered {t.unanswered} of {t.requests} frames; worst {fmt_us(t.worst_us)}")
    if r.residence is not None:
        e = r.residence
        spread = "" if not e.delays_us else "p50 {p50} p99 {p99} p99.9 {p999} ".format(
            **{k[:-3]: fmt_us(v) for k, v in e.percentiles().items()})
        over = "" if r.limit_ms * 1000.0 == SOEM_TIMEOUT_US else \
            f", over {r.limit_ms:g} ms {e.over.get(r.limit_ms * 1000.0, 0)}"
        lines.append(f"  emulator residence (its capture): {spread}max {fmt_us(e.worst_us)}; over "
                     f"{SOEM_TIMEOUT_US / 1000:g} ms {e.over.get(float(SOEM_TIMEOUT_US), 0)}{over}; not answered "
                     f"{e.unanswered}")
    dropped = r.counters.get("frames_dropped_late")
    arrival = r.counters.get("frames_late_on_arrival")
    lines.append(f"  dropped late by the rig: {'not reported by this rig' if dropped is None else dropped} "
                 f"(limit {r.limit_text()})"
                 + ("" if arrival is None else f", of which {arrival} reached the idle wire thread already late"))
    lines.append(f"  master round trip: p50 {fmt_us(m.get('rtt_p50_us', float('nan')))} "
                 f"p99 {fmt_us(m.get('rtt_p99_us', float('nan')))} max {fmt_us(m.get('rtt_max_us', float('nan')))}; "
                 f"its longest pause between two cycles {fmt_us(m.get('gap_max_us', float('nan')))} "
                 f"({m.get('gaps_over_100ms', '?')} over 100 ms, an SM watchdog's time); drive faults "
                 f"{m.get('drive_faults', '?')}")
    ecan = m.get("ecan") or {}
    if ecan or r.can:
        lines.append(f"  CAN: master -> ECAN-Lite {ecan.get('sent', 0)} frames, ECAN-Lite -> master "
                     f"{ecan.get('received', 0)} (parse errors {ecan.get('parse_errors', 0)}, RxPDO errors "
                     f"{ecan.get('pdo_errors', '?')}, TX FIFO drops {ecan.get('tx_fifo_drops', '?')}, RX cache drops "
                     f"{ecan.get('rx_cache_drops', '?')}); python-can client "
                     f"sent {r.can.get('sent', '?')} (refused: queue full {r.can.get('refused', '?')}), heard "
                     f"{r.can.get('heard', '?')} from the master and {r.can.get('other', '?')} other frames")
    lines += [f"  note: {e}" for e in r.errors]
    return "\n".join(lines)


def soak_ok(r: LineResult) -> bool:
    """No wrong working counter, no late reply, no slave out of OP."""
    return r.master.get("wrong_wkc", 1) == 0 and r.late == 0 and r.stale == 0 and not r.left_op


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """The soak's command line (``--master`` is the program inside the namespace)."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.soak_ethercat", description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=float(os.environ.get("SOAK_MINUTES", "10")),
                        help="length of the cyclic run (default SOAK_MINUTES, else 10)")
    parser.add_argument("--load", choices=("quiet", "loaded"), default="quiet",
                        help="loaded: one more process busy on a CPU meanwhile (default quiet)")
    parser.add_argument("--can-rate", type=float, default=SOAK_PLAN.can_rate,
                        help="RPDO1 frames/s the python-can client sends the CAN drive")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", dest="ethercat",
                        help="an [ethercat] key of the rig, value as TOML (e.g. busy_poll=true, max_residence_ms=0)")
    parser.add_argument("--master", metavar="IFACE", help=argparse.SUPPRESS)
    parser.add_argument("--plan", help=argparse.SUPPRESS)
    parser.add_argument("--cycles", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.minutes <= 0:
        parser.error(f"--minutes must be > 0, got {args.minutes:g}")
    bad = [item for item in args.ethercat if "=" not in item or not item.partition("=")[0].strip()]
    if bad:
        parser.error(f"--set takes KEY=VALUE, got {bad[0]!r}")
    args.ethercat = {k.strip(): v.strip() for k, _, v in (item.partition("=") for item in args.ethercat)}
    return args


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    if args.master:
        emit("done", **master_main(args.master, Plan(**json.loads(args.plan)), args.cycles))
        return 0
    from benchmarks.wire import skip_reason

    skip = skip_reason("pysoem")
    if skip:
        print(f"soak-ethercat {skip}")
        return 0
    plan = Plan(can_rate=args.can_rate)
    cycles = int(args.minutes * 60_000)
    keys = "".join(f", {k} = {v}" for k, v in args.ethercat.items())
    print(f"soak-ethercat: {plan.describe()}, {args.minutes:g} min ({cycles} cycles), {args.load}{keys}", flush=True)
    result = run_line(plan, cycles, args.load, residence=True, keep=True, ethercat=args.ethercat)
    print(report(result))
    ok = soak_ok(result)
    print("  OK" if ok else "  NOT clean: a master's test run on this line would see failures it did not cause")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
