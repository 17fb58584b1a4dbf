"""The esd host library (issue 12 'esd host library') through both backends: every scenario of
``esd_host_scenarios`` (its docstring quotes the manual / note section) runs against the in-process
master on a simulated clock and, as root, against SOEM (pysoem) in a network namespace over a veth
pair whose other end the emulator's wire thread serves. Emulator-side facts (what the bus carried)
are checked here after the run."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from esd_host_scenarios import SCENARIOS, echo_of, make_can_side, run_inprocess

from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.clock import RealTimeClock
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.wire import WireTransport

DRIVER = Path(__file__).with_name("esd_host_driver.py")
#: Errors of the EtherCAT line itself (not of a check): no answer, a late answer, a lost SM write.
TRANSPORT_FAILURE = re.compile(r"MasterTimeout|SOEM packet error|code 0x001[D6E]|B outputs / \d+ B inputs, the mapping")
Runner = Callable[[str], tuple[dict[str, Any], list[CanFrame]]]


@pytest.fixture(params=["inprocess", pytest.param("pysoem", marks=[pytest.mark.net, pytest.mark.slow])])
def run(request: pytest.FixtureRequest) -> Runner:
    if request.param == "inprocess":
        return run_inprocess
    veth = request.getfixturevalue("esd_veth")

    def run_once(name: str) -> tuple[subprocess.CompletedProcess[str], list[CanFrame], str]:
        clock = RealTimeClock()
        _bus, gw, heard = make_can_side(clock, SCENARIOS[name][1])
        wire = WireTransport(Segment([gw.slave]), veth.emulator_iface, clock, drive_clock=True)
        wire.start()
        try:
            proc = subprocess.run(["ip", "netns", "exec", veth.namespace, sys.executable, str(DRIVER),
                                   veth.master_iface, name], capture_output=True, text=True, timeout=300,
                                  check=False)
        finally:
            wire.stop()
            gw.stop()
        assert not wire.errors
        ctrl = gw.controller
        rate = ctrl.bitrate if ctrl else 0
        state = f" | gateway {gw.setting.mode} detected {gw.detected} at {rate} bit/s, {gw.stats}"
        return proc, heard, state

    def run_pysoem(name: str) -> tuple[dict[str, Any], list[CanFrame]]:
        proc, heard, state = run_once(name)
        if proc.returncode != 0 and TRANSPORT_FAILURE.search(proc.stderr.strip().splitlines()[-1]):
            # the line lost frames beyond the library's retries (a machine loaded far past its cores):
            # the scenario runs once more from scratch; a failed check (AssertionError) never does
            proc, heard, state = run_once(name)
        assert proc.returncode == 0, proc.stderr[-3000:] + state
        return json.loads(proc.stdout.strip().splitlines()[-1]), heard

    return run_pysoem


@pytest.mark.parametrize("name", ["errors", "queue_limits", "status_statistics", "filters", "bitrates"])
def test_scenario(run: Runner, name: str) -> None:
    """One scenario (its docstring quotes the manual section) through this backend."""
    run(name)


def test_batches_reach_the_bus_in_order(run: Runner) -> None:
    """5.1.5.3 'CAN Tx messages which are transmitted with every increase of the Tx counter': the
    bus carried the 40 frames of the three batches once each, in order."""
    result, heard = run("batches_11bit")
    assert [(f.can_id, f.rtr) for f in heard] == [(i, r) for i, _d, _e, r in result["sent"]]
    assert [echo_of(f).can_id for f in heard] == [i + 0x100 for i, *_ in result["sent"]]


def test_29bit_frames_reach_the_bus(run: Runner) -> None:
    """5.1.5.4 bit 63 '1 = 29-bit CAN identifier': extended frames go out extended, the standard one standard."""
    result, heard = run("29bit")
    assert [(f.can_id, f.extended, f.rtr) for f in heard] == [(i, e, r) for i, _d, e, r in result["sent"]]


def test_transaction_numbers_complete_in_order(run: Runner) -> None:
    """5.1.5.1 'Tx Transaction Number': the numbers the gateway reported rise to the last frame's."""
    result, heard = run("transaction_numbers")
    assert result["reported"][-1] == 20 and len(heard) == 36


def test_queue_resize_batches(run: Runner) -> None:
    """5.1.5.5: Tx queue 4 -> the ten frames went out in order; Rx queue 3 -> batches of at most 3."""
    result, heard = run("queue_resize")
    assert [f.can_id for f in heard] == [0x180 + i for i in range(10)]
    assert sum(result["batches"]) == 10 and max(result["batches"]) <= 3


def test_rx_overflow_is_counted_never_silent(run: Runner) -> None:
    """5.1.5.8 'Rx overflow', 5.1.4.2 'CANDriver FIFO overrun': lost + received = the 12 echoes."""
    result, heard = run("rx_overflow")
    assert len(heard) == 12 and result["lost"] + result["received"] == 12
