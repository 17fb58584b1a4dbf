"""A TCP server on 127.0.0.1 that pyserial opens as ``socket://127.0.0.1:PORT``.

Each connection gets its own protocol channel (decoder and segmented-transfer state); all of
them share the device's object dictionary and CAN gateway.
"""

from __future__ import annotations

import socket

from gatewaylab.common.clock import Clock
from gatewaylab.devices.maxon_idx.transport.base import Channel, ChannelFactory, Reactor, ReplyWriter

__all__ = ["TcpServer"]


class _Connection(ReplyWriter):
    def __init__(self, server: TcpServer, sock: socket.socket) -> None:
        super().__init__(server.clock, server.latency)
        self.server = server
        self.sock = sock
        self.fd = sock.fileno()
        self.channel: Channel = server.make_channel(self.send)

    def _write_now(self, data: bytearray) -> int:
        return self.sock.send(data)

    def _write_failed(self) -> None:
        self.close()

    def on_readable(self) -> None:
        if self._backlog:
            self._flush()
        try:
            data = self.sock.recv(4096)
        except BlockingIOError:
            return
        except OSError:
            data = b""
        if not data:
            self.close()
            return
        self.channel.receive(data)

    @property
    def closed(self) -> bool:
        return self._closed

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self.server.reactor.remove_reader(self.fd)
        self.channel.close()
        self.sock.close()
        self.server.connections.discard(self)


class TcpServer:
    """Listens on ``host:port`` (port 0 = a free one; see :attr:`port`)."""

    def __init__(self, reactor: Reactor, clock: Clock, make_channel: ChannelFactory, port: int = 0,
                 host: str = "127.0.0.1", latency: float = 0.0) -> None:
        self.reactor = reactor
        self.clock = clock
        self.make_channel = make_channel
        self.latency = latency
        self.connections: set[_Connection] = set()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind((host, port))
        self.sock.listen(4)
        self.sock.setblocking(False)
        self.host, self.port = self.sock.getsockname()[:2]
        reactor.add_reader(self.sock.fileno(), self._accept)

    @property
    def url(self) -> str:
        """The pyserial URL a host opens (``socket://host:port``)."""
        return f"socket://{self.host}:{self.port}"

    @property
    def address(self) -> str:
        """``host:port`` as the ready file lists it."""
        return f"{self.host}:{self.port}"

    def _accept(self) -> None:
        try:
            sock, _ = self.sock.accept()
        except BlockingIOError:
            return
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        conn = _Connection(self, sock)
        self.connections.add(conn)
        self.reactor.add_reader(conn.fd, conn.on_readable)

    def close(self) -> None:
        """Close every connection and the listening socket."""
        for conn in list(self.connections):
            conn.close()
        self.reactor.remove_reader(self.sock.fileno())
        self.sock.close()
