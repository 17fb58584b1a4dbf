"""The client side of the line-JSON control sockets (a rig's control endpoint, a persistent
``gatewaylab ec`` master): connect, send one request, read one answer line, close."""

from __future__ import annotations

import json
import socket
from typing import Any

from gatewaylab.common.endpoint import Endpoint, EndpointKind

__all__ = ["Address", "ask", "endpoint_address"]


#: A Unix socket path, or a (host, port) of a TCP endpoint.
Address = str | tuple[str, int]


def endpoint_address(endpoint: Endpoint) -> Address:
    """Where :func:`ask` connects for an endpoint: its path (unix) or its (host, port) (tcp)."""
    if endpoint.kind is EndpointKind.UNIX:
        return endpoint.path
    return endpoint.host, endpoint.port


def ask(address: Address, message: dict[str, Any], timeout: float) -> bytes:
    """Send ``message`` as one JSON line and return the one line that comes back (b"" when the peer
    closed without answering); the socket is closed after. OSError when the peer cannot be reached."""
    if isinstance(address, str):
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.settimeout(timeout)
        try:
            sock.connect(address)
        except BaseException:
            sock.close()
            raise
    else:
        sock = socket.create_connection(address, timeout=timeout)
    with sock, sock.makefile("rwb") as f:
        f.write(json.dumps(message).encode() + b"\n")
        f.flush()
        return f.readline()
