"""The one-line, rate-limited log of bad Modbus requests (issue 21 defect 6: 'One log line per bad
request, rate-limited'), sans-I/O: the limiter takes the time from its caller."""

from __future__ import annotations

import logging

import pytest

from gatewaylab.devices.modbus_gateway.server import BadRequestLog, LogLimiter, one_line


def test_the_limiter_admits_a_burst_per_window_and_counts_the_rest() -> None:
    """At most ``burst`` lines per window; the first line of the next window says how many were kept back."""
    limiter = LogLimiter(burst=3, window=10.0)
    assert [limiter.admit(0.1 * n) for n in range(5)] == [(True, 0)] * 3 + [(False, 0)] * 2
    assert limiter.held == 2 and limiter.dropped == 2
    assert limiter.admit(10.2) == (True, 2)
    assert limiter.held == 0 and limiter.dropped == 2
    assert limiter.admit(10.3) == (True, 0)


@pytest.mark.parametrize("text, line", [
    ("Invalid Modbus protocol id: 24016\n>>>>> recv: 0xef 0xfe 0x5d extra data: ", "Invalid Modbus protocol id: 24016"),
    ("Datastore unable to fulfill request: 4660; Traceback (most recent call last):\n  File \"x.py\", line 1",
     "Datastore unable to fulfill request: 4660"),
    ("Unable to decode frame Modbus Error: Unknown response 99",
     "Unable to decode frame Modbus Error: Unknown response 99"),
])
def test_one_line_drops_frame_dumps_and_tracebacks(text: str, line: str) -> None:
    """What pymodbus appends to an error (its last frames byte by byte, a traceback) never reaches the log."""
    assert one_line(text) == line


def test_the_handler_writes_one_line_per_record_within_the_limit(caplog: pytest.LogCaptureFixture) -> None:
    """Each pymodbus record is one line of ours; past the burst they are counted, then summed up in one line."""
    target = logging.getLogger("test.modbus.badrequests")
    handler = BadRequestLog(target, LogLimiter(burst=2, window=3600.0))
    source = logging.getLogger("test.modbus.pymodbus")
    source.propagate = False
    source.addHandler(handler)
    try:
        with caplog.at_level(logging.WARNING, logger="test.modbus.badrequests"):
            for n in range(4):
                source.error("Invalid Modbus protocol id: %d\n>>>>> recv: 0x0 0x1 0x2", n)
            source.error("Repeating....")
            handler.report_held()
    finally:
        source.removeHandler(handler)
    lines = [r.getMessage() for r in caplog.records]
    assert lines == ["Modbus TCP: bad request: Invalid Modbus protocol id: 0",
                     "Modbus TCP: bad request: Invalid Modbus protocol id: 1",
                     "Modbus TCP: 3 more bad requests not logged (at most 2 lines per 3600 s)"]
    assert handler.count == 5


def test_a_folded_repeat_names_what_repeated(caplog: pytest.LogCaptureFixture) -> None:
    """pymodbus writes 'Repeating....' for a message equal to the one before: the line says which."""
    target = logging.getLogger("test.modbus.repeats")
    handler = BadRequestLog(target, LogLimiter(burst=5, window=3600.0))
    with caplog.at_level(logging.WARNING, logger="test.modbus.repeats"):
        for text in ("Unable to decode frame Modbus Error: Unknown response 99", "Repeating...."):
            handler.handle(logging.makeLogRecord({"msg": text, "levelno": logging.WARNING}))
    assert [r.getMessage() for r in caplog.records][-1] == \
        "Modbus TCP: bad request: Unable to decode frame Modbus Error: Unknown response 99 (again)"
