"""examples/soem_cia402.py, the program a master-software engineer copies, run against two
emulated drives over a veth pair (bring-up, enable, CSP move, stop: ETG.6010 / CiA 402)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from ecdrive_testkit import DriveVeth, serve_raw

pytestmark = [pytest.mark.net, pytest.mark.slow]
EXAMPLE = Path(__file__).resolve().parents[3] / "examples" / "soem_cia402.py"


def test_example_brings_up_enables_moves_and_stops(drive_veth: DriveVeth) -> None:
    """CiA 402 over EtherCAT as the example does it: both drives to Operation Enabled, a 1 s CSP
    ramp of 40960 increments ends at its target on both, shutdown leaves the power stage off."""
    proc, drives = serve_raw(drive_veth, EXAMPLE, "--distance", "40960", "--time", "1.0")
    assert proc.returncode == 0, proc.stderr[-3000:] + proc.stdout[-2000:]
    out = proc.stdout
    assert "2 CiA 402 drive(s)" in out and "Operation enabled" in out
    moved = [int(x) for x in re.findall(r" to (-?\d+)", out.split("moved:")[1].splitlines()[0])]
    starts = [int(x) for x in re.findall(r" at (-?\d+)", out.split("Operation enabled:")[1].splitlines()[0])]
    assert len(moved) == 2 and all(abs(e - s - 40960) <= 10 for s, e in zip(starts, moved, strict=True))
    assert all(not d.drives[0].state.name.startswith("OPERATION") for d in drives)
