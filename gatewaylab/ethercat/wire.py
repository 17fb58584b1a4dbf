"""Raw-socket transport: a segment answering EtherCAT frames on a named network interface.

An AF_PACKET socket bound to EtherType 0x88A4 is served by its own thread. The thread keeps polling
the socket for :data:`SPIN_AFTER_FRAME_S` after each frame (a master's mailbox exchange or
back-to-back cycles answer within microseconds), and otherwise blocks in ``select`` on the socket
and a wake-up socket, so an idle line costs no CPU (a busy poll burns a whole core of a 2-CPU
machine; the numbers are in docs/decisions.md and ``benchmarks/bench_ethercat.py``).
``busy_poll=True`` keeps the old behaviour (never block; for a pinned, dedicated CPU). Frames the
socket itself sent (PACKET_OUTGOING) are ignored. Protocol state is touched only under
``clock.lock``; with ``drive_clock`` the thread also runs due clock events (standalone use without
a rig runtime, so SM watchdogs and SYNC0 keep working).

The frame loop outlives any exception raised while a frame is processed (or a clock event runs):
the frame is dropped, one log line is written and ``frame_errors`` counts it, and the next frame is
served, as a real ESC keeps forwarding whatever one frame held.

Replies on time or not at all: a frame older than ``max_residence_ms`` -- its age counted from the
kernel's receive timestamp (``SO_TIMESTAMPNS``) to the moment the segment can take it (the kernel's
queue, a backlog, the wait for ``clock.lock``), or older than that when its reply is ready unless the segment's
own work on it (thread CPU time) took more than the rest of that time plus half the limit -- is
dropped, counted (``frames_dropped_late``) and logged once per burst (ethercat/residence.py), so after a
stall of this process the master sees lost frames, never replies no real line would deliver.

The rig's loop runs the CAN side in another thread of this process: the thread holding the interpreter lock
gives it up to a waiting one only after the interpreter's switch interval. So the loop asks
:meth:`WireTransport.frame_waiting` (``Clock.urgent``) after each event and steps aside while a frame waits,
and the wire thread raises ``clock.waiting`` from the moment it has a frame until it holds ``clock.lock``.

:meth:`WireTransport.stop` wakes the thread wherever it waits (``select``, or ``clock.lock``, which
the rig holds while it stops its participants) and returns within milliseconds.

Cable redundancy (``redundant=`` a second interface): the thread serves a second socket on the interface cabled to
the last slave's port 1 (ethercat/ring.py); a frame goes back out on the socket of the port it leaves the ring by
(``Segment.exit_a`` for frames from the primary interface, ``Segment.process_secondary`` for the others).
"""

from __future__ import annotations

import logging
import os
import select
import socket
import threading
import time
from collections.abc import Callable
from time import thread_time_ns
from typing import Any, cast

from gatewaylab.common.clock import Clock, RealTimeClock
from gatewaylab.common.errors import ConfigError
from gatewaylab.ethercat.datagram import ETHERTYPE_ETHERCAT
from gatewaylab.ethercat.residence import (
    DEFAULT_MAX_RESIDENCE_MS,
    SCM_TIMESTAMPNS,
    SOL_SOCKET,
    LateDrops,
    is_late,
    kernel_timestamp_ns,
    residence_limit_ns,
)
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.wire_pcap import PcapWriter

__all__ = [
    "AFTER_FRAME_MAX",
    "ANCILLARY_BYTES",
    "DRIVE_MAX_STARVE_S",
    "DRIVE_MAX_WAIT_S",
    "DRIVE_PASS_EVENTS",
    "DRIVE_PASS_S",
    "LOCK_POLL_S",
    "MAX_ERRORS_KEPT",
    "PACKET_OUTGOING",
    "REALTIME_PRIORITY",
    "SPIN_AFTER_FRAME_S",
    "STOP_JOIN_S",
    "WireTransport",
    "make_ordinary",
    "make_realtime",
]


PACKET_OUTGOING = 4
_log = logging.getLogger(__name__)
MAX_ERRORS_KEPT = 100
#: Seconds the thread keeps polling after a frame before it blocks on the socket (docs/decisions.md).
SPIN_AFTER_FRAME_S = 0.0002
#: With ``drive_clock``: the longest blocking wait, so an event another thread scheduled under the
#: lock (without waking anyone) still runs within this time.
DRIVE_MAX_WAIT_S = 0.001
#: With ``drive_clock``: clock events one pass runs at most (the drives' control periods, ~10-20 us
#: each compiled); passes follow each other for up to ``DRIVE_PASS_S``, then the thread looks at its
#: socket again, so a frame waits for that much of the work the last frame left instead of all of it
#: (~460 us at 32 drives), and the clock still gets whole slices of time: a look at the socket after
#: every pass of 4 let a 4 kHz segment's CAN buses fall behind real time and lose frames.
DRIVE_PASS_EVENTS = 4
DRIVE_PASS_S = 0.0002
#: With ``drive_clock``: frames come first, but never for longer than this without a clock slice. After a
#: stall the socket holds a backlog a busy segment drains only slowly (a 4 kHz frame every 250 us, each
#: taking most of that): frames first without a bound starved the clock for up to 28 ms, and the CAN
#: controllers' TX FIFOs (32 frames, 1 frame/ms each) overflowed behind it (docs/performance.md, 4 kHz row).
DRIVE_MAX_STARVE_S = 0.0005
#: Frames answered back to back at most before the applications' work they left runs (it runs earlier,
#: as soon as no other frame waits): a backlog still reaches the drives' outputs.
AFTER_FRAME_MAX = 4
#: How often a thread waiting for ``clock.lock`` looks whether it was asked to stop.
LOCK_POLL_S = 0.002
#: How long :meth:`WireTransport.stop` waits for the thread (it ends within ``LOCK_POLL_S``).
STOP_JOIN_S = 1.0
#: ``realtime=True``: the wire thread's SCHED_FIFO priority -- above every ordinary thread (and the rig's loop
#: thread, ``rig/segment.py``), far below the kernel's own real-time threads (up to 99); the kernel's real-time
#: throttling still leaves ordinary threads 5 % of each CPU, so nothing becomes unkillable.
REALTIME_PRIORITY = 10


def make_realtime(priority: int) -> str | None:
    """Give the calling thread SCHED_FIFO ``priority`` (threads it starts later do not inherit it:
    SCHED_RESET_ON_FORK); None when granted, else why not (it needs root or CAP_SYS_NICE)."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(priority))
    except (OSError, AttributeError) as exc:
        return str(exc)
    return None


def make_ordinary(tid: int) -> None:
    """Put thread ``tid`` back to ordinary scheduling (SCHED_OTHER); nothing if it is gone."""
    try:
        os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))
    except (OSError, AttributeError):
        pass


#: Room for the receive timestamp (one cmsg holding a struct timespec) in ``recvmsg``.
ANCILLARY_BYTES = 64


class WireTransport:
    """Serve ``segment`` on ``interface`` until ``stop()``."""

    def __init__(self, segment: Segment, interface: str, clock: Clock, *, busy_poll: bool = False,
                 drive_clock: bool = False, pcap: PcapWriter | None = None, cpu: int | None = None,
                 spin_s: float = SPIN_AFTER_FRAME_S,
                 max_residence_ms: float = DEFAULT_MAX_RESIDENCE_MS,
                 now_ns: Callable[[], int] = time.time_ns, realtime: bool = True,
                 redundant: str | None = None) -> None:
        self.segment = segment
        self.interface = interface
        #: the master's secondary interface's peer (cable redundancy), or None
        self.redundant = redundant
        self.clock = clock
        self.busy_poll = busy_poll
        self.spin_s = spin_s
        self.drive_clock = drive_clock
        self.pcap = pcap
        self.cpu = cpu
        #: Ask for SCHED_FIFO (``REALTIME_PRIORITY``) for the wire thread, as the rig's ``[ethercat] realtime``
        #: does by default; ``realtime_granted`` says if it got it.
        self.realtime = realtime
        self.realtime_granted = False
        self._sock: socket.socket | None = None
        self._sock_b: socket.socket | None = None
        self._wake_r: socket.socket | None = None
        self._wake_w: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._poller = select.poll()    # the sockets, for frame_waiting (a new one each time the thread starts)
        self._running = False
        self.frames_in = 0
        self.frames_out = 0
        #: Frames whose processing raised (and failed receives, clock events that raised): each dropped,
        #: logged on one line, counted.
        self.frame_errors = 0
        self.errors: list[str] = []
        #: The longest a frame may stay here, from its receive timestamp to its reply (0: no limit);
        #: older frames are dropped (ethercat/residence.py), counted in ``late.total``.
        self.max_residence_ns = residence_limit_ns(max_residence_ms)
        self.late = LateDrops()
        #: Unix time in nanoseconds, the time base of the kernel's receive timestamps (injected by tests)
        self.now_ns = now_ns
        #: False when the kernel gives no receive timestamps: ages then count from the ``recvmsg`` call.
        self.kernel_timestamps = False

    @property
    def frames_dropped_late(self) -> int:
        """Frames not answered because they were older than ``max_residence_ms`` (the master lost them)."""
        return self.late.total

    def stats(self) -> dict[str, int]:
        """The wire's counters (what the control request ``ethercat-states`` shows under ``wire``):
        ``frames_late_on_arrival`` are the late drops that reached an idle wire thread already too old (the
        machine held them), the rest of ``frames_dropped_late`` waited behind the emulator's own work."""
        return {"frames_in": self.frames_in, "frames_out": self.frames_out,
                "frames_dropped_late": self.frames_dropped_late,
                "frames_late_on_arrival": self.late.on_arrival, "frame_errors": self.frame_errors}

    def _open(self, interface: str) -> socket.socket:
        """A non-blocking raw EtherCAT socket bound to ``interface``, with receive timestamps if it can."""
        try:
            sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETHERTYPE_ETHERCAT))
        except PermissionError as exc:
            raise ConfigError(f"raw sockets need CAP_NET_RAW: {exc}") from exc
        try:
            sock.bind((interface, ETHERTYPE_ETHERCAT))
        except OSError as exc:
            sock.close()
            raise ConfigError(f"cannot bind to interface {interface!r}: {exc}") from exc
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        try:    # the kernel's receive time of each frame, the start of its age
            sock.setsockopt(SOL_SOCKET, SCM_TIMESTAMPNS, 1)
            self.kernel_timestamps = True
        except OSError:
            self.kernel_timestamps = False
        sock.setblocking(False)
        return sock

    def start(self) -> None:
        """Open the raw socket(s) on the interface(s) and start the wire thread serving the segment."""
        sock = self._open(self.interface)
        if self.redundant is not None:
            try:
                self._sock_b = self._open(self.redundant)
            except ConfigError:
                sock.close()
                raise
        self.clock.ensure_lock()  # this thread and the clock's owner share the state
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self._sock = sock
        self._running = True
        self._thread = threading.Thread(target=self._run, name=f"ethercat-wire-{self.interface}", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """End the thread (woken wherever it waits) and close the socket; idempotent. The caller may
        hold ``clock.lock`` (the rig stops its participants holding it)."""
        self._running = False
        if self._wake_w is not None:
            try:
                self._wake_w.send(b"\0")
            except OSError:     # full: a wake-up is pending anyway
                pass
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(STOP_JOIN_S)
            if thread.is_alive():
                _log.warning("ethercat-wire %s: the wire thread did not end within %.1f s", self.interface,
                             STOP_JOIN_S)
        self._report_late(self.now_ns(), final=True)
        for name in ("_sock", "_sock_b", "_wake_r", "_wake_w"):
            sock = getattr(self, name)
            if sock is not None:
                sock.close()
                setattr(self, name, None)

    def _report_late(self, now_ns: int, final: bool = False) -> None:
        """Log the late drops of the burst that just ended (one line per burst, at most one a second)."""
        burst = self.late.flush(now_ns) if final else self.late.settle(now_ns)
        if burst is not None:
            _log.warning("ethercat-wire %s: %s (%d so far)", self.interface, burst.describe(self.max_residence_ns),
                         self.late.total)

    def _fault(self, what: str, exc: BaseException) -> None:
        self.frame_errors += 1
        text = " ".join(str(exc).split())  # one log line, whatever the message holds
        _log.error("ethercat-wire %s: %s raised %s: %s (dropped; %d so far)", self.interface, what,
                   type(exc).__name__, text, self.frame_errors)

    def _acquire(self, lock: Any) -> bool:
        """Take ``clock.lock``; False once :meth:`stop` was called meanwhile (whoever stops this thread
        may hold the lock while it waits for the thread to end). While it waits, ``clock.waiting`` says so:
        the rig's loop ends its pass of events after the one that runs and lets this thread in first."""
        if lock.acquire(False):
            return True
        clock = self.clock
        clock.waiting += 1
        try:
            while self._running:
                if lock.acquire(True, LOCK_POLL_S):
                    return True
            return False
        finally:
            clock.waiting -= 1

    def _clock_slice(self, clock: RealTimeClock, lock: Any, overdue: float = 0.0) -> tuple[int, float | None] | None:
        """With ``drive_clock``: take ``clock.lock`` and run passes of ``DRIVE_PASS_EVENTS`` due events for up
        to ``DRIVE_PASS_S`` -- only when the earliest event is ``overdue`` seconds late, if given. Returns
        (events the last pass ran, the next deadline), or None once :meth:`stop` was called."""
        if not self._acquire(lock):
            return None
        limit = clock.pass_limit
        ran = 0
        try:
            due = clock.next_deadline()
            if overdue and (due is None or clock.now() - due < overdue):
                return 0, due
            clock.pass_limit = DRIVE_PASS_EVENTS   # this thread drives the clock
            slice_end = time.monotonic() + DRIVE_PASS_S
            while True:
                ran = clock.run_due()
                if ran < DRIVE_PASS_EVENTS or time.monotonic() >= slice_end:
                    break
            due = clock.next_deadline()
        except Exception as exc:
            self._fault("a clock event", exc)
            due = None
        finally:
            clock.pass_limit = limit
            lock.release()
        return ran, due

    def _after_frame(self, segment: Segment, lock: Any) -> bool:
        """The applications' work the answered frames left (:meth:`Segment.after_frame`, under ``clock.lock``);
        False once :meth:`stop` was called meanwhile."""
        if not self._acquire(lock):
            return False
        try:
            segment.after_frame()
        except Exception as exc:
            self._fault("the applications' work after a frame", exc)
        finally:
            lock.release()
        return True

    def _wait(self, sock: socket.socket, wake: socket.socket, timeout: float | None) -> None:
        """Block until a frame (or a wake-up from :meth:`stop`) arrives or ``timeout`` passed."""
        watched = [sock, wake] if self._sock_b is None else [sock, self._sock_b, wake]
        ready, _, _ = select.select(watched, [], [], timeout)
        if wake in ready:
            try:
                while wake.recv(64):
                    pass
            except OSError:
                pass

    def _schedule(self) -> None:
        """Pin the wire thread (``cpu``) and give it real-time priority (``realtime``), as far as allowed."""
        if self.cpu is not None and hasattr(os, "sched_setaffinity"):
            try:
                os.sched_setaffinity(0, {self.cpu})
            except OSError as exc:
                _log.warning("ethercat-wire %s: cannot pin the wire thread to CPU %d: %s", self.interface, self.cpu,
                             exc)
        if not self.realtime:
            return
        if self.busy_poll:
            _log.warning("ethercat-wire %s: realtime = true is not applied with busy_poll = true (a real-time thread "
                         "that never blocks would take its CPU from every other thread)", self.interface)
            return
        why = make_realtime(REALTIME_PRIORITY)
        if why is not None:
            _log.warning("ethercat-wire %s: realtime = true, but the wire thread may not have SCHED_FIFO (%s; it "
                         "needs root or CAP_SYS_NICE): it runs with ordinary priority, and its replies may come "
                         "late on a loaded machine", self.interface, why)
        else:
            self.realtime_granted = True
            _log.info("ethercat-wire %s: the wire thread runs SCHED_FIFO priority %d", self.interface,
                      REALTIME_PRIORITY)

    @staticmethod
    def _recv_either(sock: socket.socket, sock_b: socket.socket,
                     buf: bytearray) -> tuple[int, tuple[int, list[tuple[int, int, bytes]], int, Any]]:
        """(0 or 1, ``recvmsg_into``) of the primary socket, else the secondary; BlockingIOError when both are idle."""
        try:
            return 0, sock.recvmsg_into([buf], ANCILLARY_BYTES)
        except BlockingIOError:
            return 1, sock_b.recvmsg_into([buf], ANCILLARY_BYTES)

    def _send(self, sock: socket.socket, frame: bytes | bytearray) -> None:
        """Send one reply (counted, captured); a failed send is kept in ``errors``."""
        try:
            sock.send(frame)
        except OSError as exc:
            if len(self.errors) < MAX_ERRORS_KEPT:  # a storm must not grow the list without end
                self.errors.append(str(exc))
        else:
            self.frames_out += 1
            if self.pcap is not None:
                self.pcap.write(time.time(), frame)

    def _send_held(self, sock: socket.socket, lock: Any) -> float | None:
        """Send the replies a line fault held back whose time has come (a fault's deliberate delay is not
        a late frame: ``max_residence_ms`` does not apply to it); seconds until the next one, or None."""
        faults = self.segment.line_faults
        if faults is None or not self._acquire(lock):
            return None
        try:
            now = time.monotonic()
            replies = faults.due(now)
            due = faults.next_due()
        finally:
            lock.release()
        for reply in replies:
            self._send(sock, reply)
        return None if due is None else max(0.0, due - now)

    def frame_waiting(self) -> bool:
        """A frame waits in the socket(s): the rig's loop asks this after each event (``Clock.urgent``) and
        steps aside, so this thread gets the interpreter lock and ``clock.lock`` at once instead of after the
        interpreter's switch interval."""
        try:
            return bool(self._poller.poll(0))
        except (RuntimeError, OSError):     # another thread's poll at this very moment; a socket closed
            return False

    def _run(self) -> None:
        if self.drive_clock:    # this thread runs the clock's events itself: nobody else to step aside
            self._serve()
            return
        self._poller = select.poll()    # this run's sockets only (a restarted wire has new ones)
        for s in (self._sock, self._sock_b):
            if s is not None:
                self._poller.register(s, select.POLLIN)
        probe = self.frame_waiting
        self.clock.urgent.append(probe)
        try:
            self._serve()
        finally:
            self.clock.urgent.remove(probe)

    def _serve(self) -> None:
        self._schedule()
        sock, wake = self._sock, self._wake_r
        assert sock is not None and wake is not None
        buf = bytearray(2048)
        clock = self.clock
        lock = cast(Any, clock.lock)     # an RLock: start() installed one if there was none
        segment = self.segment
        pcap = self.pcap
        drive = self.drive_clock and isinstance(clock, RealTimeClock)
        busy = self.busy_poll
        spin = self.spin_s
        spin_until = 0.0
        next_clock = 0.0
        last_slice = time.monotonic()
        limit = self.max_residence_ns
        late = self.late
        now_ns = self.now_ns
        sock_b = self._sock_b   # cable redundancy: the secondary interface
        port = 0                # the interface the frame came in on (0: primary, 1: secondary)
        after = 0               # frames answered whose applications' work (Segment.after_frame) is still due
        idle_since = 0          # when the thread last found its socket empty (0: busy with frames since)
        while self._running:
            if drive and time.monotonic() - last_slice >= DRIVE_MAX_STARVE_S:
                # no clock slice for that long: when an event is overdue by as much (frames back to back,
                # a backlog), the clock's slice comes before the next frame
                assert isinstance(clock, RealTimeClock)
                if self._clock_slice(clock, lock, DRIVE_MAX_STARVE_S) is None:
                    return
                last_slice = time.monotonic()
            try:
                if sock_b is None:
                    n, anc, _flags, addr = sock.recvmsg_into([buf], ANCILLARY_BYTES)
                else:
                    port, (n, anc, _flags, addr) = self._recv_either(sock, sock_b, buf)
            except BlockingIOError:
                if not idle_since:  # the line fell idle: a frame stamped after this found the thread waiting
                    idle_since = now_ns()
                if after:           # no other frame waits: the applications' work the frames left
                    after = 0
                    if not self._after_frame(segment, lock):
                        return
                    continue        # a look at the socket again before blocking
                if late.pending:    # the line is idle: the burst of late frames is over
                    t_ns = now_ns()
                    self._report_late(t_ns)
                    report_in = late.report_due_in_ns(t_ns)
                else:
                    report_in = None
                now = time.monotonic()
                timeout: float | None = None
                if drive:
                    assert isinstance(clock, RealTimeClock)
                    if now >= next_clock:
                        turn = self._clock_slice(clock, lock)
                        if turn is None:
                            return
                        ran, due = turn
                        last_slice = time.monotonic()
                        # a full pass: more may be due, run them after a look at the socket
                        next_clock = now if ran >= DRIVE_PASS_EVENTS else now + 0.0002
                        timeout = DRIVE_MAX_WAIT_S if due is None else min(
                            DRIVE_MAX_WAIT_S, max(0.0, due - clock.now()))
                    else:
                        timeout = next_clock - now
                faults = segment.line_faults
                if faults is not None and faults.held:     # replies a line fault holds back, when due
                    held_in = self._send_held(sock, lock)
                    if held_in is not None:
                        timeout = held_in if timeout is None else min(timeout, held_in)
                if busy or now < spin_until:
                    continue
                if report_in is not None:   # merged into a report due later: wake up for it
                    timeout = report_in / 1e9 if timeout is None else min(timeout, report_in / 1e9)
                self._wait(sock, wake, timeout)
                continue
            except OSError as exc:
                if not self._running:
                    return
                # e.g. ENETDOWN while the interface flaps: keep serving once it is back
                if not self.errors or self.errors[-1] != str(exc):
                    self._fault("receive", exc)
                if len(self.errors) < MAX_ERRORS_KEPT:
                    self.errors.append(str(exc))
                self._wait(sock, wake, 0.01)
                continue
            if addr[2] == PACKET_OUTGOING:
                continue
            received = kernel_timestamp_ns(anc) if anc else None
            if received is None:
                received = now_ns()
            frame = buf[:n]
            self.frames_in += 1
            # came to an idle thread already too old: the kernel or the machine held it, not our work
            held_before = 0 < idle_since <= received and is_late(received, now_ns(), limit)
            idle_since = 0
            try:
                if pcap is not None:
                    pcap.write(received / 1e9, frame)
                clock.waiting += 1      # the loop ends its pass at the running event (Clock.hand_over)
                try:
                    got = self._acquire(lock)
                finally:
                    clock.waiting -= 1
                if not got:
                    return
                try:
                    # its age when the segment could take it: the kernel's queue, our backlog and the wait
                    # for the lock (a stall of this process); the segment's own work on it is not counted
                    # (a state change done inside the frame may take longer in pure Python than a line
                    # holds a frame, and a master with a longer timeout must still get its answer)
                    t_ns = now_ns()
                    if is_late(received, t_ns, limit):   # lost on its way in: not processed
                        late.drop(t_ns - received, on_arrival=held_before)
                        continue
                    cpu_ns = thread_time_ns()
                    if port == 0:
                        faults = segment.line_faults
                        if faults is not None and faults.engaged:   # line faults armed (ethercat/line_faults.py)
                            ok = faults.serve(segment, frame, time.monotonic(), defer=True)
                        else:
                            ok = segment.process(frame, defer=True)
                        out = segment.exit_a if sock_b is not None else 0
                    else:   # the secondary interface: the line faults are those of the primary one
                        faults = None
                        out = segment.process_secondary(frame, defer=True)
                        ok = out >= 0
                finally:
                    lock.release()
                if not ok:
                    continue
                if limit:   # over the limit now, and not mostly by our own work on it (thread CPU time): it
                    t_out = now_ns()   # waited (kill -STOP, a stalled VM, the locks) -- a line never delivers it
                    age = t_out - received
                    if age > limit and age - (thread_time_ns() - cpu_ns) > limit // 2:
                        late.drop(age)
                        continue
                if late.pending:
                    self._report_late(now_ns())
                self._send(sock if out == 0 or sock_b is None else sock_b, frame)
                if faults is not None and faults.held:
                    self._send_held(sock, lock)
                # the applications' work (outputs to the drives) once the frame is on its way back and no
                # other frame waits (the second frame of a split image), or after AFTER_FRAME_MAX frames
                after += 1
                if after >= AFTER_FRAME_MAX:
                    after = 0
                    if not self._after_frame(segment, lock):
                        return
            except Exception as exc:
                self._fault(f"frame {self.frames_in}", exc)
            finally:
                spin_until = time.monotonic() + spin
