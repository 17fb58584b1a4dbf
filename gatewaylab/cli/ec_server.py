"""A persistent EtherCAT master for ``gatewaylab ec``: ``gatewaylab ec master --serve SOCKET``.

IgH's master is a kernel module that stays up; its ``ethercat`` tool only talks to it. Without one,
every ``gatewaylab ec`` call opens the line, and a slave left in SAFEOP/OP by the previous call sees
its process data stop: the SyncManager watchdog takes it to SAFEOP with AL status 0x001B. This
server holds one :class:`~.backend.MasterBackend` open, exchanges process data every cycle once the
segment is mapped (so slaves stay in OP between calls), and runs the verbs that clients send with
``--master SOCKET`` on that backend, one at a time.

Protocol (Unix socket, one JSON object per line each way): ``{"verb": NAME, "args": {...}}`` ->
``{"code": EXIT, "stdout": TEXT, "stderr": TEXT}``; ``{"info": true}`` -> the master's state;
``{"stop": true}`` ends the server.
"""

from __future__ import annotations

import json
import os
import socket
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gatewaylab.bus.transport.unix_file import bind_unix, remove_unix
from gatewaylab.cli.ec_args import EcUsage
from gatewaylab.common.ask import ask
from gatewaylab.common.errors import GatewaylabError
from gatewaylab.hosts.ethercat.backend import MasterBackend

__all__ = ["MAX_REQUEST", "EcMasterServer", "VerbRunner", "request"]


#: Runs one verb on the backend: (verb, JSON arguments) -> (exit code, stdout, stderr).
VerbRunner = Callable[[MasterBackend, str, dict[str, Any]], tuple[int, str, str]]
MAX_REQUEST = 16 * 1024 * 1024     # a foe-write carries its file (base64)


class _Mapped:
    """The backend as verbs see it: notes when a verb maps the process data (config_map), counts the
    exchanges verbs make, and tells ``domains`` the live domain's state (ec_cli.LiveMaster)."""

    def __init__(self, backend: MasterBackend, server: EcMasterServer) -> None:
        self._backend = backend
        self._server = server

    def config_map(self) -> int:
        size = self._backend.config_map()
        self._server.mapped = True
        return size

    @property
    def mapped(self) -> bool:
        return self._server.mapped

    def exchange(self) -> tuple[int, int]:
        return self._server.count(self._backend.exchange())

    def counters(self) -> tuple[int, int | None, int | None]:
        """(exchanges, working counter of the last one, the one expected then) of the cycling master."""
        return self._server.exchanges, self._server.last_wkc, self._server.last_expected

    def __getattr__(self, name: str) -> Any:
        return getattr(self._backend, name)


class EcMasterServer:
    """One backend, a cycling thread and a Unix socket for verbs (see the module docstring)."""

    def __init__(self, backend: MasterBackend, path: str | Path, run_verb: VerbRunner, *, cycle: float = 0.002,
                 line: str = "") -> None:
        self.backend = backend
        self.path = Path(path)
        self.run_verb = run_verb
        self.cycle = cycle
        self.line = line
        self.mapped = False
        self.exchanges = 0
        self.last_wkc: int | None = None
        self.last_expected: int | None = None
        self.requests = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._proxy: Any = _Mapped(backend, self)
        if (self.path.exists() or self.path.is_symlink()) and _alive(self.path):
            raise GatewaylabError(f"{self.path}: a master is already serving there")
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            self._bound = bind_unix(self._sock, self.path)   # a stale socket is replaced, another file never
        except OSError as exc:
            self._sock.close()
            raise GatewaylabError(f"{self.path}: {exc.strerror or exc}") from None
        os.chmod(self.path, 0o600)
        self._sock.listen(8)
        self._sock.settimeout(0.2)

    def info(self) -> dict[str, Any]:
        """What ``gatewaylab ec master`` prints of a running master."""
        with self._lock:
            slaves = self.backend.slaves()
        return {"line": self.line, "slaves": len(slaves), "mapped": self.mapped, "cycle_ms": self.cycle * 1000,
                "exchanges": self.exchanges, "working_counter": self.last_wkc, "requests": self.requests,
                "pid": os.getpid(), "socket": str(self.path)}

    def count(self, result: tuple[int, int]) -> tuple[int, int]:
        """Note one exchange's (working counter, expected)."""
        self.exchanges += 1
        self.last_wkc, self.last_expected = result
        return result

    def _cycling(self) -> None:
        """Process data every cycle once mapped: the SM watchdog of slaves in SAFEOP/OP stays fed."""
        next_t = time.monotonic()
        while not self._stop.is_set():
            if self.mapped:
                with self._lock:
                    try:
                        self.count(self.backend.exchange())
                    except (GatewaylabError, OSError):
                        pass      # a lost frame or an unplugged line: the next cycle tries again
            next_t += self.cycle
            self._stop.wait(max(0.0, next_t - time.monotonic()))
            if time.monotonic() - next_t > 1.0:
                next_t = time.monotonic()     # suspended or overloaded: no burst of late cycles

    def _answer(self, request: dict[str, Any]) -> dict[str, Any]:
        if request.get("stop"):
            self._stop.set()
            return {"ok": True}
        if request.get("info"):
            return self.info()
        verb, args = request.get("verb"), request.get("args")
        if not isinstance(verb, str) or not isinstance(args, dict):
            return {"code": 2, "stdout": "", "stderr": "a request is {\"verb\": NAME, \"args\": {...}}\n"}
        with self._lock:
            self.requests += 1
            code, out, err = self.run_verb(self._proxy, verb, args)
        return {"code": code, "stdout": out, "stderr": err}

    def _serve_one(self, conn: socket.socket) -> None:
        with conn, conn.makefile("rwb") as f:
            line = f.readline(MAX_REQUEST)
            try:
                request = json.loads(line)
                answer = self._answer(request) if isinstance(request, dict) else {"code": 2, "stderr": "not JSON"}
            except ValueError as exc:
                answer = {"code": 2, "stdout": "", "stderr": f"not a JSON request: {exc}\n"}
            f.write(json.dumps(answer).encode() + b"\n")
            f.flush()

    def serve(self, ready: Callable[[], None] | None = None) -> None:
        """Serve until a ``stop`` request (or KeyboardInterrupt / SystemExit from a signal handler)."""
        cycler = threading.Thread(target=self._cycling, name="gatewaylab-ec-cycle", daemon=True)
        cycler.start()
        if ready is not None:
            ready()
        try:
            while not self._stop.is_set():
                try:
                    conn, _ = self._sock.accept()
                except TimeoutError:
                    continue
                conn.settimeout(None)
                try:
                    self._serve_one(conn)
                except OSError:
                    pass          # the client went away mid-request
        finally:
            self._stop.set()
            cycler.join(2)
            self._sock.close()
            remove_unix(self.path, self._bound)


def _alive(path: Path) -> bool:
    """Whether something accepts connections on the socket ``path`` (a stale file does not)."""
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    probe.settimeout(1.0)
    try:
        probe.connect(str(path))
        return True
    except OSError:
        return False
    finally:
        probe.close()


def request(path: str, message: dict[str, Any], timeout: float = 600.0) -> dict[str, Any]:
    """Send one request to the master at ``path``; its answer (GatewaylabError when it is not there)."""
    try:
        line = ask(path, message, timeout)
    except FileNotFoundError:          # a path that does not exist is the user's to fix (docs/cli.md: exit 2)
        raise EcUsage(f"{path}: no master serving there (start one: gatewaylab ec master --serve {path} "
                      "-i IFNAME)") from None
    except OSError as exc:
        raise GatewaylabError(f"{path}: cannot reach the master: {exc.strerror or exc}") from None
    if not line:
        raise GatewaylabError(f"{path}: the master closed the connection without an answer")
    answer: dict[str, Any] = json.loads(line)
    return answer
