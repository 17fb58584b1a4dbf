"""I/O adapters that carry the IDX USB byte stream: a pseudo-terminal and a TCP server."""

from gatewaylab.devices.maxon_idx.transport.base import Channel, ChannelFactory, Reactor
from gatewaylab.devices.maxon_idx.transport.pty import PtyPort
from gatewaylab.devices.maxon_idx.transport.tcp import TcpServer

__all__ = ["Channel", "ChannelFactory", "PtyPort", "Reactor", "TcpServer"]
