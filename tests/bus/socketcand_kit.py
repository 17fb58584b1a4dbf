"""A plain TCP socketcand client for tests: what a tool other than python-can sends and sees."""

from __future__ import annotations

import socket
import time


class RawClient:
    """One socketcand connection; :meth:`expect` reads until a text arrived (socket timeouts, no sleeps)."""

    def __init__(self, port: int, *, rcvbuf: int | None = None) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        if rcvbuf is not None:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
        self.sock.settimeout(10.0)
        self.sock.connect(("127.0.0.1", port))
        self.buf = b""

    def send(self, text: bytes) -> None:
        self.sock.sendall(text)

    def expect(self, text: bytes, timeout: float = 10.0) -> bytes:
        """Everything up to and including the first ``text``; AssertionError if it does not come."""
        deadline = time.monotonic() + timeout
        while text not in self.buf:
            left = deadline - time.monotonic()
            assert left > 0, f"{text!r} not received; got {self.buf[-300:]!r}"
            self.sock.settimeout(left)
            chunk = self.sock.recv(65536)
            assert chunk, f"connection closed before {text!r}; got {self.buf[-300:]!r}"
            self.buf += chunk
        i = self.buf.index(text) + len(text)
        seen, self.buf = self.buf[:i], self.buf[i:]
        return seen

    def closed_by_peer(self, timeout: float = 10.0) -> bool:
        """Read until the server ends the connection (True) or ``timeout`` passes (False)."""
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            self.sock.settimeout(left)
            try:
                chunk = self.sock.recv(65536)
            except TimeoutError:
                return False
            except ConnectionResetError:
                return True
            if not chunk:
                return True
            self.buf += chunk
        return False

    def open_raw(self, bus: str = "can0", *, fd: bool = False) -> None:
        """Open ``bus`` in RAW mode; ``fd``: ask for CAN FD frames (``< rawmode fd >``)."""
        self.expect(b"< hi >")
        self.send(f"< open {bus} >".encode())
        self.expect(b"< ok >")
        self.send(b"< rawmode fd >" if fd else b"< rawmode >")
        self.expect(b"< ok >")

    def close(self) -> None:
        self.sock.close()
