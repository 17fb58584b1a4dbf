"""python-can over the gateways on a real interface: the same canopen application as
test_canhost_canopen.py, with the master being SOEM (pysoem) on one end of a veth pair inside a
network namespace and the gateways served by the emulator's wire transport on the other end."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from gatewaylab.bus import VirtualBus
from gatewaylab.common.clock import RealTimeClock
from gatewaylab.devices.canopen_drive.device import Drive
from gatewaylab.devices.ecanlite.device import EcanLiteDevice
from gatewaylab.devices.esd_can_ethercat.device import create_esd_gateway
from gatewaylab.ethercat.esc import AlState

if TYPE_CHECKING:      # 'conftest' names another package's conftest when several are collected
    from conftest import CanhostVeth
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.wire import WireTransport

DRIVER = Path(__file__).with_name("canhost_driver.py")


@pytest.mark.net
@pytest.mark.slow
@pytest.mark.parametrize("interface", ["esd_can_ethercat", "ecanlite"])
def test_canopen_reads_and_moves_the_drive_over_soem(canhost_veth: CanhostVeth, interface: str) -> None:
    """Issue 12: canopen.Network().connect(interface=..., channel=IFNAME) with SOEM as master reads
    0x1008 / 0x1018:04 of the drive behind the gateway and moves it in profile position mode
    (statusword bit 10 'target reached'); shutdown leaves the gateway in PREOP."""
    clock = RealTimeClock()
    bus = VirtualBus(clock, "can0", bitrate=500_000)
    esd = create_esd_gateway(clock, bus, "esd1", serial=0x10)
    ecan = EcanLiteDevice(clock, [bus.attach("ecan.mcan0")])
    drive = Drive(clock, bus, 2, 0x1002)
    drive.start()
    wire = WireTransport(Segment([esd.slave, ecan.slave]), canhost_veth.emulator_iface, clock, drive_clock=True)
    wire.start()
    try:
        proc = subprocess.run(["ip", "netns", "exec", canhost_veth.namespace, sys.executable, str(DRIVER),
                               interface, canhost_veth.master_iface], capture_output=True, text=True,
                              timeout=300, check=False)
    finally:
        wire.stop()
        esd.stop()
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert result["name"].startswith("IDX") and result["serial"] == 0x1002
    assert abs(result["position"] - 20_000) <= 10 and result["statusword"] & 0x400
    assert esd.slave.esc.al_state == AlState.PREOP and ecan.slave.esc.al_state == AlState.PREOP
