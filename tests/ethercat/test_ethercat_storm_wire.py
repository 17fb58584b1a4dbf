"""A storm of random EtherCAT frames over the veth pair, then SOEM (pysoem) re-initialises the segment
(issue 15: 'A malformed EtherCAT frame kills the segment')."""

from __future__ import annotations

import json
import logging
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from wire_kit import lost_allowed

from gatewaylab.common.clock import RealTimeClock
from gatewaylab.devices.ethercat_io.device import create_io_slave
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.wire import WireTransport

pytestmark = [pytest.mark.net, pytest.mark.slow]
STORM_DRIVER = Path(__file__).with_name("ethercat_storm_driver.py")
STORM_FRAMES = 3000
CYCLES = 1000


def _segment(clock: RealTimeClock) -> Segment:
    return Segment([create_io_slave(clock, f"GL-IO #{i}", serial=1000 + i, revision=i + 1) for i in range(3)])


def test_soem_reaches_op_after_a_storm(veth_ns: Any) -> None:
    """issue 15: after thousands of random frames (random bytes; 1-4 datagrams of random command,
    address and length, some lengths lying) the frame loop is alive, nothing raised, and SOEM's
    config_init finds the three slaves, reaches OP and runs 1,000 cycles with 0 wrong working counters."""
    clock = RealTimeClock()
    segment = _segment(clock)
    eeproms = [bytes(s.esc.eeprom) for s in segment.slaves]
    wire = WireTransport(segment, veth_ns.emulator_iface, clock, drive_clock=True, realtime=True)
    wire.start()
    try:
        proc = subprocess.run(["ip", "netns", "exec", veth_ns.namespace, sys.executable, str(STORM_DRIVER),
                               veth_ns.master_iface, "15", str(STORM_FRAMES), str(CYCLES)],
                              capture_output=True, text=True, timeout=180, check=False)
        alive = wire._thread is not None and wire._thread.is_alive()
    finally:
        wire.stop()
    assert proc.returncode == 0, proc.stderr[-2000:]
    r = json.loads(proc.stdout.strip().splitlines()[-1])
    print("bring-up attempts:", r["attempts"])
    assert alive
    assert wire.frame_errors == 0
    assert r["storm"]["sent"] == STORM_FRAMES
    assert segment.stats.bad_frames > 100 and wire.frames_in > 1000
    assert [bytes(s.esc.eeprom) for s in segment.slaves] == eeproms
    assert r["count"] == 3
    assert r["names"] == ["GL-IO #0", "GL-IO #1", "GL-IO #2"]
    assert r["op"] == 8, r["attempts"]
    print("lost frames (no reply within 2 ms):", r["lost"])
    assert r["bad_wkc"] == 0 and r["cycles"] == CYCLES and r["lost"] <= lost_allowed(CYCLES)


class _Flaky:
    """A segment whose first ``fail`` frames raise (a stand-in for any bug on the frame path)."""

    def __init__(self, segment: Segment, fail: int) -> None:
        self.segment = segment
        self.fail = fail
        self.line_faults = None         # what the wire reads of a segment besides process/after_frame

    def process(self, frame: bytearray, *, defer: bool = False) -> bool:
        if self.fail:
            self.fail -= 1
            raise RuntimeError("injected fault")
        return self.segment.process(frame, defer=defer)

    def after_frame(self) -> None:
        self.segment.after_frame()


def test_frame_loop_survives_exceptions_with_one_log_line_each(veth_ns: Any,
                                                               caplog: pytest.LogCaptureFixture) -> None:
    """issue 15: 'the frame loop survives any exception with one log line and a counter': the frames that
    raised are dropped (SOEM retries), the rest are served, and config_init finds the slaves."""
    clock = RealTimeClock()
    segment = _segment(clock)
    wire = WireTransport(segment, veth_ns.emulator_iface, clock, drive_clock=True, realtime=True)
    wire.segment = _Flaky(segment, 3)  # type: ignore[assignment]
    caplog.set_level(logging.ERROR, logger="gatewaylab.ethercat.wire")
    wire.start()
    try:
        proc = veth_ns.run_master("config")
    finally:
        wire.stop()
    assert proc.returncode == 0, proc.stderr[-2000:]
    r = json.loads(proc.stdout.strip().splitlines()[-1])
    assert r["count"] == 3
    assert wire.frame_errors == 3
    lines = [rec for rec in caplog.records if rec.name == "gatewaylab.ethercat.wire"]
    assert len(lines) == 3 and all("injected fault" in rec.getMessage() for rec in lines)
    assert all(rec.exc_info is None and "\n" not in rec.getMessage() for rec in lines)
