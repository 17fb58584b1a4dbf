"""`gatewaylab run` in a child process: what tests, soaks and scripts start beside a real-time rig.

A program that tests master software against a rig wants it in another process (its own GIL, its
own signal handling, killed like a real device) and wants to know when it is up. The CLI writes
the ready file atomically once every endpoint exists and then prints its banner, so
:class:`RigProcess` waits on the child's output and reads that file; :meth:`RigProcess.stop` ends
it the way systemd or CI would (SIGTERM, then SIGKILL).
"""

from __future__ import annotations

import json
import os
import select
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Mapping
from pathlib import Path
from types import TracebackType
from typing import IO, Any

from gatewaylab.common.errors import ConfigError, GatewaylabError

__all__ = ["RigFileValueError", "RigProcess", "RigStartTimeout", "free_udp_ports", "rig_toml"]


def _value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)        # a JSON string is a TOML basic string
    if isinstance(value, Mapping):
        return "{ " + ", ".join(f"{_key(k)} = {_value(v)}" for k, v in value.items()) + " }"
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_value(v) for v in value) + "]"
    raise RigFileValueError(f"a rig file has no values of type {type(value).__name__} ({value!r})")


def _key(key: str) -> str:
    return key if key.replace("_", "").replace("-", "").isalnum() and key.isascii() else json.dumps(key)


def rig_toml(data: Mapping[str, Any]) -> str:
    """A rig given as a dict (the shape of a parsed rig file) as rig-file text."""
    lines: list[str] = []
    tables: list[str] = []
    for key, value in data.items():
        if isinstance(value, list) and value and all(isinstance(v, Mapping) for v in value):
            for entry in value:
                tables.append(f"\n[[{_key(key)}]]")
                tables.extend(f"{_key(k)} = {_value(v)}" for k, v in entry.items())
        elif isinstance(value, Mapping):
            tables.append(f"\n[{_key(key)}]")
            tables.extend(f"{_key(k)} = {_value(v)}" for k, v in value.items())
        else:
            lines.append(f"{_key(key)} = {_value(value)}")
    return "\n".join(lines + tables) + "\n"


def free_udp_ports(n: int, host: str = "127.0.0.1") -> list[int]:
    """``n`` UDP ports free on ``host`` right now: the two ends of rigs joined by cannelloni tunnels
    need each other's port before either starts."""
    socks = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(n)]
    try:
        for sock in socks:
            sock.bind((host, 0))
        return [sock.getsockname()[1] for sock in socks]
    finally:
        for sock in socks:
            sock.close()


class RigFileValueError(ConfigError, TypeError):
    """A rig given as a mapping holds a value no TOML file can (a TypeError to callers that expect one)."""


class RigStartTimeout(GatewaylabError, RuntimeError):
    """The child did not write its ready file in time, or exited before it did (a failure at run time)."""


class RigConfigError(ConfigError):
    """The child refused its rig file or options (``gatewaylab run`` exit 2): the message is its one line,
    the same ConfigError an in-process rig raises for the same mistake."""


#: ``gatewaylab run``'s exit code for a rig file or command line that is wrong (docs/cli.md).
USAGE_EXIT = 2


class RigProcess:
    """A started ``gatewaylab run RIG_FILE --ready-file ...`` child and its ready-file contents.

    ``rig_file`` None runs the default rig; ``extra`` are more ``gatewaylab run`` options
    (``--acker``, ``--trace can0=x.log``). The rig's log (stderr) goes to ``stderr`` or, by default,
    to ``rig-*.log`` in ``workdir`` (a file, not a pipe: a long run that logs a lot never blocks);
    its tail is shown when the start fails. ``prefix`` runs it through another command that then
    executes it, e.g. ``("ip", "netns", "exec", "NS")`` for a rig in a network namespace.
    """

    def __init__(self, rig_file: str | Path | None, *extra: str, workdir: str | Path,
                 timeout: float = 60.0, stderr: IO[Any] | int | None = None,
                 prefix: tuple[str, ...] = ()) -> None:
        tag = f"{os.getpid()}-{id(self):x}"
        self.ready_file = Path(workdir) / f"ready-{tag}.json"
        self.log_file: Path | None = None
        if stderr is None:
            self.log_file = Path(workdir) / f"rig-{tag}.log"
        args = [*prefix, sys.executable, "-m", "gatewaylab", "run", *([str(rig_file)] if rig_file else []),
                "--ready-file", str(self.ready_file), *extra]
        log = self.log_file.open("wb") if self.log_file is not None else None
        try:
            self.proc: subprocess.Popen[bytes] = subprocess.Popen(
                args, stdout=subprocess.PIPE, stderr=log if log is not None else stderr,
                env={**os.environ, "PYTHONUNBUFFERED": "1"})
        finally:
            if log is not None:
                log.close()
        try:
            self.info: dict[str, Any] = self._wait_ready(timeout)
        except BaseException:
            self.stop()
            raise

    def _wait_ready(self, timeout: float) -> dict[str, Any]:
        assert self.proc.stdout is not None
        fd = self.proc.stdout.fileno()
        deadline = time.monotonic() + timeout
        seen = b""
        while True:
            try:
                info: dict[str, Any] = json.loads(self.ready_file.read_text())
                return info
            except (OSError, ValueError):
                pass
            left = deadline - time.monotonic()
            if left <= 0 or self.proc.poll() is not None:
                break
            if select.select([fd], [], [], min(left, 0.2))[0]:
                chunk = os.read(fd, 65536)
                seen += chunk
        err = self.log_file.read_bytes()[-2000:] if self.log_file is not None else b""
        code = self.proc.poll()
        text = (seen + err).decode(errors="replace").strip()
        if code == USAGE_EXIT:         # the rig file or the options are wrong: nothing timed out
            lines = [line.removeprefix("gatewaylab: ") for line in text.splitlines() if line.strip()]
            raise RigConfigError(lines[-1] if lines else f"gatewaylab run refused its rig file (exit {code})")
        raise RigStartTimeout(f"gatewaylab run did not start (exit {code}): {text}")

    @property
    def pid(self) -> int:
        """The rig's process id (to signal or kill it in a test)."""
        return self.proc.pid

    def endpoint(self, bus: str = "can0") -> str:
        """The endpoint of ``bus`` as the ready file gives it (``unix:PATH`` / ``tcp:HOST:PORT``)."""
        return str(self.info["buses"][bus]["endpoint"])

    def log_text(self) -> str:
        """What the rig logged so far (its stderr), when it logs to the default file."""
        return self.log_file.read_text(errors="replace") if self.log_file is not None else ""

    def stop(self, timeout: float = 10.0) -> int | None:
        """SIGTERM, wait up to ``timeout``, then SIGKILL; returns the exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.proc.stdout is not None:
            self.proc.stdout.close()
        return self.proc.returncode

    def __enter__(self) -> RigProcess:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()
