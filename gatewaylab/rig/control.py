"""The control endpoint of a running rig: one JSON request per line in, one JSON answer per line out.

A Unix socket ``gatewaylab-control.sock`` in the rig's state folder (127.0.0.1 TCP when the rig's buses use
TCP endpoints), listed in the ready file as ``"control"``. Served from the rig's own select loop
(``rig.add_reader``), so every request runs on the rig thread holding ``clock.lock``, between
frames, like any other client's. Answers: ``{"ok": true, ...}`` or ``{"ok": false, "error": "..."}``;
nothing a client sends (garbage, half lines, huge lines, vanishing) stops the rig. docs/faults.md.
"""

from __future__ import annotations

import contextlib
import json
import logging
import socket
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Protocol

from gatewaylab.bus.transport.outbox import receive
from gatewaylab.bus.transport.unix_file import Identity, bind_unix, remove_unix
from gatewaylab.common.endpoint import format_tcp, format_unix
from gatewaylab.common.errors import GatewaylabError

__all__ = ["MAX_LINE", "ControlServer", "Handler", "Reactor", "answer_line"]


log = logging.getLogger(__name__)

#: A request line longer than this is refused and skipped to its end (a request is tiny).
MAX_LINE = 64 * 1024


class Reactor(Protocol):
    """The rig's select loop as the server sees it: the server never blocks and owns no thread."""

    def add_reader(self, fd: int, callback: Callable[[], None]) -> None:
        """Call ``callback`` on the rig thread whenever ``fd`` is readable."""

    def remove_reader(self, fd: int) -> None:
        """Stop watching ``fd`` (before it is closed)."""


Handler = Callable[[Mapping[str, Any]], dict[str, Any]]


def answer_line(handler: Handler, line: bytes) -> bytes:
    """The answer to one request line (sans-I/O: what the server writes back, newline included)."""
    try:
        req = json.loads(line.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        return _encode({"ok": False, "error": f"not a JSON object: {exc}"})
    if not isinstance(req, dict):
        return _encode({"ok": False, "error": "a request is one JSON object per line"})
    try:
        result = handler(req)
    except GatewaylabError as exc:
        return _encode({"ok": False, "error": " ".join(str(exc).split())})
    except Exception as exc:   # a device that failed on the request: answered and logged, the rig goes on
        log.exception("control request %r failed", req)
        return _encode({"ok": False, "error": f"{type(exc).__name__}: {exc}"})
    return _encode({"ok": True, **result})


def _encode(obj: dict[str, Any]) -> bytes:
    return json.dumps(obj, separators=(",", ":")).encode() + b"\n"


class _Connection:
    """One client: its unanswered partial line, and whether the rest of an over-long one is being skipped."""

    def __init__(self, server: ControlServer, sock: socket.socket) -> None:
        self.server = server
        self.sock = sock
        self.fd = sock.fileno()
        self.buf = bytearray()
        self.skipping = False
        self.closed = False

    def on_readable(self) -> None:
        data = receive(self.sock)
        if data is None:
            return
        if data and not isinstance(data, OSError):    # a reset connection ends as a closed one
            self._feed(data)
        else:
            self.close()

    def _feed(self, data: bytes) -> None:
        """Answer every whole request line received so far; keep the rest for the next read."""
        self.buf += data
        while not self.closed:
            end = self.buf.find(b"\n")
            if self.skipping:        # the rest of an over-long line: dropped up to its end
                if end < 0:
                    self.buf.clear()
                    return
                del self.buf[:end + 1]
                self.skipping = False
                continue
            if end < 0:
                if len(self.buf) > MAX_LINE:
                    self._write(_encode({"ok": False, "error": f"request line longer than {MAX_LINE} bytes"}))
                    self.buf.clear()
                    self.skipping = True
                return
            line = bytes(self.buf[:end])
            del self.buf[:end + 1]
            if line.strip():
                self.server.requests += 1
                self._write(answer_line(self.server.handler, line))

    def _write(self, data: bytes) -> None:
        """Non-blocking: answers are small and the socket buffer holds hundreds of them; a client
        that lets them pile up until the buffer is full is disconnected (the rig never waits)."""
        try:
            sent = self.sock.send(data)
        except OSError:
            sent = -1
        if sent != len(data):
            log.warning("control client does not read its answers: disconnected")
            self.close()

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self.server.reactor.remove_reader(self.fd)
        with contextlib.suppress(OSError):
            self.sock.close()
        self.server.connections.discard(self)


class ControlServer:
    """Listens on ``unix_path`` or on 127.0.0.1:``tcp_port``; each line goes to ``handler``."""

    def __init__(self, reactor: Reactor, handler: Handler, *, unix_path: Path | None = None,
                 tcp_port: int | None = None) -> None:
        self.reactor = reactor
        self.handler = handler
        self.connections: set[_Connection] = set()
        self.requests = 0
        self.unix_path = unix_path
        #: the socket file bound (device, inode): removed at close only while it is still that file
        self._bound: Identity = (0, 0)
        if unix_path is not None:
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            try:
                self._bound = bind_unix(sock, unix_path)
            except OSError:
                sock.close()
                raise
            self.endpoint = format_unix(unix_path)
        else:
            sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            try:
                sock.bind(("127.0.0.1", tcp_port or 0))
            except OSError:
                sock.close()
                raise
            self.endpoint = format_tcp("127.0.0.1", sock.getsockname()[1])
        sock.listen(8)
        sock.setblocking(False)
        self.listener = sock
        reactor.add_reader(sock.fileno(), self._accept)

    def _accept(self) -> None:
        try:
            sock, _ = self.listener.accept()
        except (BlockingIOError, OSError):
            return
        sock.setblocking(False)
        conn = _Connection(self, sock)
        self.connections.add(conn)
        self.reactor.add_reader(conn.fd, conn.on_readable)

    def close(self) -> None:
        """Stop listening, drop every client and remove the socket file (the rig stops)."""
        self.reactor.remove_reader(self.listener.fileno())
        with contextlib.suppress(OSError):
            self.listener.close()
        for conn in list(self.connections):
            conn.close()
        if self.unix_path is not None:
            remove_unix(self.unix_path, self._bound)
