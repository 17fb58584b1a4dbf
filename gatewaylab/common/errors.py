"""One error base for the whole emulator.

Errors are split by *who* misbehaved, because the boundary that turns them into wire codes
(SDO abort codes, AL status codes, maxon error codes, ECAN-Lite LastPDOError) treats them
differently: local misuse is a bug in the caller's code and is raised to it; remote
misbehaviour is answered on the wire with the spec's code and counted, never crashes a device.
"""

from __future__ import annotations

__all__ = [
    "ConfigError", "FrameError", "GatewaylabError", "LocalError", "ProtocolError", "RemoteError", "TimeoutError_",
]


class GatewaylabError(Exception):
    """Base of every error raised by gatewaylab."""

    #: A protocol-specific wire code (SDO abort code, AL status code, ...) or None.
    code: int | None = None

    def __init__(self, message: str, code: int | None = None) -> None:
        super().__init__(message)
        if code is not None:
            self.code = code


class LocalError(GatewaylabError):
    """The API was misused by local code (bad argument, wrong state); a bug to fix at the caller."""


class RemoteError(GatewaylabError):
    """A peer sent something the spec forbids; answered with ``code`` on the wire and counted."""


class FrameError(LocalError, ValueError):
    """A CAN frame that cannot exist on the bus (DLC > 8 on classic CAN, id out of range, ...)."""


class ConfigError(LocalError):
    """A rig file or a constructor argument describes something impossible."""


class ProtocolError(RemoteError):
    """Malformed bytes or frames received from a peer."""


class TimeoutError_(RemoteError):
    """A peer did not answer in time (named with a trailing underscore to not shadow the builtin)."""
