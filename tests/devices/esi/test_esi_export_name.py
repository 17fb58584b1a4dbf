"""``gatewaylab esi KIND --name NAME``: the ESI carries NAME everywhere a slave of that kind named NAME in a rig
does -- the SII device name and the device name object 0x1008 (CiA 301 / ETG.1000.6 "Manufacturer device
name"), so ``kind = "esi"`` from it answers 0x1008 as the original does. Found by SOEM's ``slaveinfo -sdo``: the
ESI copy of an ``ethercat_io`` named ``io-orig`` answered 0x1008 with the product name (another length too)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.esi.device import esi_slave
from gatewaylab.devices.esi.reader import read_esi_file
from gatewaylab.devices.ethercat_drive.device import EthercatDrive
from gatewaylab.devices.ethercat_io.device import create_io_slave
from gatewaylab.ethercat.slave import Slave


def _io(name: str) -> Slave:
    return create_io_slave(SimulatedClock(), name=name)


def _drive(name: str) -> Slave:
    drive = EthercatDrive(SimulatedClock(), name=name)
    drive.stop()
    return drive.slave


@pytest.mark.parametrize(("kind", "original"), [("ethercat_io", _io), ("ethercat_drive", _drive)])
def test_the_name_reaches_the_device_name_object(tmp_path: Path, kind: str, original: object) -> None:
    esi = tmp_path / f"{kind}.xml"
    subprocess.run([sys.executable, "-m", "gatewaylab", "esi", kind, "--name", "cell-3-axis", "-o", str(esi)],
                   check=True, capture_output=True, timeout=120)
    assert callable(original)
    orig: Slave = original("cell-3-axis")
    copy = esi_slave(SimulatedClock(), read_esi_file(esi), "whatever")
    assert orig.od.get(0x1008, 0) == "cell-3-axis"
    assert copy.od.get(0x1008, 0) == orig.od.get(0x1008, 0)
    assert copy.od.get_bytes(0x1008, 0) == orig.od.get_bytes(0x1008, 0)
