"""The ECAN-Lite host programs on a real EtherCAT interface (issue 12: the same host code on pysoem
and in process): ``gatewaylab ecan sdo-probe -i`` and ``cia402 -i`` (one axis, and ten CSP axes on
four channels) run inside a test-made network namespace through SOEM over a veth pair, against the
emulated ECAN-Lite with IDX-like drives (the command line is the driver script: the master runs in
its own process)."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from gatewaylab.bus import VirtualBus
from gatewaylab.common.clock import RealTimeClock
from gatewaylab.devices.canopen_drive.device import Drive
from gatewaylab.devices.ecanlite.device import EcanLiteDevice
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.wire import WireTransport

pytestmark = [pytest.mark.net, pytest.mark.slow]


@pytest.fixture
def line(veth_ns: Any, tmp_path: Path) -> Iterator[Any]:
    """The emulated line: ECAN-Lite with drive node 1 on CAN0 (1 Mbit/s), wire thread running."""
    clock = RealTimeClock()
    bus = VirtualBus(clock, "can0", 1_000_000)
    drive = Drive(clock, bus, node_id=1, serial=0x1001, name="axis1", store_path=None)
    device = EcanLiteDevice(clock, [bus.attach("ecan.mcan0")], flash_path=tmp_path / "ecan.flash")
    wire = WireTransport(Segment([device.slave]), veth_ns.emulator_iface, clock, drive_clock=True)
    clock.call_soon(drive.start)
    wire.start()
    try:
        yield veth_ns
    finally:
        wire.stop()
    assert not wire.errors


#: The 10-axis demo of 15.6: drives (node ids) on CAN0..CAN3.
TEN_AXES = ((1, 2, 3), (4, 5, 6), (7, 8), (9, 10))


@pytest.fixture
def ten_axes_line(veth_ns: Any, tmp_path: Path) -> Iterator[Any]:
    """ECAN-Lite with ten drives on four 1 Mbit/s buses (TEN_AXES), wire thread running."""
    clock = RealTimeClock()
    buses = [VirtualBus(clock, f"can{k}", 1_000_000) for k in range(len(TEN_AXES))]
    drives = [Drive(clock, bus, node_id=n, serial=0x1000 + n, name=f"axis{n}", store_path=None)
              for bus, nodes in zip(buses, TEN_AXES, strict=True) for n in nodes]
    device = EcanLiteDevice(clock, [b.attach(f"ecan.mcan{k}") for k, b in enumerate(buses)],
                            flash_path=tmp_path / "ecan.flash")
    wire = WireTransport(Segment([device.slave]), veth_ns.emulator_iface, clock, drive_clock=True)
    for d in drives:
        clock.call_soon(d.start)
    wire.start()
    try:
        yield veth_ns
    finally:
        wire.stop()
    assert not wire.errors


def _ecan(veth: Any, *args: str) -> subprocess.CompletedProcess[str]:
    """Run the command in the namespace; once more when SOEM lost the line at start-up (a fresh veth
    link on a loaded 2-core machine: register reads unanswered, shared notes soem-interop)."""
    cmd = ["ip", "netns", "exec", veth.namespace, sys.executable, "-m", "gatewaylab", "ecan", *args,
           "-i", veth.master_iface]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300, check=False)
    if r.returncode == 1 and ("does not answer" in r.stderr or "no EtherCAT slaves" in r.stderr):
        print("retried after:", r.stderr.strip())
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=300, check=False)
    return r


def test_sdo_probe_and_cia402_over_soem(line: Any) -> None:
    """15.4 SDO probe: 0x1000:00 of node 1 = 0x00020192 through SOEM; 15.6 demo with the first
    bring-up settings (5 ms cycle, few cycles): the axis is enabled and reaches start + 40 * 25,
    no PDO parse error. Working-counter errors (late frames on a loaded machine) are printed."""
    r = _ecan(line, "sdo-probe", "--node", "1", "--index", "0x1000", "--sub", "0", "--bitrate", "1000000",
              "--cycle-us", "5000", "--timeout", "3", "--json")
    assert r.returncode == 0, r.stderr[-3000:]
    report = json.loads(r.stdout)
    assert report["value"] == 0x00020192 and report["errors"]["parse_errors"] == 0
    r = _ecan(line, "cia402", "--axes", "0:0:1", "--cycle-us", "5000", "--cycles", "40", "--step", "25",
              "--settle-s", "2", "--sdo-timeout", "3", "--json")
    report = json.loads(r.stdout) if r.stdout.strip() else {}
    assert report, r.stderr[-3000:]
    print("WKC errors over SOEM:", report["errors"]["wkc_errors"], "master_period:", report["master_period"])
    (axis,) = report["axes"]
    assert axis["enabled"] and axis["target"] - axis["start"] == 1000 and axis["reached"]
    assert report["errors"]["parse_errors"] == 0


def test_ten_csp_axes_over_soem(ten_axes_line: Any) -> None:
    """15.6 ``igh_cia402_10axis_demo`` through SOEM: ten drives on CAN0..CAN3 of one ECAN-Lite
    (N = 3), NMT, CSP mapping by SDO through the gateway, enable, 120 cycles of CSP motion by 25
    inc: every axis is enabled and reaches start + 3000 (less a step per cycle that followed an
    incomplete domain, 15.5.2 step 8), no PDO parse error (15.5.4). A generous
    2 ms cycle for a loaded machine; working-counter errors and late cycles are printed."""
    axes = ",".join(f"0:{ch}:{n}" for ch, nodes in enumerate(TEN_AXES) for n in nodes)
    r = _ecan(ten_axes_line, "cia402", "--axes", axes, "--pdo-n", "3", "--cycle-us", "2000", "--cycles", "120",
              "--step", "25", "--settle-s", "3", "--sdo-timeout", "3", "--json")
    report = json.loads(r.stdout) if r.stdout.strip() else {}
    assert report, r.stderr[-3000:]
    print("WKC errors over SOEM:", report["errors"]["wkc_errors"], "master_period:", report["master_period"])
    assert len(report["axes"]) == 10
    held = report["errors"]["wkc_errors"]     # 15.5.2 step 8: a cycle after an incomplete domain holds targets
    for axis in report["axes"]:
        moved = axis["target"] - axis["start"]
        assert axis["enabled"] and axis["reached"], axis
        assert moved % 25 == 0 and 3000 - 25 * held <= moved <= 3000, axis
    assert report["errors"]["parse_errors"] == 0
