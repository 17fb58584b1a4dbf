"""A ``socketserver`` server served in a daemon thread that stops at once.

``serve_forever`` notices ``shutdown()`` only at its next poll (0.5 s by default), and a rig stops its
web servers one after the other: with two of them SIGTERM would take a second. Here
the thread waits in ``select`` on the listening socket and a wake-up socket, so :meth:`ServerThread.stop`
ends it within the time one accept takes, and an idle server never wakes up.
"""

from __future__ import annotations

import select
import socket
import socketserver
import threading

__all__ = ["ServerThread"]


class ServerThread:
    """Serve ``server`` (its ``handle_request``) in a daemon thread named ``name`` until :meth:`stop`."""

    def __init__(self, server: socketserver.TCPServer, name: str) -> None:
        self.server = server
        self._wake_r, self._wake_w = socket.socketpair()
        self._stopping = False
        self._thread = threading.Thread(target=self._serve, name=name, daemon=True)

    def start(self) -> None:
        """Start serving in the thread (stop() wakes and joins it)."""
        self._thread.start()

    def _serve(self) -> None:
        server = self.server
        # handle_request() after select said ready: the accept never waits (timeout 0 if it was spurious)
        server.timeout = 0
        listener, wake = server.fileno(), self._wake_r.fileno()
        while not self._stopping:
            try:
                ready, _, _ = select.select([listener, wake], [], [])
            except (OSError, ValueError):   # the listening socket was closed under us
                return
            if self._stopping:
                return
            if listener in ready:
                server.handle_request()
            server.service_actions()

    def stop(self, timeout: float = 1.0) -> None:
        """Wake the thread and wait (at most ``timeout``) until it ended; idempotent. The server's
        socket stays open (``server_close()`` is the caller's)."""
        self._stopping = True
        try:
            self._wake_w.send(b"\0")
        except OSError:
            pass
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout)
        self._wake_r.close()
        self._wake_w.close()
