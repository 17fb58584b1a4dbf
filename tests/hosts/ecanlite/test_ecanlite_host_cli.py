"""``gatewaylab ecan simple-loop | sdo-probe | cia402`` (issue 12, manual 15.4 / 15.6) as subprocesses
on ``--rig`` files: the values, the master_period / WKC / parse-error lines, ``--json`` for scripts,
and exit code 2 with one stderr line for a wrong command line."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from gatewaylab.hosts.ecanlite.demo import rig_toml


def _ecan(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "gatewaylab", "ecan", *args], capture_output=True, text=True,
                          timeout=300, check=False)


@pytest.fixture
def rig_file(tmp_path: Path) -> str:
    path = tmp_path / "rig.toml"
    path.write_text(rig_toml(((1, 2), (3,), (4,), (5,))))
    return str(path)


def test_sdo_probe_prints_the_value(rig_file: str) -> None:
    """15.4: ``sdo-probe --node 1 --index 0x1000 --sub 0 --bitrate 1000000`` prints the device type
    of the drive behind CAN0 (0x00020192, CiA 402 servo) and the cycle statistics."""
    r = _ecan("sdo-probe", "--rig", rig_file, "--node", "1", "--index", "0x1000", "--sub", "0",
              "--bitrate", "1000000")
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0] == "node 1 0x1000:00 = 0x00020192 131474 [92 01 02 00]"
    assert lines[1].startswith("master_period: ")
    assert "WKC errors 0, parse errors 0" in lines[2]
    r = _ecan("sdo-probe", "--rig", rig_file, "--node", "9", "--index", "0x1000", "--timeout", "0.2")
    assert r.returncode == 1 and "SDO abort 0x05040000" in r.stderr


def test_simple_loop_json(rig_file: str) -> None:
    """15.4 simple loop on CAN0..CAN3: every frame sent is confirmed by a TX_RESULT (chapter 10); the
    progress bar (forced, stderr is not a terminal here) goes to stderr, the JSON alone to stdout."""
    r = _ecan("simple-loop", "--rig", rig_file, "--cycles", "30", "--json", "--progress")
    assert r.returncode == 0, r.stderr
    assert "30/30" in r.stderr
    report = json.loads(r.stdout)
    assert set(report["channels"]) == {"0", "1", "2", "3"}
    for c in report["channels"].values():
        assert c["sent"] == c["tx_ok"] == 30 and c["tx_failed"] == 0
    assert report["errors"]["wkc_errors"] == 0 and report["errors"]["parse_errors"] == 0


def test_cia402_moves_every_rig_axis(rig_file: str) -> None:
    """15.6 demo flags on the rig's five drives: every axis reaches start + cycles * step; text output
    has one line per axis."""
    r = _ecan("cia402", "--rig", rig_file, "--slaves", "1", "--pdo-n", "3", "--cycle-us", "1000", "--cycles", "300",
              "--step", "15", "--motion-div", "1", "--json")
    assert r.returncode == 0, r.stderr
    report = json.loads(r.stdout)
    assert [a["node_id"] for a in report["axes"]] == [1, 2, 3, 4, 5]
    assert all(a["reached"] and a["target"] - a["start"] == 4500 for a in report["axes"])
    r = _ecan("cia402", "--rig", rig_file, "--axes", "0:2:4", "--cycles", "100", "--step", "-10", "--align4",
              "--dc-sync0", "--dc-shift-us", "700")
    assert r.returncode == 0, r.stderr
    last = r.stdout.splitlines()[-1]
    assert last.startswith("axis slave 0 CAN2 node 4: start 0 target -1000 actual ") and last.endswith(" reached")


def test_usage_errors(rig_file: str, tmp_path: Path) -> None:
    """A wrong command line: exit 2, one line on stderr naming the problem."""
    for args, text in ((("sdo-probe", "--node", "1", "--index", "0x1000"), "-i IFNAME"),
                       (("cia402", "--rig", str(tmp_path / "none.toml")), "does not exist"),
                       (("cia402", "--rig", rig_file, "--axes", "0:9:1"), "not 0..3"),
                       (("cia402", "--rig", rig_file, "--slaves", "2"), "1 ECAN-Lite")):
        r = _ecan(*args)
        assert r.returncode == 2, (args, r.stdout, r.stderr)
        assert text in r.stderr and len(r.stderr.strip().splitlines()) == 1
