"""What every KickCAT driver of the suite shares: the process set up as KickCAT's README tells users to, and
the one place where a step that failed on a lost frame runs again (``run_step``).

A driver runs inside the test's network namespace; the emulator's wire counters reach it through the Unix
socket named by ``WIRE_COUNTERS_ENV`` (a rig's control socket, or tests/wire_kit.py ``serve_wire_counters``
for a wire in the test process: both answer the control request ``ethercat-states``). Without it the
driver reruns blind and the test's ``check_reruns`` judges the whole run afterwards.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import sys
from collections.abc import Callable
from typing import TypeVar

from gatewaylab.common.ask import ask

__all__ = [
    "ATTEMPTS",
    "EMULATOR_LATE",
    "JUDGED",
    "LOST_FRAME",
    "MAILBOX_ATTEMPTS",
    "WIRE_COUNTERS_ENV",
    "WireCounters",
    "run_as_kickcat_readme_says",
    "run_step",
]

T = TypeVar("T")

#: a step that failed on a lost frame runs at most this many times in all
ATTEMPTS = 5
#: An SDO read or write (a mailbox exchange) is never run again: KickCAT 2.5 repeating one after "error while
#: checking mailboxes" crashed (SIGSEGV) or failed with "error while process mailboxes" in the measured runs
#: (docs/decisions.md, helper h36b), and a rerun would hide a lost mailbox frame from the test.
MAILBOX_ATTEMPTS = 1
#: The environment variable naming the Unix socket that answers ``{"fault": "ethercat-states"}`` with the
#: emulator's wire counters under ``wire``.
WIRE_COUNTERS_ENV = "GATEWAYLAB_TEST_WIRE_COUNTERS"
#: What KickCAT 2.5 raises (``RuntimeError``, by its text) when a frame did not come back within the link
#: timeout: the datagram callbacks of Bus.cc / CoE.cc get ``DatagramState::LOST`` and throw their step's
#: message (``Invalid working counter``, ``Error while fetching eeprom data``, ``Error fetching DL status``,
#: ``error while checking mailboxes``), its wait loops ``Timeout`` / ``Error while reading SDO - Timeout``,
#: the Python ``process_data`` ``LOST``. A scan cannot tell a lost frame from a wrong working counter (both
#: ``Invalid working counter``): the wire's counters between the attempts do. Anything else (an SDO abort:
#: ``ErrorCoE``, an AL error: ``ErrorAL``, ``Invalid SyncManager configuration``, ``No slave detected``) is no
#: lost frame and ends the step at once.
LOST_FRAME = ("Timeout", "Invalid working counter", "Error while fetching", "Error fetching", "error while checking",
              "error while process", "LOST", "WriteThenRead")
#: the text of the error that ends a step whose failed attempt the emulator caused (no rerun then)
EMULATOR_LATE = "the emulator held"
#: the end of a record entry whose failed attempt the wire's counters cleared (the machine's, not the emulator's)
JUDGED = re.compile(r"\[machine held \d+, emulator late 0\]$")


def run_as_kickcat_readme_says() -> None:
    """SCHED_FIFO priority 3, as KickCAT's README (Performance Optimization: ``chrt -f 80``) runs a master:
    its socket read sleeps 20 us between polls and gives up once a sleep overran the deadline without a last
    look (Socket::read), so an ordinary process waiting for a CPU loses replies that came in time. Below the
    emulator's wire thread (10) and loop (5): the line is hardware. Nothing without the privilege."""
    with contextlib.suppress(OSError):
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(3))


class WireCounters:
    """The emulator's wire counters (``frames_dropped_late``, ``frames_late_on_arrival``, ...) read through
    the socket named by ``WIRE_COUNTERS_ENV``; ``None`` from ``read`` when there is none."""

    def __init__(self, address: str | None = None) -> None:
        self.address = address if address is not None else os.environ.get(WIRE_COUNTERS_ENV)

    def read(self) -> dict[str, int] | None:
        """The counters now (the control request ``ethercat-states``, ``wire``); None when the socket does not
        answer (a rig the test ended meanwhile): the attempt is then judged by the test alone."""
        if not self.address:
            return None
        try:
            answer = json.loads(ask(self.address, {"fault": "ethercat-states"}, 10.0) or b"{}")
        except OSError as exc:
            print(f"the wire's counters at {self.address} did not answer: {exc}", file=sys.stderr, flush=True)
            return None
        wire: dict[str, int] = answer.get("wire") or {}
        return wire


def _window(before: dict[str, int] | None, after: dict[str, int] | None) -> tuple[int, int] | None:
    """(frames the emulator held late itself, frames the machine held) between two readings."""
    if before is None or after is None:
        return None

    def grew(key: str) -> int:
        return after.get(key, 0) - before.get(key, 0)

    held = grew("frames_late_on_arrival")
    return grew("frames_dropped_late") - held, held


def run_step(name: str, step: Callable[[], T], lost: tuple[str, ...] = LOST_FRAME, attempts: int = ATTEMPTS,
             counters: WireCounters | None = None) -> tuple[T, list[str]]:
    """``step()``'s result and a record of each failed attempt (``"NAME: KickCAT's text [what the wire
    counted]"``, also printed on stderr), the step run again after a ``RuntimeError`` whose text holds one of
    ``lost``, at most ``attempts`` times in all.

    With the wire's counters (``WIRE_COUNTERS_ENV``) a failed attempt runs again only when the emulator held
    no frame past ``max_residence_ms`` during it (``frames_dropped_late`` grew no more than
    ``frames_late_on_arrival``, the frames the machine handed it already late); else the step ends at once
    with ``EMULATOR_LATE`` in its error: a rerun would hide the emulator being late. A late drop of its own
    the wire counts only after that reading (its thread still busy) shows in the attempt that then succeeds:
    no frame of a successful attempt was lost, so it was the failed attempt's, and ends the step the same way
    (one more reading after a success that followed failures). Such a judged failure ends in ``JUDGED``; the
    test's ``check_reruns`` over the whole run checks only the reruns that were not. The error after the last
    attempt reads ``KickCAT NAME failed`` with the record."""
    if attempts < 1:
        raise ValueError(f"attempts must be at least 1, not {attempts}")
    counters = counters if counters is not None else WireCounters()
    record: list[str] = []
    before = counters.read()        # one reading per attempt: a failure's is the next attempt's start
    for attempt in range(attempts):
        try:
            result = step()
        except RuntimeError as exc:
            text = str(exc)
            if not any(word in text for word in lost):
                raise
            after = counters.read()
            window, before = _window(before, after), after
            if window is None:
                note = f"{name}: {text}"
            else:
                own, held = window
                note = f"{name}: {text} [machine held {held}, emulator late {own}]"
            record.append(note)
            print(f"KickCAT step failed on a lost frame: {note}", file=sys.stderr, flush=True)
            if window is not None and window[0] > 0:
                raise RuntimeError(f"KickCAT {name}: {EMULATOR_LATE} {window[0]} frame(s) past max_residence_ms; "
                                   f"not run again: {record}") from exc
            if attempt == attempts - 1:
                raise RuntimeError(f"KickCAT {name} failed {attempts} times: {record}") from exc
            continue
        window = _window(before, counters.read()) if record else None
        if window is not None and window[0] > 0:
            raise RuntimeError(f"KickCAT {name}: {EMULATOR_LATE} {window[0]} frame(s) past max_residence_ms, "
                               f"counted after the failed attempt; it was run again: {record}")
        return result, record
    raise AssertionError("the last attempt returns or raises")
