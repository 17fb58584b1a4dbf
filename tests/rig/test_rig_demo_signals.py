"""`gatewaylab demo` cleans up when it is stopped (issue 25): SIGTERM stops its rig child with SIGTERM
(the rig removes its own folder) and removes the demo's folder; `make demo | head` (a closed stdout,
SIGPIPE in a shell pipeline) does the same and leaves without a traceback."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

WAIT = 90.0


def _start(tmp_path: Path) -> subprocess.Popen[str]:
    env = {**os.environ, "TMPDIR": str(tmp_path), "PYTHONUNBUFFERED": "1"}
    return subprocess.Popen([sys.executable, "-m", "gatewaylab", "demo"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env)


def _until_rig_is_up(proc: subprocess.Popen[str]) -> int:
    """Read the demo's output until it printed the rig's ready file; returns the rig's pid."""
    assert proc.stdout is not None
    deadline = time.monotonic() + WAIT
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        m = re.match(r"\s*ready file: (\{.*\})$", line)
        if m:
            return int(json.loads(m[1])["pid"])
        assert line, "the demo ended before its rig was up"
    raise AssertionError("the rig did not come up")


def _gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return Path(f"/proc/{pid}/status").read_text().find("State:\tZ") >= 0


def _wait_gone(pid: int) -> None:
    deadline = time.monotonic() + 20
    while not _gone(pid):
        assert time.monotonic() < deadline, f"rig {pid} still running"
        time.sleep(0.1)


@pytest.mark.parametrize("how", ["sigterm", "closed-pipe"])
def test_demo_stopped_leaves_no_rig_and_no_folder(tmp_path: Path, how: str) -> None:
    proc = _start(tmp_path)
    try:
        rig_pid = _until_rig_is_up(proc)
        names = [p.name for p in tmp_path.iterdir()]
        assert any(n.startswith("gatewaylab-demo-") for n in names) and len(names) >= 2, names  # demo's, rig's
        if how == "sigterm":
            proc.send_signal(signal.SIGTERM)
            code = proc.wait(WAIT)
            assert code == 128 + signal.SIGTERM
        else:
            assert proc.stdout is not None
            proc.stdout.close()             # `| head` has read enough
            code = proc.wait(WAIT)
            assert code == 0
        assert proc.stderr is not None
        assert "Traceback" not in proc.stderr.read()
        _wait_gone(rig_pid)
        assert list(tmp_path.iterdir()) == []          # the demo's folder and the rig's both removed
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
