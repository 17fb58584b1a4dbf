"""What the IDX transports need from the rig loop and from the protocol side."""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

from gatewaylab.common.clock import Clock

__all__ = ["MAX_BACKLOG", "Channel", "ChannelFactory", "Reactor", "ReplyWriter"]


#: Reply bytes kept for a host that does not read them before new ones are dropped.
MAX_BACKLOG = 1 << 16


class Reactor(Protocol):
    """The rig runtime's file-descriptor interface (callbacks run holding ``clock.lock``)."""

    def add_reader(self, fd: int, callback: Callable[[], None]) -> None:
        """Call ``callback`` whenever ``fd`` is readable."""

    def remove_reader(self, fd: int) -> None:
        """Stop watching ``fd``."""


class Channel(Protocol):
    """One host connection's protocol endpoint (an :class:`~..protocol.IdxSlave`)."""

    def receive(self, data: bytes) -> None:
        """Bytes from the host, in any pieces."""

    def close(self) -> None:
        """The host connection ended: drop what is pending."""


#: Build a channel whose replies go to the given ``send``.
ChannelFactory = Callable[[Callable[[bytes], None]], Channel]


class ReplyWriter:
    """Reply bytes to one host: optional USB latency on the clock, then a non-blocking write whose
    unsent rest waits for the next readable event (a host slow to read is not disconnected)."""

    def __init__(self, clock: Clock, latency: float) -> None:
        self.clock = clock
        self.latency = latency
        self.tx_bytes = 0
        self.dropped_bytes = 0
        self._backlog = bytearray()
        self._closed = False

    def _write_now(self, data: bytearray) -> int:
        """Write what the descriptor takes now (raises BlockingIOError / OSError)."""
        raise NotImplementedError

    def _write_failed(self) -> None:
        """The descriptor refused the write for good."""
        self.dropped_bytes += len(self._backlog)
        self._backlog.clear()

    def send(self, data: bytes) -> None:
        """Reply bytes from the protocol, after the optional latency."""
        if self.latency > 0:
            self.clock.call_later(self.latency, self._write, data)
        else:
            self._write(data)

    def _write(self, data: bytes) -> None:
        if self._closed:
            return
        self._backlog += data
        self._flush()

    def _flush(self) -> None:
        while self._backlog:
            try:
                n = self._write_now(self._backlog)
            except BlockingIOError:
                break
            except OSError:
                self._write_failed()
                return
            self.tx_bytes += n
            del self._backlog[:n]
        if len(self._backlog) > MAX_BACKLOG:
            self.dropped_bytes += len(self._backlog)
            self._backlog.clear()
