"""The KickCAT drivers' one rerun loop (tests/ethercat/kickcat_kit.py ``run_step``): a step is run again only
after a lost frame (KickCAT's texts for a datagram not back within its link timeout, lib/master/src/Bus.cc and
CoE.cc v2.5) and only when the emulator held no frame past ``max_residence_ms`` meanwhile (docs/decisions.md:
"a rerun after the emulator's own late drop fails the test"). No KickCAT and no network needed."""

from __future__ import annotations

from collections.abc import Callable

import pytest
from kickcat_kit import EMULATOR_LATE, WIRE_COUNTERS_ENV, WireCounters, run_step
from wire_kit import check_reruns, serve_wire_counters


class Scripted(WireCounters):
    """Wire counters that grow as the test says: one reading per call, from a list."""

    def __init__(self, readings: list[dict[str, int]]) -> None:
        super().__init__("")
        self.readings = readings

    def read(self) -> dict[str, int] | None:
        return self.readings.pop(0)


def failing(*texts: str, result: str = "done") -> tuple[Callable[[], str], list[int]]:
    """A step that raises RuntimeError(text) for each of ``texts`` in turn, then returns ``result``."""
    calls = [0]

    def step() -> str:
        calls[0] += 1
        if calls[0] <= len(texts):
            raise RuntimeError(texts[calls[0] - 1])
        return result

    return step, calls


def wire(dropped: int, held: int) -> dict[str, int]:
    return {"frames_dropped_late": dropped, "frames_late_on_arrival": held}


def test_a_lost_frame_runs_the_step_again_and_is_recorded() -> None:
    """KickCAT's scan gives up on a register read later than the link timeout (Bus.cc:795 ``Timeout``) and its
    mailbox check on a LOST datagram (CoE.cc:13): run again, each failure in the record with its text."""
    step, calls = failing("/project/lib/master/src/Bus.cc:795: Timeout",
                          "/project/lib/master/src/CoE.cc:13: error while checking mailboxes")
    result, record = run_step("init", step, counters=WireCounters(""))
    assert (result, calls[0]) == ("done", 3)
    assert record == ["init: /project/lib/master/src/Bus.cc:795: Timeout",
                      "init: /project/lib/master/src/CoE.cc:13: error while checking mailboxes"]


def test_an_error_that_is_no_lost_frame_is_not_run_again() -> None:
    """``Invalid SyncManager configuration`` (Bus.cc:455) is the slave's answer, not a lost frame: raised at once."""
    step, calls = failing("/project/lib/master/src/Bus.cc:455: Invalid SyncManager configuration")
    with pytest.raises(RuntimeError, match="Invalid SyncManager"):
        run_step("create_mapping", step, counters=WireCounters(""))
    assert calls[0] == 1


def test_a_step_that_keeps_losing_frames_fails_with_its_record() -> None:
    step, calls = failing(*["/project/lib/master/src/Bus.cc:795: Timeout"] * 5)
    with pytest.raises(RuntimeError, match="KickCAT init failed 5 times") as caught:
        run_step("init", step, counters=WireCounters(""))
    assert calls[0] == 5 and str(caught.value).count("Bus.cc:795: Timeout") == 5


def test_a_frame_the_machine_held_allows_the_rerun() -> None:
    """The wire's late drop that reached an idle wire thread already late (``frames_late_on_arrival``) is the
    machine's: the step runs again and the record says so."""
    step, calls = failing("Bus.cc:789: Invalid working counter")
    counters = Scripted([wire(3, 3), wire(4, 4), wire(4, 4)])
    result, record = run_step("init", step, counters=counters)
    assert (result, calls[0]) == ("done", 2)
    assert record == ["init: Bus.cc:789: Invalid working counter [machine held 1, emulator late 0]"]


def test_a_frame_the_emulator_held_ends_the_step() -> None:
    """A late drop of the emulator's own (``frames_dropped_late`` grew more than ``frames_late_on_arrival``)
    during the failed attempt: not run again, the error names it."""
    step, calls = failing("Bus.cc:789: Invalid working counter")
    counters = Scripted([wire(3, 3), wire(5, 4)])
    with pytest.raises(RuntimeError, match=EMULATOR_LATE) as caught:
        run_step("init", step, counters=counters)
    assert calls[0] == 1 and "emulator late 1" in str(caught.value)


def test_the_driver_reads_the_counters_the_test_serves() -> None:
    """``serve_wire_counters`` answers the control request ``ethercat-states`` as a rig does (``wire``)."""
    now = wire(7, 2)
    with serve_wire_counters(lambda: now) as env:
        assert WireCounters(env[WIRE_COUNTERS_ENV]).read() == now


def test_a_late_drop_counted_after_the_failure_ends_the_step_that_then_succeeded() -> None:
    """The wire counts its own late drop only when its thread gets to the frame, which may be after the
    driver's reading: the attempt that then succeeds lost no frame, so the drop was the failed attempt's."""
    step, calls = failing("CoE.cc:13: error while checking mailboxes")
    counters = Scripted([wire(0, 0), wire(1, 1), wire(2, 1)])
    with pytest.raises(RuntimeError, match=EMULATOR_LATE):
        run_step("read 1C13:0", step, counters=counters)
    assert calls[0] == 2


def test_check_reruns_leaves_the_judged_reruns_to_the_driver() -> None:
    """A rerun the driver cleared with the counters of its own attempt passes whatever late drops the whole
    run had (the cyclic phases' lost cycles); a rerun without them fails when the emulator dropped a frame."""
    whole = wire(3, 1)
    check_reruns(["read 1000:0: CoE.cc:13: error while checking mailboxes [machine held 1, emulator late 0]"], whole)
    with pytest.raises(AssertionError, match="without the wire's counters"):
        check_reruns(["init: Bus.cc:795: Timeout"], whole)
