"""RealTimeClock.begin_wait / end_wait: the loop that runs a real-time clock is woken when an event is
scheduled (by another thread, holding ``clock.lock``) before the time it would wake up by itself
(docs/architecture.md 'Threads'; issue 21 defect 3: the esd's first Tx batch after OP waited 240 ms for
the rig loop's timeout)."""

from __future__ import annotations

from gatewaylab.common.clock import RealTimeClock, SimulatedClock


def _clock() -> tuple[RealTimeClock, list[int]]:
    clock = RealTimeClock()
    woken: list[int] = []
    clock.wakeup = lambda: woken.append(1)
    return clock, woken


def test_an_event_before_the_loops_deadline_wakes_it_once() -> None:
    """The loop sleeps until its next event; an earlier one wakes it, once per wait (the first
    wake-up is enough: the loop recomputes its deadline)."""
    clock, woken = _clock()
    clock.call_later(10.0, lambda: None)
    deadline = clock.begin_wait()
    assert deadline is not None and deadline > clock.now() + 9
    clock.call_later(1.0, lambda: None)
    assert woken == [1]
    clock.call_later(0.5, lambda: None)
    assert woken == [1]
    clock.end_wait()


def test_an_event_after_the_deadline_or_while_awake_wakes_nobody() -> None:
    """Events the loop will reach anyway (after its deadline), and events scheduled while it runs
    (between end_wait and the next begin_wait: its own callbacks), cost no wake-up."""
    clock, woken = _clock()
    clock.call_later(1.0, lambda: None)
    clock.begin_wait()
    clock.call_later(5.0, lambda: None)
    assert woken == []
    clock.end_wait()
    clock.call_soon(lambda: None)
    assert woken == []


def test_an_empty_queue_wakes_the_loop_for_any_event() -> None:
    """Nothing scheduled: the loop waits for I/O only, so the first event wakes it (a frame a wire
    thread hands to the bus of an idle rig)."""
    clock, woken = _clock()
    assert clock.begin_wait() is None
    clock.call_later(100.0, lambda: None)
    assert woken == [1]


def test_a_rescheduled_handle_wakes_the_loop_too() -> None:
    """The bus queues its arbitration by re-using a handle (Clock.reschedule), not call_at."""
    clock, woken = _clock()
    ran: list[int] = []
    handle = clock.call_soon(ran.append, 1)
    clock.run_due()
    assert ran == [1]
    clock.begin_wait()
    clock.reschedule(handle, clock.now())
    assert woken == [1]
    clock.end_wait()
    clock.run_due()
    assert ran == [1, 1]


def test_a_simulated_clock_never_calls_wakeup() -> None:
    """A simulated clock has no loop that sleeps: scheduling never wakes anything."""
    clock = SimulatedClock()
    woken: list[int] = []
    clock.wakeup = lambda: woken.append(1)
    clock.call_later(1.0, lambda: None)
    clock.advance(2.0)
    assert woken == []
