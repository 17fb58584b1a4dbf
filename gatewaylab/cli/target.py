"""What a client command names -- a ready file, a bus endpoint -- opened with the exit codes of docs/cli.md.

One rule for every command: what the user typed wrong, or a file, socket or device path that does not
exist, is a :class:`~gatewaylab.common.endpoint.EndpointError` (a ConfigError: exit 2); a peer that is
there but does not accept, answer or agree is :class:`Unreachable` (exit 1: it happened at run time).
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any

from gatewaylab.common.endpoint import EndpointError, EndpointKind, bus_endpoint, parse_endpoint
from gatewaylab.common.errors import ConfigError, GatewaylabError

if TYPE_CHECKING:
    import can

__all__ = ["USAGE", "Unreachable", "bus_target", "exit_code", "open_bus", "open_endpoint"]

#: The exit code of a usage error (the command line or a file it names); 1 is for run-time failures.
USAGE = 2


class Unreachable(GatewaylabError):
    """The endpoint exists (or is a TCP address) but nothing accepted or answered there (exit 1)."""


def exit_code(exc: BaseException) -> int:
    """docs/cli.md's table for an error a command reports: 2 for the user's to fix, else 1."""
    return USAGE if isinstance(exc, ConfigError) else 1


def bus_target(target: str, bus: str = "can0") -> str:
    """The endpoint of ``bus`` in ``target`` (a ready file or an endpoint), checked: malformed, not a bus
    endpoint, no such ready file or no such socket file are EndpointErrors (exit 2)."""
    endpoint = bus_endpoint(target, bus)
    ep = parse_endpoint(endpoint, bare_path=EndpointKind.UNIX)
    if ep.kind not in (EndpointKind.UNIX, EndpointKind.TCP):
        raise EndpointError(f"{endpoint}: not a bus endpoint (unix:PATH or tcp:HOST:PORT, or a ready file)")
    if ep.kind is EndpointKind.UNIX and not os.path.exists(ep.path):
        raise EndpointError(f"{endpoint}: no such socket (is the rig running? its banner and ready file "
                            f"list the endpoints)")
    return endpoint


def open_endpoint(endpoint: str, **kwargs: Any) -> can.BusABC:
    """``can.Bus(interface="gatewaylab", channel=endpoint, **kwargs)``; Unreachable (exit 1) when it fails."""
    import can

    try:
        return can.Bus(interface="gatewaylab", channel=endpoint, **kwargs)
    except (can.CanError, OSError) as exc:
        raise Unreachable(f"cannot open bus {endpoint}: {exc}") from None


def open_bus(target: str, bus: str = "can0", **kwargs: Any) -> can.BusABC:
    """:func:`bus_target` then :func:`open_endpoint`."""
    return open_endpoint(bus_target(target, bus), **kwargs)
