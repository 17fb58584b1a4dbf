"""The monitor's EtherCAT side (issue 14, "Watch": "EtherCAT-side events where the rig has them"): the AL state of
each EtherCAT device of the rig, asked from the rig's control endpoint (docs/faults.md), one log line per change."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import threading
from pathlib import Path

from gatewaylab.cli.monitor import EthercatWatcher
from gatewaylab.rig.process import RigProcess

RIG = """
clock = "realtime"
[[bus]]
name = "can0"
bitrate = 1000000
[[device]]
kind = "ethercat_drive"
name = "ax1"
"""


def test_watcher_logs_each_al_state_change(tmp_path: Path) -> None:
    """ETG.1000.6 AL status: INIT, then OP, then SAFEOP with the error flag and code 0x001A are three events; an
    unchanged state is none."""
    path = tmp_path / "control.sock"
    server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    server.bind(str(path))
    server.listen(4)
    answers = [{"ax1": {"state": "INIT", "error": False, "code": 0}},
               {"ax1": {"state": "INIT", "error": False, "code": 0}},
               {"ax1": {"state": "OP", "error": False, "code": 0}},
               {"ax1": {"state": "SAFEOP", "error": True, "code": 0x1A}}]

    def serve() -> None:
        for devices in answers:
            conn, _ = server.accept()
            with conn, conn.makefile("rwb") as f:
                assert json.loads(f.readline()) == {"fault": "ethercat-states"}
                f.write(json.dumps({"ok": True, "fault": "ethercat-states", "devices": devices}).encode() + b"\n")

    thread = threading.Thread(target=serve)
    thread.start()
    watcher = EthercatWatcher(f"unix:{path}", period=0.0)
    texts = [e.text for t in range(4) for e in watcher.poll(float(t))]
    thread.join(10)
    server.close()
    assert texts == ["EtherCAT ax1: INIT", "EtherCAT ax1: INIT -> OP",
                     "EtherCAT ax1: OP -> SAFEOP, AL status code 0x001A"]


def test_live_monitor_shows_the_rigs_ethercat_devices(tmp_path: Path) -> None:
    """`gatewaylab monitor READY --json` on a rig with an EtherCAT drive prints its AL state (INIT: no master)."""
    rig_file = tmp_path / "rig.toml"
    rig_file.write_text(RIG)
    with RigProcess(rig_file, workdir=tmp_path, timeout=30) as rig:
        out = subprocess.run([sys.executable, "-m", "gatewaylab", "monitor", str(rig.ready_file), "--json",
                              "--duration", "2"], capture_output=True, text=True, timeout=60, check=True)
    events = [json.loads(line) for line in out.stdout.splitlines()]
    assert {"kind": "ethercat", "device": "ax1", "state": "INIT"}.items() <= next(
        e for e in events if e["kind"] == "ethercat").items()
