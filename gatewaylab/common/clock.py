"""The one clock abstraction every protocol core schedules its timing on.

Protocol code never reads the wall clock and never sleeps: it asks a :class:`Clock` for ``now()``
and schedules callbacks with ``call_at``/``call_later``. Two implementations exist:

* :class:`SimulatedClock` -- a discrete-event scheduler. Time moves only when the owner calls
  :meth:`SimulatedClock.advance` or :meth:`SimulatedClock.run_until`; events due at the same
  instant run in the order they were scheduled. Tests use it: faster than real time, reproducible.
* :class:`RealTimeClock` -- the same event queue read against a monotonic wall clock. Something
  outside the protocol code (the rig runtime's I/O loop) calls :meth:`RealTimeClock.run_due` and
  waits until the next event (:meth:`Clock.begin_wait`); other threads hand work in with
  :meth:`Clock.call_soon_threadsafe` or schedule under :attr:`Clock.lock`, and either wakes the
  loop when the work is due before it would wake by itself. Each ``run_due`` pass runs a bounded
  number of events, so that loop serves its I/O between passes whatever the protocols schedule.

A blocking caller outside the protocol cores (an in-process EtherCAT master polling a mailbox)
lets time pass with :meth:`Clock.wait`, never by moving a simulated clock or spinning itself.
"""

from __future__ import annotations

import heapq
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from typing import Any

from gatewaylab.common.errors import LocalError

__all__ = ["Callback", "Clock", "PeriodicTimer", "RealTimeClock", "SimulatedClock", "TimerHandle"]


Callback = Callable[..., Any]


class TimerHandle:
    """A scheduled callback; ``cancel()`` it to stop it from running."""

    __slots__ = ("args", "callback", "cancelled", "seq", "when")

    def __init__(self, when: float, seq: int, callback: Callback, args: tuple[Any, ...]) -> None:
        self.when = when
        self.seq = seq
        self.callback = callback
        self.args = args
        self.cancelled = False

    def cancel(self) -> None:
        """Keep the callback from running (it stays queued, skipped when due)."""
        self.cancelled = True

    def __repr__(self) -> str:
        name = getattr(self.callback, "__qualname__", repr(self.callback))
        return f"<TimerHandle t={self.when:.9f} #{self.seq} {name}{' cancelled' if self.cancelled else ''}>"


#: The longest :meth:`Clock.hand_over` steps aside for a waiting thread (it takes the lock within
#: microseconds once it runs; a waiter that holds back longer is not waiting on this loop's lock).
HAND_OVER_S = 0.0005


class Clock:
    """Event queue shared by both clocks; subclasses decide what ``now`` means."""

    def __init__(self) -> None:
        #: (when, seq, handle): time first, then scheduling order, so simultaneous events are
        #: stable; tuples compare in C, which matters at tens of thousands of events per second.
        self._heap: list[tuple[float, int, TimerHandle]] = []
        self._seq = 0
        self._injected: deque[tuple[Callback, tuple[Any, ...]]] = deque()
        #: Called (from any thread) after work was injected, or an event was scheduled before the
        #: time the waiting loop wakes up by itself (:meth:`begin_wait`); the runtime sets it to wake its loop.
        self.wakeup: Callable[[], None] | None = None
        #: While the loop that runs this clock waits (between :meth:`begin_wait` and :meth:`end_wait`):
        #: the time it wakes up by itself; an event scheduled before it wakes the loop. -inf otherwise.
        self._wake_before = -math.inf
        #: Serialises access to the protocol state when several threads touch it: a real lock once
        #: :meth:`ensure_lock` was called; single-threaded use needs none (a no-op context).
        self.lock: AbstractContextManager[Any] = nullcontext()
        #: Threads blocked on :attr:`lock` that must not wait for a whole pass of the clock's events (the
        #: EtherCAT wire thread, whose frames a line answers in microseconds): each raises it while it waits;
        #: :meth:`RealTimeClock.run_due` ends its pass after the event that runs, and :meth:`hand_over` lets
        #: them in before the loop takes the lock again.
        self.waiting = 0
        #: Probes of input that must not wait for a whole pass either (the EtherCAT wire's: a frame is
        #: in its socket): the loop asks them after each event and steps aside as for :attr:`waiting`,
        #: so the wire thread, woken by its frame, need not wait for the interpreter lock until the
        #: interpreter's switch interval forces the loop to give it up.
        self.urgent: list[Callable[[], bool]] = []
        #: Unix time (seconds since the epoch) of clock time 0: an event at clock time ``t``
        #: happened at ``wall_epoch + t``. The one time base of traces, client timestamps and the demo.
        self.wall_epoch: float = time.time()

    def ensure_lock(self) -> AbstractContextManager[Any]:
        """Make this clock safe to share between threads, and return its :attr:`lock`.

        The contract: the thread that runs the clock (the rig's loop, a simulation's owner) holds
        :attr:`lock` while it runs events, and every other thread (a wire thread, a python-can
        adapter's caller, a web server, a host library's cycle thread) takes it before it touches
        any state of the protocol cores that share the clock, or schedules on the clock. The lock
        is re-entrant, so a callback may call code that takes it again. The first call installs
        it; later calls (from every component that shares the clock) return the same lock, so
        all of them serialise on one. Protocol code never takes it itself: only the code that
        brings threads in does.
        """
        lock = self.lock
        if isinstance(lock, nullcontext):
            lock = self.lock = threading.RLock()
        return lock

    # -- time ---------------------------------------------------------------------------------
    def now(self) -> float:
        """Seconds since the clock's epoch."""
        raise NotImplementedError

    @property
    def is_simulated(self) -> bool:
        """True for a clock whose time moves only when its owner moves it."""
        return False

    # -- scheduling ---------------------------------------------------------------------------
    def call_at(self, when: float, callback: Callback, *args: Any) -> TimerHandle:
        """Run ``callback(*args)`` at time ``when`` (never before ``now()``)."""
        self._seq = seq = self._seq + 1
        handle = TimerHandle(when, seq, callback, args)
        heapq.heappush(self._heap, (when, seq, handle))
        if when < self._wake_before:
            self._wake_loop()
        return handle

    def reschedule(self, handle: TimerHandle, when: float) -> None:
        """Queue a handle that has run (and is not queued any more) again for ``when``: a fresh
        scheduling (it runs after the events already scheduled for that instant), no new handle.
        For an owner that keeps at most one run of a callback pending (a bus's end of frame)."""
        self._seq = seq = self._seq + 1
        handle.when = when
        handle.seq = seq
        handle.cancelled = False
        heapq.heappush(self._heap, (when, seq, handle))
        if when < self._wake_before:
            self._wake_loop()

    def call_later(self, delay: float, callback: Callback, *args: Any) -> TimerHandle:
        """Run ``callback(*args)`` ``delay`` seconds from now."""
        if delay < 0:
            raise LocalError(f"negative delay {delay}")
        return self.call_at(self.now() + delay, callback, *args)

    def call_soon(self, callback: Callback, *args: Any) -> TimerHandle:
        """Run ``callback(*args)`` now, after the events already due."""
        return self.call_at(self.now(), callback, *args)

    def call_every(self, period: float, callback: Callback, *args: Any,
                   first: float | None = None) -> PeriodicTimer:
        """Run ``callback`` every ``period`` seconds without drift (next = previous + period)."""
        if period <= 0:
            raise LocalError(f"period must be > 0, got {period}")
        return PeriodicTimer(self, period, callback, args, self.now() + (period if first is None else first))

    def call_soon_threadsafe(self, callback: Callback, *args: Any) -> None:
        """Hand work to the thread that runs the clock; safe from any thread."""
        self._injected.append((callback, args))
        wake = self.wakeup
        if wake is not None:
            wake()

    def next_deadline(self) -> float | None:
        """Time of the earliest pending event, or None when nothing is scheduled."""
        heap = self._heap
        while heap and heap[0][2].cancelled:
            heapq.heappop(heap)
        if self._injected:
            return self.now()
        return heap[0][0] if heap else None

    def begin_wait(self) -> float | None:
        """For the loop that runs this clock, before it blocks (in ``select``): the time of the
        earliest pending event (None: none). Until :meth:`end_wait`, scheduling an event before
        that time -- from another thread holding :attr:`lock` (a wire thread, a web server, an
        in-process master) -- calls :attr:`wakeup` once, so the loop never sleeps past an event
        it did not know of when it went to sleep (otherwise a Tx batch the EtherCAT wire thread
        hands to the bus would wait for the loop's next timeout, up to 250 ms)."""
        with self.lock:
            deadline = self.next_deadline()
            self._wake_before = math.inf if deadline is None else deadline
        return deadline

    def hand_over(self, patience: float = HAND_OVER_S) -> None:
        """For the loop that runs this clock, after it released :attr:`lock`: while a thread is
        :attr:`waiting` for the lock or an :attr:`urgent` probe has input, step aside (up to ``patience``
        seconds) so that the thread takes the lock before this thread takes it again -- a released lock goes
        to whoever asks first, and the thread that just released it, still running, would; ``time.sleep(0)``
        also hands over the interpreter lock. Returns at once when nobody waits."""
        if not self.waiting and not self.input_urgent():
            return
        deadline = time.monotonic() + patience
        while (self.waiting or self.input_urgent()) and time.monotonic() < deadline:
            time.sleep(0)   # lets the waiting thread run (and take the lock) on this CPU or its own

    def input_urgent(self) -> bool:
        """True when one of the :attr:`urgent` probes has input waiting."""
        for probe in self.urgent:  # noqa: SIM110 -- a plain loop compiles to less than any(generator)
            if probe():
                return True
        return False

    def end_wait(self) -> None:
        """The loop is awake again (see :meth:`begin_wait`): events it schedules itself wake nobody."""
        self._wake_before = -math.inf

    def _wake_loop(self) -> None:
        """An event falls due before the waiting loop wakes up: wake it (once per wait)."""
        self._wake_before = -math.inf
        wake = self.wakeup
        if wake is not None:
            wake()

    def wait(self, delay: float) -> None:
        """Let ``delay`` seconds pass for a caller that blocks on the clock (an in-process master
        polling a slave): a simulated clock runs its events up to then, a real-time one blocks
        the calling thread without spinning. Protocol code never calls it: it schedules."""
        raise NotImplementedError

    def pending(self) -> int:
        """How many events wait (cancelled ones not counted): for tests and diagnostics."""
        return sum(1 for _, _, h in self._heap if not h.cancelled) + len(self._injected)

    def _drain_injected(self) -> None:
        injected = self._injected
        while injected:
            callback, args = injected.popleft()
            self.call_soon(callback, *args)


class PeriodicTimer:
    """A drift-free repeating timer on a :class:`Clock`."""

    __slots__ = ("_count", "_handle", "_origin", "args", "callback", "clock", "next_time", "period")

    def __init__(self, clock: Clock, period: float, callback: Callback, args: tuple[Any, ...],
                 first: float) -> None:
        self.clock = clock
        self.period = period
        self.callback = callback
        self.args = args
        self.next_time = first
        self._origin = first
        self._count = 0
        self._handle: TimerHandle | None = clock.call_at(first, self._fire)

    def _fire(self) -> None:
        # origin + k * period: no accumulated rounding error however long it runs.
        self._count = count = self._count + 1
        self.next_time = when = self._origin + count * self.period
        # one pending run per timer: the handle that has just fired is queued again
        if self._handle is not None:
            self.clock.reschedule(self._handle, when)
        self.callback(*self.args)

    def cancel(self) -> None:
        """Stop the timer (idempotent)."""
        if self._handle is not None:
            self._handle.cancel()
            self._handle = None

    @property
    def active(self) -> bool:
        """True until the timer is cancelled."""
        return self._handle is not None


class SimulatedClock(Clock):
    """Deterministic discrete-event clock: time jumps from event to event."""

    def __init__(self, start: float = 0.0) -> None:
        super().__init__()
        self._now = start
        self.wall_epoch -= start

    def now(self) -> float:
        """The simulated time: moves only in advance/run_until/step."""
        return self._now

    @property
    def is_simulated(self) -> bool:
        """Always True: nothing runs unless the owner moves the clock."""
        return True

    def step(self) -> bool:
        """Run the earliest event (advancing time to it); False when nothing is scheduled."""
        with self.lock:
            return self._run_next()

    def _run_next(self) -> bool:
        """:meth:`step` for a caller that holds the lock already."""
        if self._injected:
            self._drain_injected()
        heap = self._heap
        while heap:
            when, _, handle = heapq.heappop(heap)
            if handle.cancelled:
                continue
            if when > self._now:
                self._now = when
            handle.callback(*handle.args)
            return True
        return False

    def run_until(self, t: float) -> int:
        """Run every event due at or before ``t`` and leave ``now() == t``; returns events run."""
        count = 0
        with self.lock:
            if t < self._now:
                raise LocalError(f"cannot run backwards to {t} from {self._now}")
            heap = self._heap
            injected = self._injected
            pop = heapq.heappop
            while True:
                if injected:
                    self._drain_injected()
                if not heap:
                    break
                # pop first (one heap operation per event); the one event beyond t goes back
                # with its own (when, seq), so the queue order is unchanged
                item = pop(heap)
                when, _, handle = item
                if handle.cancelled:
                    continue
                if when > t:
                    heapq.heappush(heap, item)
                    break
                if when > self._now:
                    self._now = when
                handle.callback(*handle.args)
                count += 1
            self._now = t
        return count

    def advance(self, dt: float) -> int:
        """Let ``dt`` seconds of simulated time pass."""
        if dt < 0:
            raise LocalError(f"cannot advance by a negative time {dt}")
        with self.lock:  # read "now" under the lock: another thread may be running the clock
            return self.run_until(self._now + dt)

    def wait(self, delay: float) -> None:
        """:meth:`Clock.wait`: the events of the next ``delay`` seconds run, then time is ``now + delay``."""
        self.advance(delay)

    def run_while(self, condition: Callable[[], bool], max_events: int = 1_000_000) -> int:
        """Run events one by one while ``condition()`` holds (e.g. while a bus is busy)."""
        count = 0
        with self.lock:   # taken once, not per event
            while count < max_events and condition() and self._run_next():
                count += 1
        return count


class RealTimeClock(Clock):
    """The event queue against a monotonic wall clock; the rig runtime's loop drives it."""

    def __init__(self) -> None:
        super().__init__()
        self._t0 = time.monotonic()
        self.wall_epoch = time.time()
        #: Called with the exception when a callback raises; None lets it propagate. A running rig
        #: sets it so one faulty callback is logged instead of stopping every device.
        self.on_error: Callable[[BaseException], None] | None = None
        #: Events one :meth:`run_due` pass runs at most (a few milliseconds of work): large enough
        #: to batch a burst of frames into one write per client, small enough to poll I/O often.
        self.pass_limit = 1000

    def now(self) -> float:
        """Monotonic seconds since the clock was made."""
        return time.monotonic() - self._t0

    def wait(self, delay: float) -> None:
        """:meth:`Clock.wait`: block the calling thread for ``delay`` seconds. When no loop runs
        this clock (no :attr:`wakeup` installed, e.g. a script without a rig), run its events
        meanwhile as they fall due."""
        if delay < 0:
            raise LocalError(f"negative delay {delay}")
        deadline = self.now() + delay
        while True:
            alone = self.wakeup is None
            if alone:
                self.run_due()
            now = self.now()
            if now >= deadline:
                return
            until = deadline
            if alone:
                due = self.next_deadline()
                if due is not None and due < until:
                    until = due
            # The one wall-clock wait of the project: RealTimeClock is the adapter between protocol
            # time and wall time, and only blocking clients (the in-process master) call wait();
            # protocol cores schedule on the clock instead.
            time.sleep(max(0.0, until - now))

    def run_due(self) -> int:
        """Run the events that are due, those that fall due meanwhile included, but at most
        :attr:`pass_limit` of them; returns how many ran.

        The limit bounds each pass, so the loop that calls it serves its sockets and signals
        between passes whatever the protocols schedule (frames that take no time, a callback
        that schedules itself for now again and again); what is left runs in the next pass. A pass
        also ends after the running event when a thread is :attr:`waiting` for :attr:`lock`, which
        then takes it first (:meth:`hand_over`)."""
        count = 0
        limit = self.pass_limit
        with self.lock:
            self._drain_injected()
            heap = self._heap
            now = self.now()
            while heap and count < limit:
                when, _, handle = heap[0]
                if handle.cancelled:
                    heapq.heappop(heap)
                    continue
                if when > now:
                    now = self.now()
                    if when > now:
                        break
                heapq.heappop(heap)
                try:
                    handle.callback(*handle.args)
                except Exception as exc:
                    if self.on_error is None:
                        raise
                    self.on_error(exc)
                count += 1
                if self.waiting or (self.urgent and self.input_urgent()):
                    break           # a thread that may not wait for the whole pass: the rest runs later
                self._drain_injected()
        if self.waiting or self.urgent:
            self.hand_over()    # returns at once when nobody waits and no probe has input
        return count
