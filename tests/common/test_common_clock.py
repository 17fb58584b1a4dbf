"""The injected clock: deterministic ordering and time that moves only when told (DEVELOPERS.md, principle 2)."""

import threading

import pytest

from gatewaylab.common.clock import RealTimeClock, SimulatedClock
from gatewaylab.common.errors import LocalError


def test_simultaneous_events_run_in_scheduling_order() -> None:
    """Simultaneous events run in the order they were scheduled (issue 2 §2 'stable ordering of simultaneous
    events')."""
    clock = SimulatedClock()
    seen: list[str] = []
    clock.call_at(1.0, seen.append, "b1")
    clock.call_at(0.5, seen.append, "a")
    clock.call_at(1.0, seen.append, "b2")
    clock.call_at(1.0, seen.append, "b3")
    assert clock.advance(0.99) == 1
    assert seen == ["a"]
    clock.run_until(1.0)
    assert seen == ["a", "b1", "b2", "b3"]
    assert clock.now() == 1.0


def test_events_scheduled_by_events_at_the_same_instant_run_after_the_earlier_ones() -> None:
    """An event scheduled for 'now' by another event runs after the events already due at that instant (issue 2 §2)."""
    clock = SimulatedClock()
    seen: list[str] = []
    clock.call_at(1.0, lambda: (seen.append("first"), clock.call_soon(seen.append, "nested")))
    clock.call_at(1.0, seen.append, "second")
    clock.advance(2.0)
    assert seen == ["first", "second", "nested"]


def test_cancelled_events_do_not_run_and_time_does_not_move_by_itself() -> None:
    """Simulated time moves only when the owner advances it; cancelled timers never fire (DEVELOPERS.md principle 2)."""
    clock = SimulatedClock()
    seen: list[int] = []
    handle = clock.call_later(0.1, seen.append, 1)
    clock.call_later(0.2, seen.append, 2)
    handle.cancel()
    assert clock.now() == 0.0
    clock.advance(1.0)
    assert seen == [2]


def test_periodic_timer_does_not_drift() -> None:
    """A 1 ms periodic timer fires exactly 1000 times in 1 s with no accumulated rounding (issue 2 §2: cycles on
    the clock)."""
    clock = SimulatedClock()
    times: list[float] = []
    timer = clock.call_every(0.001, lambda: times.append(clock.now()))
    clock.advance(1.0005)
    timer.cancel()
    clock.advance(1.0)
    assert len(times) == 1000
    assert times[-1] == pytest.approx(1.0, abs=1e-9)


def test_run_while_stops_when_condition_clears() -> None:
    """run_while runs events only as long as the condition holds (how the in-process adapter settles a bus)."""
    clock = SimulatedClock()
    state = {"n": 0}

    def tick() -> None:
        state["n"] += 1
        clock.call_later(0.01, tick)

    clock.call_soon(tick)
    clock.run_while(lambda: state["n"] < 5)
    assert state["n"] == 5
    assert clock.now() == pytest.approx(0.04)


def test_negative_time_is_local_misuse() -> None:
    """Asking the clock to go backwards is local misuse: LocalError (DEVELOPERS.md principle 4)."""
    clock = SimulatedClock()
    with pytest.raises(LocalError):
        clock.advance(-1)
    with pytest.raises(LocalError):
        clock.call_later(-0.1, print)


def test_real_time_pass_does_bounded_work() -> None:
    """Issue 15 '`timing = false` hangs the rig': a callback that keeps scheduling work for 'now' must not keep
    RealTimeClock.run_due from returning, so the runtime's loop serves its sockets and signals between passes;
    what is left runs in the next pass, in order."""
    clock = RealTimeClock()
    clock.pass_limit = 10
    runs: list[str] = []

    def again() -> None:
        runs.append("again")
        if len(runs) < 1000:   # bounded, so a regression fails instead of hanging
            clock.call_soon(again)

    clock.call_soon(again)
    clock.call_soon(runs.append, "other")
    assert clock.run_due() == 10 and runs[:3] == ["again", "other", "again"] and len(runs) == 10
    assert clock.next_deadline() is not None       # the rest waits for the next pass
    assert clock.run_due() == 10 and len(runs) == 20


def test_wait_lets_time_pass_through_the_clock() -> None:
    """A blocking caller (the in-process EtherCAT master polling a mailbox, issue 9) waits through the clock: a
    simulated clock runs the events of that span; a real-time clock that no loop runs runs its due events."""
    sim = SimulatedClock()
    seen: list[str] = []
    sim.call_later(0.0004, seen.append, "slave answered")
    sim.wait(0.0005)
    assert seen == ["slave answered"] and sim.now() == pytest.approx(0.0005)
    real = RealTimeClock()
    real.call_soon(seen.append, "due")
    real.wait(0.0)
    assert seen == ["slave answered", "due"]
    with pytest.raises(LocalError):
        real.wait(-1.0)


def test_ensure_lock_installs_one_reentrant_lock_every_sharer_gets() -> None:
    """Issue 22 'one clock-lock method on Clock instead of four installs': the first sharer installs a
    re-entrant lock, every later one (the adapter, the rig runtime, the wire thread, a host library)
    gets the same, so all of them serialise on one lock."""
    clock = SimulatedClock()
    first = clock.ensure_lock()
    assert clock.lock is first
    assert clock.ensure_lock() is first
    with first, clock.lock:    # re-entrant: a callback may call code that takes it again
        pass


def test_a_thread_waiting_for_the_lock_goes_before_the_rest_of_the_pass() -> None:
    """docs/architecture.md 'Threads': the EtherCAT wire thread takes ``clock.lock`` for every frame, and a
    line answers a frame in microseconds; a pass of the rig loop's due events (up to ``pass_limit``) must not
    make it wait. A thread that raises ``clock.waiting`` while it blocks on the lock ends the running pass
    after the event in progress (``run_due`` returns 1 of 3 due events), and :meth:`RealTimeClock.hand_over`
    lets it take the lock before the loop's next pass runs the other two."""
    clock = RealTimeClock()
    lock = clock.ensure_lock()
    order: list[str] = []
    blocked = threading.Event()

    def waiter() -> None:
        clock.waiting += 1
        blocked.set()
        with lock:
            order.append("waiter")
        clock.waiting -= 1

    thread = threading.Thread(target=waiter)

    def first() -> None:
        order.append("event")
        thread.start()
        assert blocked.wait(30)     # it waits for the lock this pass holds

    with lock:
        clock.call_at(clock.now() - 0.001, first)
        for _ in range(2):
            clock.call_at(clock.now() - 0.001, order.append, "event")
    assert clock.run_due() == 1
    clock.hand_over(patience=30.0)   # run_due stepped aside for HAND_OVER_S; a loaded machine may need longer
    thread.join(30)
    assert clock.waiting == 0
    assert clock.run_due() == 2
    assert order == ["event", "waiter", "event", "event"]



def test_input_an_urgent_probe_reports_ends_the_pass_and_is_handed_over() -> None:
    """docs/architecture.md 'Threads': a frame in the EtherCAT wire's socket must not wait for a pass of the loop's
    events, nor for the interpreter's switch interval while the loop holds the interpreter lock. A probe in
    ``clock.urgent`` (the wire's ``frame_waiting``) that reports input ends the pass after the running event
    (``run_due`` returns 1 of 3 due events); :meth:`Clock.hand_over` steps aside while it reports input and returns
    once the input is taken; with no probe reporting, the rest of the events run in one pass."""
    clock = RealTimeClock()
    clock.ensure_lock()
    frame = threading.Event()
    frame.set()
    clock.urgent.append(frame.is_set)
    for _ in range(3):
        clock.call_at(clock.now() - 0.001, lambda: None)
    assert clock.run_due() == 1
    taker = threading.Timer(0.01, frame.clear)      # the wire thread takes its frame
    taker.start()
    clock.hand_over(patience=30.0)
    assert not frame.is_set()       # hand_over returned because the input was taken, not by its patience
    taker.join(30)
    assert clock.run_due() == 2
