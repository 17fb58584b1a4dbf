"""`gatewaylab run` as a subprocess for the transport tests (waits for its ready file, never sleeps)."""

from collections.abc import Callable, Iterator
from pathlib import Path

import can

from gatewaylab.rig.process import RigProcess

RIG = """
clock = "realtime"
[[bus]]
name = "can0"
bitrate = 1000000
data_bitrate = 5000000
"""


class Rig:
    """A :class:`RigProcess` with can0's endpoint as an attribute and ``stop()`` returning its log."""

    def __init__(self, process: RigProcess) -> None:
        self.process = process
        self.proc = process.proc
        self.info = process.info

    @property
    def endpoint(self) -> str:
        return self.process.endpoint("can0")

    def stop(self) -> str:
        """SIGTERM, wait, return what the rig logged."""
        self.process.stop(20)
        return self.process.log_text()


def start(tmp_path: Path, *extra: str, rig_text: str = RIG) -> Rig:
    rig_file = tmp_path / "rig.toml"
    rig_file.write_text(rig_text)
    return Rig(RigProcess(rig_file, *extra, workdir=tmp_path, timeout=30))


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
    rig.stop()
