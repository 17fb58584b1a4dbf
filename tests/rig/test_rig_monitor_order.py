"""The decoded monitor's log in time order, the rig's controller events among the frames (docs/monitor.md
"Time order"), and the IDX in the monitor's node table (docs/monitor.md "What the decoded view shows":
"The rig's nodes are listed before they speak"), driven as a user does: `gatewaylab run`, `gatewaylab
monitor --plain`, `gatewaylab send` and `gatewaylab fault` from other processes."""

from __future__ import annotations

import json
import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from gatewaylab.rig.process import RigProcess

WAIT = 90.0
_SCRIPT = Path(sys.executable).parent / "gatewaylab"
GL = [str(_SCRIPT)] if _SCRIPT.exists() else [sys.executable, "-m", "gatewaylab"]

RIG = """
clock = "realtime"
[[bus]]
name = "can0"
bitrate = 1000000
[[drive]]
bus = "can0"
node_id = 2
serial = 0x1002
name = "axis2"
[[drive]]
bus = "can0"
node_id = 3
serial = 0x1003
name = "axis3"
[[device]]
kind = "maxon_idx"
name = "idx1"
bus = "can0"
node_id = 1
usb = { pty = false }
"""
_LINE = re.compile(r"(\d+\.\d{6})  (.*)")


def gl(*args: str) -> subprocess.CompletedProcess[str]:
    done = subprocess.run([*GL, *args], capture_output=True, text=True, timeout=WAIT)
    assert done.returncode == 0, done.stderr
    return done


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RigProcess]:
    tmp = tmp_path_factory.mktemp("order")
    (tmp / "rig.toml").write_text(RIG)
    # --acker: while one drive is off the other's frames are still acknowledged
    with RigProcess(tmp / "rig.toml", "--acker", workdir=tmp, timeout=WAIT) as r:
        yield r


class Monitor:
    """`gatewaylab monitor READY --plain` in the background; its lines as they come."""

    def __init__(self, ready: Path, *extra: str) -> None:
        self.proc = subprocess.Popen([*GL, "monitor", str(ready), *extra], stdin=subprocess.DEVNULL,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     env={**os.environ, "PYTHONUNBUFFERED": "1"})
        self.lines: list[str] = []
        self._q: queue.Queue[str] = queue.Queue()
        assert self.proc.stdout is not None and self.proc.stderr is not None
        out = self.proc.stdout
        self._reader = threading.Thread(target=lambda: [self._q.put(ln.rstrip("\n")) for ln in out], daemon=True)
        self._reader.start()
        assert self.proc.stderr.readline().startswith("monitoring ")      # connected

    def until(self, pattern: str) -> str:
        deadline = time.monotonic() + WAIT
        while time.monotonic() < deadline:
            try:
                line = self._q.get(timeout=0.5)
            except queue.Empty:
                continue
            self.lines.append(line)
            if re.search(pattern, line):
                return line
        raise AssertionError(f"{pattern!r} not seen; got {self.lines[-30:]}")

    def stop(self) -> list[str]:
        """SIGTERM: the monitor prints what it held back and exits 0 (docs/cli.md "Signals")."""
        self.proc.send_signal(signal.SIGTERM)
        self.proc.wait(WAIT)
        assert self.proc.returncode == 0
        self._reader.join(WAIT)             # every line, up to the end of the pipe
        while not self._q.empty():
            self.lines.append(self._q.get())
        return self.lines


def _index(lines: list[str], pattern: str, start: int = 0) -> int:
    return next(k for k in range(start, len(lines)) if re.search(pattern, lines[k]))


def test_controller_events_and_frames_in_time_order(rig: RigProcess) -> None:
    """docs/monitor.md "Time order": the log is sorted by time although the rig's controller events come by
    polling; a node cannot send while it is off the bus, so between "CAN axis3: unplugged" and "plugged in
    again" there is no heartbeat of node 3, and after a power cycle "CAN axis2: plugged in again" comes
    before "boot-up of node 2" (the issue: boot-up at 14.121 printed before "plugged in again" at 14.524,
    an unplug at 4.2046 before a heartbeat at 4.2036)."""
    ready = str(rig.ready_file)
    mon = Monitor(rig.ready_file, "--plain")
    try:
        for node in (2, 3):          # heartbeats every 100 ms (0x1017): frames interleave with the events
            gl("send", ready, f"60{node}#2B17100064000000")
        mon.until(r"heartbeat of node 3")
        # off for three of the monitor's 0.5 s polls of the controllers: one poll late on a loaded machine
        # (a concurrent test's real-time rig) must not miss the whole power cycle
        gl("fault", ready, "power-cycle", "axis2", "--off", "1.5")
        mon.until(r"boot-up of node 2")
        gl("fault", ready, "can-unplug", "axis3")
        mon.until(r"CAN axis3: unplugged")
        gl("fault", ready, "can-replug", "axis3")
        mon.until(r"CAN axis3: plugged in again")
        mon.until(r"heartbeat of node 3")
    finally:
        lines = mon.stop()
    times = [float(m.group(1)) for m in map(_LINE.match, lines) if m]
    assert len(times) == len(lines), [ln for ln in lines if not _LINE.match(ln)]
    assert times == sorted(times), [(a, b) for a, b, ta, tb in zip(lines, lines[1:], times, times[1:], strict=False)
                                    if ta > tb]
    cycle = _index(lines, r"CAN axis2: unplugged")
    assert _index(lines, r"CAN axis2: plugged in again", cycle) < _index(lines, r"boot-up of node 2", cycle)
    away, back = _index(lines, r"CAN axis3: unplugged"), _index(lines, r"CAN axis3: plugged in again")
    assert away < back
    assert not [ln for ln in lines[away:back] if "heartbeat of node 3" in ln]


def test_idx_is_a_node_of_the_ready_file_and_the_monitor(rig: RigProcess) -> None:
    """docs/rig.md ready file "canopen": every CANopen node of the rig with its node-ID and EDS -- the IDX
    too (it is node 1 on can0, CiA 301); the monitor lists it in its node table before it speaks and names
    its objects from its EDS (0x1018:04 "Identity object/Serial number")."""
    info = json.loads(rig.ready_file.read_text())
    idx = info["canopen"]["can0"]["idx1"]
    assert idx["node_id"] == 1 and idx["serial"] == 0x2001 and Path(idx["eds"]).is_file()
    table = subprocess.run([*GL, "monitor", str(rig.ready_file), "--duration", "1"], capture_output=True, text=True,
                           timeout=WAIT)
    assert table.returncode == 0, table.stderr
    rows = [ln.split("│")[1].strip() for ln in table.stdout.splitlines() if ln.startswith("│")]
    assert rows[:3] == ["1", "2", "3"]
    mon = Monitor(rig.ready_file, "--plain")
    try:
        gl("send", str(rig.ready_file), "601#4018100400000000")       # SDO upload 0x1018:04 from node 1
        line = mon.until(r"node 1 read 0x1018:04")
    finally:
        mon.stop()
    assert "Identity object/Serial number = 8193 (0x00002001)" in line
