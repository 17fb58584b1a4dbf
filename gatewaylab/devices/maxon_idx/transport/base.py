"""What the IDX transports need from the rig loop and from the protocol side."""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol


class Reactor(Protocol):
    """The rig runtime's file-descriptor interface (callbacks run holding ``clock.lock``)."""

    def add_reader(self, fd: int, callback: Callable[[], None]) -> None: ...

    def remove_reader(self, fd: int) -> None: ...


class Channel(Protocol):
    """One host connection's protocol endpoint (an :class:`~..protocol.IdxSlave`)."""

    def receive(self, data: bytes) -> None: ...

    def close(self) -> None: ...


#: Build a channel whose replies go to the given ``send``.
ChannelFactory = Callable[[Callable[[bytes], None]], Channel]
