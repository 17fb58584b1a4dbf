"""Issue 13 part 3: ``gatewaylab migrate compare --wire`` runs the application "in real time over veth
pairs with pysoem": each gateway's copy of the rig on one end of a fresh veth pair, SOEM as the
master in a child process inside a network namespace; the namespace and the pair are removed again."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import can
import pytest
from test_migrate_compare_cli import RIG, SAME_APP
from wire_kit import net_capable

from gatewaylab.cli.main import main


@pytest.mark.net
@pytest.mark.slow
def test_wire_compare_of_one_sdo_upload(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 13 part 3 '--wire in real time over veth pairs with pysoem': the same raw SDO upload
    through both gateways on real raw sockets gives the same CAN traffic (exit 0) and the report; no
    namespace or veth interface of the run is left behind. (Latencies are measured, never asserted.)"""
    reason = net_capable("pysoem")
    if reason is not None:
        pytest.skip(reason)
    rig = tmp_path / "rig.toml"
    rig.write_text(RIG)
    app = tmp_path / "app.py"
    app.write_text(SAME_APP)
    report = tmp_path / "rep"
    code = main(["migrate", "compare", "--rig", str(rig), "--bus", "can0", "--app", str(app),
                 "--report", str(report), "--wire", "--json"])
    summary = json.loads(capsys.readouterr().out)
    assert code == 0, summary
    assert summary["identical"] is True
    assert summary["latency"]["esd CAN-EtherCAT"]["master_to_can"]["count"] == 1
    ids = [m.arbitration_id for m in can.LogReader(str(report / "ecanlite.bus.csv"))]
    assert ids[-2:] == [0x602, 0x582]
    assert "real time over veth pairs" in (report / "report.md").read_text()
    left = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True, check=False).stdout
    assert f"gl-cmp-{os.getpid() % 100000}" not in left      # this process's namespaces (compare_wire)
