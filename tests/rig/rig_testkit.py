"""Start `gatewaylab run` as a real subprocess and wait for its ready file (helpers for tests/rig)."""

import json
import os
import selectors
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest


class RunningRig:
    def __init__(self, proc: subprocess.Popen[str], ready_file: Path, info: dict) -> None:
        self.proc = proc
        self.ready_file = ready_file
        self.info = info

    def endpoint(self, bus: str = "can0") -> str:
        return self.info["buses"][bus]["endpoint"]


_buffers: "dict[int, bytes]" = {}


def wait_for_line(proc: "subprocess.Popen[str]", needle: str, timeout: float = 20.0) -> str:
    """Read the child's stdout until a line contains ``needle`` (waits on the pipe, never sleeps)."""
    assert proc.stdout is not None
    fd = proc.stdout.fileno()
    sel = selectors.DefaultSelector()
    sel.register(fd, selectors.EVENT_READ)
    deadline = time.monotonic() + timeout
    buf = _buffers.get(proc.pid, b"")
    seen = b""
    try:
        while True:
            while b"\n" in buf:
                line, buf = buf.split(b"\n", 1)
                seen += line + b"\n"
                if needle.encode() in line:
                    return line.decode()
            remaining = deadline - time.monotonic()
            if remaining <= 0 or not sel.select(remaining):
                break
            chunk = os.read(fd, 65536)
            if not chunk:
                break
            buf += chunk
    finally:
        _buffers[proc.pid] = buf
        sel.close()
    raise AssertionError(f"{needle!r} not seen; output so far: {seen.decode(errors='replace')}")


@pytest.fixture
def start_rig(tmp_path: Path) -> Iterator:
    procs: list[subprocess.Popen[str]] = []
    state_dirs: dict[int, list[Path]] = {}

    def _start(rig_text: str | None, *extra: str) -> RunningRig:
        args = [sys.executable, "-m", "gatewaylab", "run"]
        if rig_text is not None:
            rig_file = tmp_path / f"rig{len(procs)}.toml"
            rig_file.write_text(rig_text)
            args.append(str(rig_file))
        ready = tmp_path / f"ready{len(procs)}.json"
        args += ["--ready-file", str(ready), *extra]
        proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                env={**os.environ, "PYTHONUNBUFFERED": "1"})
        procs.append(proc)
        wait_for_line(proc, "bus ")  # printed after the ready file was written
        info = json.loads(ready.read_text())
        state_dirs[proc.pid] = [Path(bus["endpoint"][len("unix:"):]).parent for bus in info["buses"].values()
                                if bus.get("endpoint", "").startswith("unix:")]
        return RunningRig(proc, ready, info)

    yield _start
    for proc in procs:  # SIGTERM first: a rig removes its sockets and state folder (issue 15)
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        for pipe in (proc.stdout, proc.stderr):
            if pipe is not None:
                pipe.close()
        if proc.returncode == -signal.SIGKILL:  # killed on purpose: nothing in it could clean up
            for folder in state_dirs.get(proc.pid, []):
                if folder.name.startswith("gatewaylab-"):
                    shutil.rmtree(folder, ignore_errors=True)
