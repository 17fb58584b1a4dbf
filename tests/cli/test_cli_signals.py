"""SIGINT and SIGTERM as a user sends them, at several moments, to `gatewaylab run`, `dump`, `monitor`
and a one-shot command (docs/cli.md "Signals"): "SIGINT (Ctrl-C) and SIGTERM end every command the
same way, at every moment, never with a traceback: `run`, `monitor` and `dump` exit 0 (once running,
with what they print at their end); every other command exits 128 + the signal's number".

The moments: right after the process was started (the signal may come before Python runs any of
gatewaylab's code: then the system ends it, as docs/cli.md says); as soon as the process has taken SIGTERM
over (/proc/PID/status ``SigCgt``: gatewaylab's first line); while its modules load (python-can's
``_asyncio`` extension mapped into the process, /proc/PID/maps); while it runs (after a line it prints
once running). No timing is asserted.
"""

from __future__ import annotations

import os
import pty
import queue
import select
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from gatewaylab.rig.process import RigProcess

WAIT = 90.0     # generous: a CLI needs seconds to start on a loaded 2-CPU machine
_SCRIPT = Path(sys.executable).parent / "gatewaylab"
#: `gatewaylab` as the user runs it (the console script pip installs), else `python -m gatewaylab`
GL = [str(_SCRIPT)] if _SCRIPT.exists() else [sys.executable, "-m", "gatewaylab"]
SIGNALS = [signal.SIGINT, signal.SIGTERM]

RIG = """
clock = "realtime"
[[bus]]
name = "can0"
bitrate = 1000000
[[bus]]
name = "lone"
bitrate = 1000000
[[drive]]
bus = "can0"
node_id = 2
serial = 0x1002
"""


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("signals")
    (path / "rig.toml").write_text(RIG)
    return path


@pytest.fixture(scope="module")
def rig(workdir: Path) -> Iterator[RigProcess]:
    with RigProcess(workdir / "rig.toml", workdir=workdir, timeout=WAIT) as r:
        yield r


def _args(command: str, rig: RigProcess | None, workdir: Path) -> list[str]:
    if command == "run":
        return ["run", str(workdir / "rig.toml"), "--ready-file", str(workdir / f"ready-{os.getpid()}-run.json")]
    assert rig is not None
    if command == "dump":
        return ["dump", str(rig.ready_file)]
    if command == "monitor":
        return ["monitor", str(rig.ready_file), "--plain"]
    return ["send", str(rig.ready_file), "--bus", "lone", "123#00", "--timeout", "600"]   # nobody acknowledges


def _spawn(args: list[str], **kw: object) -> subprocess.Popen[str]:
    return subprocess.Popen([*GL, *args], stdout=kw.pop("stdout", subprocess.PIPE), stderr=subprocess.PIPE,
                            stdin=subprocess.DEVNULL, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"},
                            **kw)  # type: ignore[call-overload]


def _takes_sigterm(pid: int) -> bool:
    """SIGTERM has a handler in ``pid`` (Python never sets one itself: gatewaylab's main() has run)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    caught = next(int(line.split()[1], 16) for line in status.splitlines() if line.startswith("SigCgt:"))
    return bool(caught & (1 << (signal.SIGTERM - 1)))


def _loads_python_can(pid: int) -> bool:
    """python-can is being imported (its asyncio brings the ``_asyncio`` extension into the process): the
    heavy part of the command's modules, hundreds of milliseconds before the command runs."""
    try:
        return "/_asyncio." in Path(f"/proc/{pid}/maps").read_text()
    except OSError:
        return False


MOMENTS = {"first-line": _takes_sigterm, "python-can-loads": _loads_python_can}


def _when(proc: subprocess.Popen[str], moment: str) -> None:
    reached = MOMENTS[moment]
    deadline = time.monotonic() + WAIT
    while not reached(proc.pid):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, f"{moment} never reached"
        time.sleep(0.001)


def _finish(proc: subprocess.Popen[str]) -> tuple[int, str, str]:
    try:
        out, err = proc.communicate(timeout=WAIT)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    return proc.returncode, out or "", err


def _expected(command: str, signum: int) -> int:
    return 0 if command in ("run", "monitor", "dump") else 128 + signum


def _no_leftovers(command: str, workdir: Path) -> None:
    if command == "run":
        assert not list(workdir.glob(f"ready-{os.getpid()}-run.json*"))


@pytest.mark.parametrize("command", ["run", "dump"])
def test_sigterm_right_after_spawn(command: str, rig: RigProcess, workdir: Path) -> None:
    """docs/cli.md "Signals": a signal at once after the start ends the command quietly; before Python
    has run gatewaylab's first line it is the system's (killed by SIGTERM), after it the documented code."""
    proc = _spawn(_args(command, rig, workdir))
    proc.send_signal(signal.SIGTERM)
    code, _, err = _finish(proc)
    assert code in (_expected(command, signal.SIGTERM), -signal.SIGTERM), (code, err)
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    _no_leftovers(command, workdir)


@pytest.mark.parametrize(("command", "signum", "moment"), [
    *[(c, signal.SIGTERM, "first-line") for c in ("run", "monitor")],
    *[(c, s, "python-can-loads") for c in ("run", "dump", "monitor", "send") for s in SIGNALS]])
def test_signal_while_modules_load(command: str, signum: int, moment: str, rig: RigProcess, workdir: Path) -> None:
    """docs/cli.md "Signals": from gatewaylab's first line on, and while the command's modules load (the
    issue: a KeyboardInterrupt traceback for Ctrl-C in the first 0.3 s, exit 143 for SIGTERM), both
    signals end it with the same code, quietly."""
    proc = _spawn(_args(command, rig, workdir))
    _when(proc, moment)
    proc.send_signal(signum)
    code, _, err = _finish(proc)
    assert code == _expected(command, signum), (code, err)
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    _no_leftovers(command, workdir)


def _read_until(proc: subprocess.Popen[str], want: str, poke: list[str] | None = None) -> list[str]:
    """stdout lines of ``proc`` until one contains ``want`` (``poke``: a gatewaylab command run meanwhile);
    the rest of stdout is left for :func:`_finish`."""
    assert proc.stdout is not None
    stdout = proc.stdout
    lines: queue.Queue[str] = queue.Queue()

    def read() -> None:
        for line in stdout:
            lines.put(line)
            if want in line:
                return
        lines.put("")

    threading.Thread(target=read, daemon=True).start()
    seen: list[str] = []
    deadline = time.monotonic() + WAIT
    while time.monotonic() < deadline:
        if poke is not None:
            subprocess.run([*GL, *poke], capture_output=True, timeout=WAIT)
        try:
            while True:
                line = lines.get(timeout=1.0)
                if not line:
                    raise AssertionError(f"ended before {want!r}: {seen} {proc.communicate()}")
                seen.append(line)
                if want in line:
                    return seen
        except queue.Empty:
            continue
    raise AssertionError(f"{want!r} not seen: {seen}")


@pytest.mark.parametrize("signum", SIGNALS, ids=["SIGINT", "SIGTERM"])
def test_run_stops_alike_while_running(signum: int, workdir: Path) -> None:
    """docs/cli.md "Signals", docs/rig.md: a running rig stops cleanly on either signal, says so, exit 0,
    its ready file removed."""
    ready = workdir / f"ready-{os.getpid()}-run.json"
    proc = _spawn(_args("run", None, workdir))
    _read_until(proc, "running (pid")
    assert ready.exists()
    proc.send_signal(signum)
    code, out, err = _finish(proc)
    assert code == 0 and out.rstrip().endswith("gatewaylab rig stopped"), (code, out, err)
    assert "Traceback" not in err
    assert not ready.exists()


@pytest.mark.parametrize("signum", SIGNALS, ids=["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("command", ["dump", "monitor"])
def test_dump_and_monitor_end_alike_while_running(command: str, signum: int, rig: RigProcess,
                                                  workdir: Path) -> None:
    """docs/cli.md "Signals": a running dump or decoded monitor ends on either signal with exit 0 and keeps
    what it printed (the issue: SIGTERM exit 143 with no output, SIGINT 0)."""
    proc = _spawn(_args(command, rig, workdir))
    lines = _read_until(proc, "DE AD BE EF", poke=["send", str(rig.ready_file), "321#DEADBEEF"])
    proc.send_signal(signum)
    code, _, err = _finish(proc)
    assert code == 0, (code, err)
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    assert any("321" in line and "DE AD BE EF" in line for line in lines)


def test_viewer_ends_on_sigterm_as_on_ctrl_c(rig: RigProcess) -> None:
    """docs/cli.md "Signals": `monitor --viewer` on a terminal shows its table of identifiers; SIGTERM ends it
    as Ctrl-C does, exit 0 with the table of what it saw on the screen (the issue: exit 143)."""
    signum = signal.SIGTERM
    master, slave = pty.openpty()
    proc = subprocess.Popen([*GL, "monitor", str(rig.ready_file), "--viewer"], stdin=subprocess.DEVNULL,
                            stdout=slave, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1", "COLUMNS": "100", "TERM": "xterm"})
    os.close(slave)
    screen = b""
    try:
        deadline = time.monotonic() + WAIT
        while b"DE AD BE EF" not in screen:
            assert time.monotonic() < deadline, screen[-2000:]
            subprocess.run([*GL, "send", str(rig.ready_file), "322#DEADBEEF"], capture_output=True, timeout=WAIT)
            # the viewer redraws its table all the time: read what came within 2 s, then look at it
            until = time.monotonic() + 2.0
            while time.monotonic() < until and select.select([master], [], [], 0.5)[0]:
                screen += os.read(master, 65536)
        proc.send_signal(signum)
        code, _, err = _finish(proc)
        until = time.monotonic() + 5.0
        while time.monotonic() < until and select.select([master], [], [], 0.2)[0]:
            try:
                screen += os.read(master, 65536)
            except OSError:          # EIO: the viewer closed its end
                break
    finally:
        os.close(master)
        if proc.poll() is None:
            proc.kill()
    assert code == 0, (code, err)
    assert "Traceback" not in err, err
    assert b"322" in screen and b"error frames" in screen


#: `gatewaylab run RIG` in-process, with a SIGTERM taken inside a weakref callback once `main` runs the command:
#: CPython drops the handler's exception there ("Exception ignored in"), as it does when the signal comes while
#: an import releases its module lock (the race this session's fresh-clone CI hit).
SWALLOWED = """
import os, signal, sys, weakref
from gatewaylab.cli.main import main

class Thing:
    pass

def swallow(event_frame, event, arg):
    if event == "call" and event_frame.f_code.co_name == "_main":
        sys.setprofile(None)
        thing = Thing()
        def callback(ref):
            os.kill(os.getpid(), signal.SIGTERM)
            for _ in range(1000):       # the handler runs here, inside the callback
                pass
        keep = weakref.ref(thing, callback)
        del thing

sys.setprofile(swallow)
sys.exit(main(["run", sys.argv[1]]))
"""


def test_a_signal_whose_exception_python_drops_still_stops_run(workdir: Path) -> None:
    """docs/cli.md "Signals": SIGTERM while `run` starts stops it quietly, exit 0, even when CPython drops the
    handler's exception (raised inside a weakref callback: "Exception ignored in" on stderr); before, the rig
    started and ran on until it was killed."""
    proc = subprocess.run([sys.executable, "-c", SWALLOWED, str(workdir / "rig.toml")], capture_output=True,
                          text=True, timeout=WAIT, check=False)
    assert "Exception ignored in" in proc.stderr, proc.stderr[-2000:]      # the exception was dropped indeed
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "Traceback (most recent call last)" not in proc.stderr.split("Exception ignored in")[0]
