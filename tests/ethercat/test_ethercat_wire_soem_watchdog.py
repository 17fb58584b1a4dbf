"""SOEM over a veth pair reads a low working counter after a master pause longer than the SM watchdog.

ET1100 data sheet section II 0x0807 bit 0 ("SyncManager deactivated ... locks access to Memory area");
SOES ``ESC_stopoutput`` / Beckhoff's slave stack deactivate SM2 when OP is left by a local request (SM
watchdog: SAFEOP + error, AL status code 0x001B), so the LRW's output writes stop counting (ETG.1000.4
working counter) and SOEM's simple_test recovery, which acts on a low working counter, sees the fall;
after the acknowledge and SAFEOP -> OP the counter is full again.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from gatewaylab.common.clock import RealTimeClock
from gatewaylab.devices.ethercat_io.device import create_io_slave
from gatewaylab.ethercat.errors import AlStatusCode
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.wire import WireTransport

pytestmark = [pytest.mark.net, pytest.mark.slow]
DRIVER = Path(__file__).with_name("ethercat_soem_watchdog_driver.py")
NO_FRAME = -1  # pysoem: no reply within the receive timeout (a lost frame, not a wrong counter)


def _replies(wkcs: list[int]) -> list[int]:
    got = [w for w in wkcs if w != NO_FRAME]
    assert got, "every frame was lost"
    return got


@pytest.fixture(scope="module")
def paused_run(veth_ns: Any) -> dict[str, Any]:
    clock = RealTimeClock()
    segment = Segment([create_io_slave(clock, f"GL-IO #{i}", serial=1000 + i, revision=i + 1) for i in range(3)])
    wire = WireTransport(segment, veth_ns.emulator_iface, clock, drive_clock=True)
    wire.start()
    try:
        proc = subprocess.run(["ip", "netns", "exec", veth_ns.namespace, sys.executable, str(DRIVER),
                               veth_ns.master_iface], capture_output=True, text=True, timeout=120, check=False)
    finally:
        wire.stop()
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert not wire.errors
    result: dict[str, Any] = json.loads(proc.stdout.strip().splitlines()[-1])
    return result


def test_soem_reads_a_low_working_counter_after_a_pause(paused_run: dict[str, Any]) -> None:
    """All three slaves are SAFEOP + error with 0x001B after the pause; every LRW then counts the
    inputs only (3 of SOEM's expected 9: 2 per output slave + 1 per input slave)."""
    r = paused_run
    assert (r["count"], r["safeop"], r["op"], r["expected_wkc"]) == (3, 4, 8, 9)
    assert r["after_pause"] == [[0x14, AlStatusCode.SM_WATCHDOG]] * 3
    assert set(_replies(r["wkc_after_pause"])) == {3}


def test_soem_recovery_brings_the_working_counter_back(paused_run: dict[str, Any]) -> None:
    """The acknowledge alone keeps SM2 deactivated (SAFEOP: inputs only); SAFEOP -> OP activates it again
    and the working counter is full."""
    r = paused_run
    assert r["acked"] == 4 and set(_replies(r["wkc_safeop_acked"])) == {3}
    assert r["recovered"] == 8 and set(_replies(r["wkc_recovered"])) == {9}
