"""`gatewaylab run` as a subprocess for the transport tests (waits for its ready file, never sleeps)."""

import json
import os
import selectors
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import can

RIG = """
clock = "realtime"
[[bus]]
name = "can0"
bitrate = 1000000
data_bitrate = 5000000
"""


class Rig:
    def __init__(self, proc: "subprocess.Popen[bytes]", info: dict) -> None:
        self.proc = proc
        self.info = info

    @property
    def endpoint(self) -> str:
        return self.info["buses"]["can0"]["endpoint"]

    def stop(self) -> str:
        """SIGTERM, wait, return what the rig logged."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        _, err = self.proc.communicate(timeout=20)
        return err.decode(errors="replace")


def start(tmp_path: Path, *extra: str, rig_text: str = RIG) -> Rig:
    rig_file = tmp_path / "rig.toml"
    rig_file.write_text(rig_text)
    ready = tmp_path / "ready.json"
    proc = subprocess.Popen([sys.executable, "-m", "gatewaylab", "run", str(rig_file), "--ready-file", str(ready),
                             *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    assert proc.stdout is not None
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    out = b""
    deadline = time.monotonic() + 30
    try:
        while b"  bus " not in out:   # printed after the ready file was written
            if time.monotonic() > deadline or not sel.select(deadline - time.monotonic()):
                break
            chunk = os.read(proc.stdout.fileno(), 4096)
            if not chunk:
                break
            out += chunk
    finally:
        sel.close()
    if b"  bus " not in out:
        proc.kill()
        _, err = proc.communicate()
        raise AssertionError(f"rig did not start: {out!r} {err!r}")
    return Rig(proc, json.loads(ready.read_text()))


def rigs(tmp_path: Path) -> Iterator[Callable[..., Rig]]:
    """Body of the ``rig_factory`` fixture of each test module: start rigs, kill leftovers."""
    rigs: list[Rig] = []

    def _start(*extra: str, rig_text: str = RIG) -> Rig:
        folder = tmp_path / f"rig{len(rigs)}"
        folder.mkdir()
        rig = start(folder, *extra, rig_text=rig_text)
        rigs.append(rig)
        return rig

    yield _start
    for rig in rigs:
        stop(rig)


def drain(bus: can.BusABC, count: int, timeout: float = 10.0) -> list[can.Message]:
    """Receive until ``count`` messages came or none came for ``timeout`` seconds."""
    got: list[can.Message] = []
    while len(got) < count:
        msg = bus.recv(timeout)
        if msg is None:
            break
        got.append(msg)
    return got


def one_rig(tmp_path: Path, *extra: str) -> Iterator[Rig]:
    """Body of a module-scoped rig fixture: one rig shared by the tests of a module."""
    rig = start(tmp_path, *extra)
    try:
        yield rig
    finally:
        stop(rig)


def stop(rig: Rig) -> None:
    """SIGTERM (the rig removes its sockets and folder), SIGKILL only if that does not end it."""
    if rig.proc.poll() is None:
        rig.proc.send_signal(signal.SIGTERM)
        try:
            rig.proc.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            rig.proc.kill()
            rig.proc.communicate()
