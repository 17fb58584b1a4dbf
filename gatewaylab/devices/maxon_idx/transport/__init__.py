"""I/O adapters that carry the IDX USB byte stream: a pseudo-terminal and a TCP server."""

from .base import Channel, ChannelFactory, Reactor
from .pty import PtyPort
from .tcp import TcpServer

__all__ = ["Channel", "ChannelFactory", "PtyPort", "Reactor", "TcpServer"]
