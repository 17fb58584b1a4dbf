"""The kit of the EtherCAT user-path tests (issue 21, "The user's path as a suite").

A user starts ``gatewaylab run RIG.toml --ready-file R`` with the ``[ethercat]`` segment on one end of a veth
pair, runs his master (pysoem or KickCAT) on the other end, and watches the CAN bus with python-can through
the endpoint the ready file names. This kit does exactly that and nothing more privileged:

* :func:`ethercat_rig`: a veth pair with the master's end in a fresh namespace (tests/wire_kit.py) and the
  rig as a child process on the root end (gatewaylab/rig/process.py ``RigProcess``);
* :class:`MasterRun`: the master script (``ethercat_userpath_master.py``) in the namespace, its events read
  while it runs (so a test acts on ``op`` and can SIGKILL it mid-exchange);
* four python-can clients, each written the way users write one: a ``recv(0)`` poll loop inside a cyclic
  task, ``recv(timeout)``, ``for msg in bus``, ``can.Notifier`` + ``BufferedReader``; all open
  ``can.Bus(interface="gatewaylab", channel=ENDPOINT)`` as a context manager;
* :func:`exchange`: one session (client up, master to OP, frames both ways every 5 ms, each tagged with its
  sender so frames a killed master left behind are told apart), :func:`latency`: first-frame and
  steady-state latencies from the wall times both sides took (frames across a stall of the master process
  counted apart), :func:`bounded`: issue 21's bounds (first frame after OP < 100 ms, steady p99 < 50 ms),
  a session beyond them measured once more.
"""

from __future__ import annotations

import collections
import contextlib
import itertools
import json
import os
import signal
import statistics
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, ClassVar

import can
import pytest
from wire_kit import check_reruns, net_capable, rig_counters_env, rig_wire_stats, veth_namespace

from gatewaylab.rig.process import RigProcess

MASTER = Path(__file__).with_name("ethercat_userpath_master.py")
#: the ids of the two directions (ethercat_userpath_master.py)
M2C_ID, C2M_ID = 0x123, 0x2A5
#: the client's frames to the master: one each SEND_PERIOD (the master sends one each 5 ms too)
SEND_PERIOD = 0.005
#: the client's first frame waits at most this long for the master's first one
QUIET_S = 0.3
#: bounds of the user's path on a loaded 2-CPU machine (issue 21): generous, they catch lags, not jitter
FIRST_FRAME_S = 0.100
STEADY_P99_S = 0.050
#: seconds a master may take from its start to OP (scan, CoE configuration) on a loaded machine
BRING_UP_S = 90.0


# ------------------------------------------------------------------------------------------ rig + namespace
@dataclass
class UserRig:
    """The running rig and the namespace whose interface the master opens."""

    rig: RigProcess
    namespace: str
    master_iface: str
    workdir: Path

    def endpoint(self, bus: str = "can0") -> str:
        return self.rig.endpoint(bus)

    def master(self, lib: str, kind: str, seconds: float) -> MasterRun:
        """The master process, once it reported OP. A KickCAT scan that failed on a register read answered
        later than its link timeout (a stall of this shared machine, see ethercat_userpath_master.py) is
        started again, as a user would, twice at most."""
        for attempt in range(3):
            master = MasterRun(self, lib, kind, seconds)
            try:
                master.wait("op", BRING_UP_S)
                return master
            except AssertionError:
                master.kill()
                if "KickCAT init failed" not in master.stderr() or attempt == 2:
                    raise
        raise AssertionError("unreachable")


@contextlib.contextmanager
def ethercat_rig(workdir: Path, rig_toml: str) -> Iterator[UserRig]:
    """``rig_toml`` (``{interface}`` filled in) run by ``gatewaylab run`` with its segment on a fresh veth
    pair; skipped where this process may not make one or a master library is missing."""
    reason = net_capable("pysoem", "kickcat")
    if reason is not None:
        pytest.skip(reason)
    with veth_namespace("gl-up-", "glu") as (ns, emu, mst):
        path = workdir / "rig.toml"
        path.write_text(rig_toml.format(interface=emu))
        with RigProcess(path, workdir=workdir, timeout=60) as rig:
            assert rig.info["ethercat"]["interface"] == emu
            yield UserRig(rig, ns, mst, workdir)
            log = rig.log_text()
            assert rig.proc.poll() is None, f"the rig died: {log[-2000:]}"
            # whatever the masters did (killed mid-exchange included), the rig logged no error: a frame the
            # wire thread could not process is logged 'ERROR ... raised ... (dropped)' (issue 21 defect 2)
            bad = [line for line in log.splitlines() if line.startswith(("ERROR", "CRITICAL", "Traceback"))]
            assert not bad, bad[:10]


def module_rig(factory: pytest.TempPathFactory, rig_toml: str, slaves: list[str]) -> Iterator[UserRig]:
    """The body of a module's rig fixture: :func:`ethercat_rig` in a fresh folder, its ready file listing
    ``slaves`` (names, in segment order) on the veth interface."""
    with ethercat_rig(factory.mktemp("rig"), rig_toml) as user:
        assert [s["name"] for s in user.rig.info["ethercat"]["slaves"]] == slaves
        yield user


class MasterRun:
    """The master script inside the namespace; its JSON events collected as they come."""

    def __init__(self, user: UserRig, lib: str, kind: str, seconds: float) -> None:
        self.lib, self.kind = lib, kind
        self.stderr_path = user.workdir / f"master-{lib}-{kind}-{time.monotonic_ns()}.err"
        err: IO[bytes]
        with self.stderr_path.open("wb") as err:
            self.proc = subprocess.Popen(
                ["ip", "netns", "exec", user.namespace, sys.executable, str(MASTER), user.master_iface, lib,
                 kind, repr(seconds)], stdout=subprocess.PIPE, stderr=err, text=True,
                env=rig_counters_env(user.rig.info))     # KickCAT's reruns judged by the rig's counters
        self.events: list[dict[str, Any]] = []
        self._cond = threading.Condition()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            with contextlib.suppress(ValueError):
                event = json.loads(line)
                with self._cond:
                    self.events.append(event)
                    self._cond.notify_all()
        with self._cond:
            self._cond.notify_all()

    def _find(self, ev: str, n: int) -> list[dict[str, Any]]:
        return [e for e in self.events if e["ev"] == ev][:n]

    def wait(self, ev: str, timeout: float, n: int = 1) -> dict[str, Any]:
        """The ``n``-th event ``ev``, waiting up to ``timeout`` s; AssertionError (with the master's stderr)
        when it did not come."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while len(self._find(ev, n)) < n:
                left = deadline - time.monotonic()
                if left <= 0 or (not self._reader.is_alive() and len(self._find(ev, n)) < n):
                    break
                self._cond.wait(min(left, 0.2))
            found = self._find(ev, n)
        if len(found) < n:
            raise AssertionError(f"{self.lib} master ({self.kind}): no {ev!r} #{n} within {timeout} s "
                                 f"(exit {self.proc.poll()}): {self.stderr()}")
        return found[-1]

    def times(self, ev: str, src: int | None = None) -> dict[int, float]:
        """seq -> wall time of each event ``ev`` (the first one of a seq), of frames from ``src`` only when
        given (``rx``: the client's tag)."""
        with self._cond:
            out: dict[int, float] = {}
            for e in self.events:
                if e["ev"] == ev and (src is None or e.get("src") == src):
                    out.setdefault(int(e["seq"]), float(e["t"]))
            return out

    def stalls(self) -> list[tuple[float, float]]:
        """(from, to) wall times of each cycle the master started more than 20 ms late."""
        with self._cond:
            return [(float(e["t0"]), float(e["t"])) for e in self.events if e["ev"] == "late"]

    def stderr(self) -> str:
        return self.stderr_path.read_text(errors="replace")[-3000:]

    def finish(self, timeout: float) -> dict[str, Any]:
        """The ``done`` event after the master exited by itself (exit 0)."""
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.kill()
            raise AssertionError(f"{self.lib} master ({self.kind}) did not finish: {self.stderr()}") from None
        self._reader.join(5)
        assert self.proc.returncode == 0, self.stderr()
        return self.wait("done", 0)

    def kill(self) -> None:
        """SIGKILL, as a crashed or killed master process ends (``ip netns exec`` execs the interpreter, so the
        pid is the master's)."""
        if self.proc.poll() is None:
            os.kill(self.proc.pid, signal.SIGKILL)
        self.proc.wait(10)
        self._reader.join(5)


# ------------------------------------------------------------------------------------------ python-can clients
#: a frame's 8 data bytes: sequence number, sender's tag (ethercat_userpath_master.py)
FRAME = struct.Struct("<II")
_tags = itertools.count(1)


@dataclass
class CanClient:
    """A python-can client of the rig's bus: records the master's frames it received (seq -> wall time)
    and, once :meth:`start_sending` was called, sends one frame each ``SEND_PERIOD`` (seq -> wall time just
    before ``send``). Subclasses are the ways users write the receiving side."""

    style: ClassVar[str] = "python-can"
    endpoint: str
    #: (sender's tag, seq) -> wall time, of the master's frames: a master's tag is its pid
    received: dict[tuple[int, int], float] = field(default_factory=dict)
    bus_times: dict[tuple[int, int], float] = field(default_factory=dict)
    duplicates: list[tuple[int, int]] = field(default_factory=list)
    sent: dict[int, float] = field(default_factory=dict)
    errors: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._stop = threading.Event()
        self._sending = threading.Event()
        self._send_until = self._send_from = 0.0
        self._opened = threading.Event()
        self._threads: list[threading.Thread] = []
        self.tag = os.getpid() << 8 | next(_tags) & 0xFF

    # what each client does with a frame it got
    def heard(self, msg: can.Message) -> None:
        t = time.time()
        if msg.arbitration_id != M2C_ID or len(msg.data) != FRAME.size:
            return
        seq, src = FRAME.unpack(msg.data)
        if (src, seq) in self.received:
            self.duplicates.append((src, seq))
        else:
            self.received[src, seq] = t
            self.bus_times[src, seq] = msg.timestamp

    def received_from(self, src: int, bus_time: bool = False) -> dict[int, float]:
        """seq -> wall time the client got each frame of the master with tag (pid) ``src`` (with ``bus_time``:
        the frame's ``Message.timestamp``, its end on the bus)."""
        times = self.bus_times if bus_time else self.received
        return {seq: t for (tag, seq), t in times.items() if tag == src}

    def send_due(self, bus: can.BusABC, next_at: list[float]) -> None:
        """Send the next frame when its time came (called from a cyclic loop). The first one waits until the
        master's first frame arrived (at most ``QUIET_S``): the master's first frame after OP crosses a quiet
        bus, as it does for a user whose nodes answer the master (the rig's loop is not woken by this
        client's traffic meanwhile: issue 21 defect 3 hid behind it)."""
        now = time.monotonic()
        if not self._sending.is_set() or now < next_at[0] or now > self._send_until:
            return
        if not self.sent and not self.received and now < self._send_from + QUIET_S:
            return
        seq = len(self.sent)
        self.sent[seq] = time.time()
        bus.send(can.Message(arbitration_id=C2M_ID, data=FRAME.pack(seq, self.tag), is_extended_id=False),
                 timeout=0.5)
        next_at[0] = max(next_at[0] + SEND_PERIOD, now)

    def start_sending(self, seconds: float) -> None:
        self._send_from = time.monotonic()
        self._send_until = self._send_from + seconds
        self._sending.set()

    def _guard(self, target: Any) -> Any:
        def run() -> None:
            try:
                target()
            except Exception as exc:  # a client failing is a test failure, reported by stop()
                self.errors.append(f"{type(exc).__name__}: {exc}")
        return run

    def _spawn(self, target: Any) -> None:
        thread = threading.Thread(target=self._guard(target), daemon=True)
        thread.start()
        self._threads.append(thread)

    def _sender(self, bus: can.BusABC) -> None:
        next_at = [0.0]
        while not self._stop.wait(0.001):
            self.send_due(bus, next_at)

    def start(self) -> CanClient:
        self._spawn(self.main)
        assert self._opened.wait(10), f"client not connected: {self.errors}"
        return self

    def main(self) -> None:
        raise NotImplementedError

    def stop(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(10)
        assert not self.errors, self.errors


class PollLoopClient(CanClient):
    """One cyclic task (1 ms) that drains the bus with ``while (msg := bus.recv(0)) is not None`` and sends
    its own frames when due: python-can's ``virtual`` returns every frame that way."""

    style = "recv(0) poll loop in a cyclic task"

    def main(self) -> None:
        with can.Bus(interface="gatewaylab", channel=self.endpoint) as bus:
            self._opened.set()
            next_at = [0.0]
            while not self._stop.wait(0.001):
                while (msg := bus.recv(0)) is not None:
                    self.heard(msg)
                self.send_due(bus, next_at)


class TimeoutClient(CanClient):
    """``bus.recv(0.05)`` in a receive thread, a sender thread beside it."""

    style = "recv(timeout)"

    def main(self) -> None:
        with can.Bus(interface="gatewaylab", channel=self.endpoint) as bus:
            self._spawn(lambda: self._sender(bus))
            self._opened.set()
            while not self._stop.is_set():
                msg = bus.recv(0.05)
                if msg is not None:
                    self.heard(msg)


class IterClient(CanClient):
    """``for msg in bus:`` in a receive thread (ended by ``shutdown()`` from the context manager's exit,
    which python-can turns into an error on the next ``recv``), a sender thread beside it."""

    style = "for msg in bus"

    def main(self) -> None:
        bus = can.Bus(interface="gatewaylab", channel=self.endpoint)
        with bus:
            self._spawn(lambda: self._sender(bus))
            self._spawn(lambda: self._iterate(bus))
            self._opened.set()
            self._stop.wait()

    def _iterate(self, bus: can.BusABC) -> None:
        with contextlib.suppress(can.CanOperationError):
            for msg in bus:
                self.heard(msg)
                if self._stop.is_set():
                    break


class NotifierClient(CanClient):
    """``can.Notifier(bus, [can.BufferedReader()])`` and ``reader.get_message(timeout)`` in a loop, a sender
    thread beside it."""

    style = "can.Notifier + BufferedReader"

    def main(self) -> None:
        with can.Bus(interface="gatewaylab", channel=self.endpoint) as bus:
            reader = can.BufferedReader()
            notifier = can.Notifier(bus, [reader], timeout=0.05)
            try:
                self._spawn(lambda: self._sender(bus))
                self._opened.set()
                while not self._stop.is_set():
                    msg = reader.get_message(0.05)
                    if msg is not None:
                        self.heard(msg)
            finally:
                notifier.stop()


# ------------------------------------------------------------------------------------------ latencies
def pct(values: list[float], q: float) -> float:
    s = sorted(values)
    return s[min(len(s) - 1, int(q * len(s)))]


@dataclass(frozen=True)
class Latency:
    """One direction: the first frame after OP and the steady state after it, in seconds. Frames whose way
    overlapped a stall of the master process (a cycle more than 20 ms late: the shared machine did not run
    it) are counted apart, not judged (the brief of the wire tests: count late cycles, do not assert them)."""

    name: str
    first: float
    steady: list[float]
    missing: list[int]
    #: master -> CAN: the same measured to the frame's end on the bus (python-can's ``Message.timestamp``, the
    #: rig's bus time in Unix time): the gateway's share, without the delivery to the client
    on_bus: list[float] = field(default_factory=list)
    #: latencies of the frames that crossed a stall of the master (the first frame's included when it did)
    stalled: list[float] = field(default_factory=list)
    first_stalled: bool = False

    @property
    def median(self) -> float:
        return statistics.median(self.steady)

    @property
    def p99(self) -> float:
        return pct(self.steady, 0.99)

    def show(self) -> str:
        text = (f"{self.name}: first frame after OP {1e3 * self.first:.1f} ms"
                f"{' (across a stall of the master)' if self.first_stalled else ''}, steady median "
                f"{1e3 * self.median:.2f} ms p99 {1e3 * self.p99:.2f} ms max {1e3 * max(self.steady):.2f} ms "
                f"({len(self.steady)} frames, {len(self.missing)} missing)")
        if self.on_bus:
            text += (f"; to the end of the frame on the bus: median {1e3 * statistics.median(self.on_bus):.2f} ms "
                     f"p99 {1e3 * pct(self.on_bus, 0.99):.2f} ms")
        if self.stalled:
            text += f"; {len(self.stalled)} frames across a stall of the master, max {1e3 * max(self.stalled):.1f} ms"
        print(text)
        return text


def latency(name: str, sent: dict[int, float], got: dict[int, float], tail: float = 0.2,
            on_bus: dict[int, float] | None = None, stalls: Sequence[tuple[float, float]] = ()) -> Latency:
    """Latencies of the frames ``got`` of those ``sent`` (seq -> wall time); frames sent in the last ``tail``
    seconds may still be in flight and do not count as missing; ``stalls`` are the master's (from, to)."""
    assert sent and 0 in sent, f"{name}: nothing sent"
    assert 0 in got, f"{name}: the first frame never arrived ({len(got)} of {len(sent)} did)"
    last = max(sent.values()) - tail

    def crossed(s: int) -> bool:
        return any(a < got[s] and b > sent[s] for a, b in stalls)

    steady = [got[s] - t for s, t in sent.items() if s > 0 and s in got and not crossed(s)]
    stalled = [got[s] - t for s, t in sent.items() if s > 0 and s in got and crossed(s)]
    missing = sorted(s for s, t in sent.items() if s not in got and t < last)
    assert len(steady) >= 20, f"{name}: only {len(steady)} frames arrived outside the master's stalls"
    bus = [on_bus[s] - t for s, t in sent.items() if on_bus and s in on_bus and not crossed(s)]
    return Latency(name, got[0] - sent[0], steady, missing, bus, stalled, crossed(0))


def beyond_bounds(lat: Latency, first: bool = True) -> str | None:
    """Issue 21's bounds on one direction: the first frame after OP < 100 ms (when ``first``), steady p99
    < 50 ms; the direction's line when it is beyond them, else None (the line is printed either way)."""
    text = lat.show()
    late_first = first and lat.first >= FIRST_FRAME_S and not lat.first_stalled
    return text if late_first or lat.p99 >= STEADY_P99_S else None


# ------------------------------------------------------------------------------------------ one session


@dataclass
class Session:
    """One master's run with one CAN client: the master's events, the client's records, both directions'
    latencies (master -> CAN from the master's ``tx`` times, CAN -> master from the client's sends)."""

    master: MasterRun
    client: CanClient
    done: dict[str, Any] | None
    m2c: Latency
    c2m: Latency


def describe(master: MasterRun, client: CanClient) -> str:
    """What each side sent and received (the client's frames by sender)."""
    sources = collections.Counter(src for src, _seq in client.received)
    return (f"master pid {master.proc.pid}: {len(master.times('tx'))} frames sent, {len(master.times('rx'))} "
            f"received; the client received {dict(sources)} (frames by sender), sent {len(client.sent)}")


def exchange(user: UserRig, lib: str, kind: str, client: CanClient, seconds: float = 1.5,
             kill_after: float | None = None) -> Session:
    """``client`` connected first (a user's bus monitor is up before the master), then the master: once it
    reports OP the client sends its frames. With ``kill_after`` the master is SIGKILLed that many seconds
    after OP, in the middle of the exchange; else it ends by itself after ``seconds`` of cycles."""
    client.start()
    try:
        master = user.master(lib, kind, seconds if kill_after is None else 600.0)
    except BaseException:
        client.stop()
        raise
    try:
        client.start_sending(seconds - 0.4 if kill_after is None else 600.0)
        done: dict[str, Any] | None = None
        if kill_after is None:
            done = master.finish(60.0)
        else:
            try:
                master.wait("rx", 30.0, n=int(kill_after / SEND_PERIOD))   # frames flow both ways
            except AssertionError as exc:
                raise AssertionError(f"{exc}; {describe(master, client)}") from None
            master.kill()
        threading.Event().wait(0.2)      # the last frames reach the client
    finally:
        master.kill()
        client.stop()
    if done is not None:
        print(f"{lib} {kind}: {done['cycles']} cycles, {done['bad_wkc']} lost or wrong, {done['late']} late > 20 ms")
        if user.rig.proc.poll() is None:    # (a test may have ended the rig meanwhile)
            check_reruns(done.get("retries", []), rig_wire_stats(user.rig.info))
    tail = 0.2 if kill_after is None else 1.0
    print(f"{lib} {kind}: {describe(master, client)}")
    stalls = master.stalls()
    m2c = latency(f"{lib} {kind} master -> CAN ({client.style})", master.times("tx"),
                  client.received_from(master.proc.pid), tail, client.received_from(master.proc.pid, bus_time=True),
                  stalls)
    c2m = latency(f"{lib} {kind} CAN -> master ({client.style})", client.sent, master.times("rx", client.tag), tail,
                  stalls=stalls)
    return Session(master, client, done, m2c, c2m)


def bounded(session: Session, again: Callable[[], Session], check: Callable[[Session], None],
            m2c_first: bool = True) -> Session:
    """``check(session)`` (what must hold in every session), then the bounds on both directions. A session
    beyond them is measured once more with ``again()``, and the test fails only when that one is beyond them
    too: a stall of this shared machine (the rig process not scheduled for 100-200 ms, seen about once in ten
    sessions with eight test suites on two CPUs) is rare and does not repeat, a lag of the gateway (issue 21
    defect 3: 250 ms) does. Both sessions' numbers are printed."""
    failed: list[str] = []
    for attempt in range(2):
        if attempt:
            print(f"beyond the bounds once, measuring again: {failed}")
            session = again()
        check(session)
        failed = [t for lat, first in ((session.m2c, m2c_first), (session.c2m, True))
                  if (t := beyond_bounds(lat, first)) is not None]
        if not failed:
            return session
    raise AssertionError(failed)
