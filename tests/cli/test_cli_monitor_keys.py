"""`q` leaves the monitor (`gatewaylab monitor --help`: "live view (q or Ctrl-C to leave)"; docs/cli.md:
exit 0 for "a monitor left with Ctrl-C / `q`"), driven as a user does: `gatewaylab monitor` against a
running rig with a terminal (a pty that is its controlling terminal) on stdin. While it runs the
terminal is in cbreak mode (keys one by one, no echo); it is restored when the monitor ends. Without a
terminal on stdin, a ``q`` in its input means nothing (docs/monitor.md "Leaving")."""

from __future__ import annotations

import fcntl
import os
import pty
import subprocess
import sys
import termios
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
"""


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RigProcess]:
    tmp = tmp_path_factory.mktemp("keys")
    (tmp / "rig.toml").write_text(RIG)
    with RigProcess(tmp / "rig.toml", "--acker", workdir=tmp, timeout=WAIT) as r:   # the boot-up is sent at once
        yield r


def _controlling_terminal() -> None:
    """In the child: a session of its own with the pty on stdin as its controlling terminal (a shell's
    foreground job)."""
    os.setsid()
    fcntl.ioctl(0, termios.TIOCSCTTY, 0)


def _cbreak(master: int) -> bool:
    lflag = termios.tcgetattr(master)[3]
    return not lflag & termios.ICANON and not lflag & termios.ECHO


@pytest.mark.parametrize("mode", ["--plain", "--viewer", "--json", "rich"])
def test_q_leaves_the_monitor(mode: str, rig: RigProcess) -> None:
    """Typing q ends the live view: exit 0, its summary printed (the viewer's table, the rich view's
    node table), the terminal back in its line mode with echo."""
    master, slave = pty.openpty()
    before = termios.tcgetattr(master)
    assert not _cbreak(master)
    extra = [] if mode == "rich" else [mode]
    proc = subprocess.Popen([*GL, "monitor", str(rig.ready_file), *extra], stdin=slave, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, preexec_fn=_controlling_terminal,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    os.close(slave)
    try:
        deadline = time.monotonic() + WAIT
        while not _cbreak(master):          # the monitor runs and reads keys
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "the terminal never went to cbreak mode"
            time.sleep(0.01)
        os.write(master, b"q")
        out, err = proc.communicate(timeout=WAIT)
        after = termios.tcgetattr(master)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        os.close(master)
    assert proc.returncode == 0, err
    assert "Traceback" not in err
    assert after[3] == before[3], "the terminal's local modes were not restored"
    if mode == "--viewer":
        assert "count  period ms" in out           # its table, printed once at the end into a pipe
    if mode == "rich":
        assert "CiA 402" in out and "│ 2 " in out  # the node table, drive 2 listed from the ready file
    if mode == "--plain":
        assert "q or Ctrl-C leaves" in err


def test_q_on_a_pipe_is_no_key(rig: RigProcess) -> None:
    """Without a terminal on stdin nothing reads keys: a q in the monitor's input does not stop it (it
    decodes the next frame, -n 1 ends it) and it does not say q leaves."""
    proc = subprocess.Popen([*GL, "monitor", str(rig.ready_file), "--plain", "-n", "1"], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    assert proc.stdin is not None and proc.stderr is not None
    proc.stdin.write("q\n")
    proc.stdin.flush()
    header = proc.stderr.readline()
    assert header.startswith("monitoring ") and "q or Ctrl-C" not in header
    try:
        deadline = time.monotonic() + WAIT
        while proc.poll() is None:
            assert time.monotonic() < deadline
            subprocess.run([*GL, "send", str(rig.ready_file), "323#0102"], capture_output=True, timeout=WAIT)
        out, err = proc.communicate(timeout=WAIT)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err
    assert "323   [2]  01 02" in out
