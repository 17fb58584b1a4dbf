"""Client sockets of the servers in the rig loop (server.py, socketcand.py): accepting them, and
non-blocking writes to each.

What the socket does not take at once waits here and goes out when the reactor says the socket is
writable; a client that lets more than ``limit`` bytes pile up is reported (``on_overflow``) so its
server can disconnect it; a failing send is reported (``on_error``) instead of raised into the loop.
"""

from __future__ import annotations

import socket
from collections.abc import Callable
from typing import Protocol, TypeVar

__all__ = ["Client", "ClientReactor", "Outbox", "WriterReactor", "accept", "accept_client", "receive"]


def accept(listener: socket.socket, index: int) -> tuple[socket.socket, str] | None:
    """The next waiting connection, non-blocking (TCP_NODELAY on TCP), with a name for logs
    (``HOST:PORT``, or ``unix-clientN`` with ``index``); None when none waits."""
    try:
        sock, addr = listener.accept()
    except BlockingIOError:
        return None
    sock.setblocking(False)
    if sock.family in (socket.AF_INET, socket.AF_INET6):
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return sock, f"{addr[0]}:{addr[1]}" if isinstance(addr, tuple) else f"unix-client{index}"


class WriterReactor(Protocol):
    """The part of the rig's reactor an outbox uses: wake me when the socket can take bytes."""

    def add_writer(self, fd: int, callback: Callable[[], None]) -> None:
        """Call ``callback`` when ``fd`` is writable."""

    def remove_writer(self, fd: int) -> None:
        """Stop watching ``fd`` for writability."""


class ClientReactor(WriterReactor, Protocol):
    """The reactor a server with clients uses: readers and writers."""

    def add_reader(self, fd: int, callback: Callable[[], None]) -> None:
        """Call ``callback`` when ``fd`` is readable."""


class Client(Protocol):
    """A connected client of a server: its socket and what to do when it has bytes."""
    sock: socket.socket

    def readable(self) -> None:
        """Read what the client sent (the reactor saw its socket readable)."""


def receive(sock: socket.socket, size: int = 65536) -> bytes | OSError | None:
    """What a socket the reactor saw readable holds: its bytes (``b""``: the peer closed), None when there
    is nothing after all (a spurious wake-up), or the OSError the receive failed with (the peer is gone)."""
    try:
        return sock.recv(size)
    except BlockingIOError:
        return None
    except OSError as exc:
        return exc


C = TypeVar("C", bound=Client)


def accept_client(listener: socket.socket, clients: list[C], make: Callable[[socket.socket, str], C],
                  reactor: ClientReactor) -> C | None:
    """Accept the next connection (:func:`accept`), make its client, list it and read from it."""
    accepted = accept(listener, len(clients))
    if accepted is None:
        return None
    client = make(*accepted)
    clients.append(client)
    reactor.add_reader(client.sock.fileno(), client.readable)
    return client


class Outbox:
    """The unsent bytes of one socket and its registration as a writer."""

    def __init__(self, sock: socket.socket, reactor: WriterReactor, limit: int,
                 on_error: Callable[[OSError], None], on_overflow: Callable[[int], None]) -> None:
        self.sock = sock
        self.reactor = reactor
        self.limit = limit
        self.on_error = on_error
        self.on_overflow = on_overflow
        self.out = bytearray()
        self.writing = False

    def write(self, data: bytes) -> None:
        """Send ``data`` now, or queue it behind bytes the socket did not take yet."""
        if self.out:
            self.out += data
        else:
            try:
                sent = self.sock.send(data)
            except BlockingIOError:
                sent = 0
            except OSError as exc:
                self.on_error(exc)
                return
            if sent < len(data):
                self.out += data[sent:]
        if self.out:
            if len(self.out) > self.limit:
                self.on_overflow(len(self.out))
                return
            if not self.writing:
                self.writing = True
                self.reactor.add_writer(self.sock.fileno(), self.flush)

    def flush(self) -> None:
        """Send queued bytes (the socket became writable); stop watching once empty."""
        try:
            sent = self.sock.send(self.out)
        except BlockingIOError:
            return
        except OSError as exc:
            self.on_error(exc)
            return
        del self.out[:sent]
        if not self.out and self.writing:
            self.writing = False
            self.reactor.remove_writer(self.sock.fileno())

    def close(self) -> None:
        """Forget what is unsent and stop waiting for the socket (before it is closed)."""
        self.out.clear()
        if self.writing:
            self.writing = False
            self.reactor.remove_writer(self.sock.fileno())
