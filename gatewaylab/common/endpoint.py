"""One endpoint syntax for every client: ``unix:PATH``, ``tcp:HOST:PORT``, a serial device, ``usb``.

What ``gatewaylab run`` prints and writes into its ready file is accepted by every client: the
python-can interface, ``IdxClient`` and ``gatewaylab idx``. The canonical forms are

* ``unix:PATH`` -- a Unix socket (a bus of a running rig);
* ``tcp:HOST:PORT`` -- a TCP port (``HOST`` is an IPv4 address, a name or ``[IPv6]``);
* ``/dev/...`` -- a serial device (an IDX's virtual or real USB port);
* ``usb`` or ``usb:VID:PID`` -- a real maxon device through pyusb.

Aliases accepted everywhere: ``socket://HOST:PORT`` (pyserial's URL) and a bare ``HOST:PORT``
mean ``tcp:HOST:PORT``; a bare absolute path means whatever the client connects to by path
(a Unix socket for a bus, a serial device for an IDX). See docs/endpoints.md.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from enum import Enum
from pathlib import Path

from gatewaylab.common.errors import ConfigError

__all__ = ["Endpoint", "EndpointError", "EndpointKind", "bus_endpoint", "format_tcp", "format_unix", "parse_endpoint"]


class EndpointKind(Enum):
    """Which transport an :class:`Endpoint` names, so each client knows how to open it (docs/endpoints.md)."""

    UNIX = "unix"
    TCP = "tcp"
    SERIAL = "serial"
    USB = "usb"
    URL = "url"          # another pyserial URL (rfc2217://, loop://, ...), handed to pyserial as is


class EndpointError(ConfigError, ValueError):
    """Text that is not an endpoint in any accepted form."""


@dataclass(frozen=True, slots=True)
class Endpoint:
    """A parsed endpoint; ``str()`` gives its canonical form."""

    kind: EndpointKind
    path: str = ""            # UNIX, SERIAL; URL: the whole URL
    host: str = ""            # TCP (IPv6 without brackets)
    port: int = 0             # TCP
    vendor: int | None = None  # USB
    product: int | None = None

    def __str__(self) -> str:
        if self.kind is EndpointKind.UNIX:
            return f"unix:{self.path}"
        if self.kind is EndpointKind.TCP:
            return format_tcp(self.host, self.port)
        if self.kind is EndpointKind.USB:
            return "usb" if self.vendor is None else f"usb:{self.vendor:04X}:{self.product or 0:04X}"
        return self.path

    @property
    def is_local(self) -> bool:
        """A TCP endpoint on this host (rig endpoints bind to 127.0.0.1 only)."""
        return self.kind is not EndpointKind.TCP or self.host in ("127.0.0.1", "localhost", "::1")

    def pyserial_url(self) -> str:
        """What ``serial.serial_for_url`` opens for this endpoint (TCP, serial devices, URLs)."""
        if self.kind is EndpointKind.TCP:
            host = f"[{self.host}]" if ":" in self.host else self.host
            return f"socket://{host}:{self.port}"
        if self.kind in (EndpointKind.SERIAL, EndpointKind.URL):
            return self.path
        raise EndpointError(f"{self} is not a serial port or a TCP endpoint")


def format_tcp(host: str, port: int) -> str:
    """The canonical ``tcp:HOST:PORT`` (IPv6 hosts in brackets)."""
    return f"tcp:[{host}]:{port}" if ":" in host else f"tcp:{host}:{port}"


def format_unix(path: object) -> str:
    """The canonical ``unix:PATH`` form of a Unix-socket path (what ``str()`` gives for a UNIX endpoint)."""
    return f"unix:{path}"


def _host_port(text: str, original: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not host:
        raise EndpointError(f"endpoint {original!r}: expected HOST:PORT")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    try:
        number = int(port, 10)
    except ValueError:
        raise EndpointError(f"endpoint {original!r}: port {port!r} is not a number") from None
    if not 0 < number <= 65535:
        raise EndpointError(f"endpoint {original!r}: port {number} outside 1..65535")
    return host, number


def _looks_like_host_port(text: str) -> bool:
    host, sep, port = text.rpartition(":")
    return bool(sep and host and port.isdigit() and "/" not in text)


def parse_endpoint(text: str, *, bare_path: EndpointKind = EndpointKind.SERIAL) -> Endpoint:
    """Parse any accepted form; ``bare_path`` says what a path without ``unix:`` means."""
    if not isinstance(text, str) or not text.strip():
        raise EndpointError("empty endpoint (expected unix:PATH, tcp:HOST:PORT, /dev/... or usb)")
    text = text.strip()
    lower = text.lower()
    if lower.startswith("unix:"):
        path = text[5:]
        if path.startswith("//"):          # unix:///path, URL style
            path = path[2:]
        if not path:
            raise EndpointError(f"endpoint {text!r}: unix: needs a path")
        return Endpoint(EndpointKind.UNIX, path=path)
    if lower.startswith("tcp://") or lower.startswith("socket://"):
        host, port = _host_port(text.split("://", 1)[1].rstrip("/"), text)
        return Endpoint(EndpointKind.TCP, host=host, port=port)
    if lower.startswith("tcp:"):
        host, port = _host_port(text[4:], text)
        return Endpoint(EndpointKind.TCP, host=host, port=port)
    if lower == "usb" or lower.startswith("usb:"):
        parts = text.split(":")
        if len(parts) == 1:
            return Endpoint(EndpointKind.USB)
        if len(parts) != 3:
            raise EndpointError(f"endpoint {text!r}: expected usb or usb:VID:PID (hex)")
        try:
            return Endpoint(EndpointKind.USB, vendor=int(parts[1], 16), product=int(parts[2], 16))
        except ValueError:
            raise EndpointError(f"endpoint {text!r}: VID and PID are hex numbers") from None
    if "://" in text:
        return Endpoint(EndpointKind.URL, path=text)
    if text.startswith("/") or text.startswith("."):
        return Endpoint(bare_path, path=text)
    if _looks_like_host_port(text):
        host, port = _host_port(text, text)
        return Endpoint(EndpointKind.TCP, host=host, port=port)
    if bare_path is EndpointKind.SERIAL:          # COM3, ttyUSB0 relative names
        return Endpoint(EndpointKind.SERIAL, path=text)
    raise EndpointError(f"endpoint {text!r}: expected unix:PATH or tcp:HOST:PORT")


def bus_endpoint(target: str, bus: str = "can0") -> str:
    """The endpoint of ``bus``: ``target`` itself when it is an endpoint, or the bus's endpoint listed
    in ``target`` when that is a rig's ready file (``gatewaylab run --ready-file``), so tools take
    either what ``gatewaylab run`` printed or the file it wrote."""
    path = Path(target)
    if not path.is_file():
        if not path.exists() and (path.suffix.lower() == ".json" or ":" not in target):
            raise EndpointError(f"{target}: no such ready file or socket (is the rig running? "
                                f"`gatewaylab run --ready-file {target}` writes it)")
        return target
    try:
        info = json.loads(path.read_text())
        return str(info["buses"][bus]["endpoint"])
    except (OSError, ValueError) as exc:
        raise EndpointError(f"{target}: not a ready file ({exc})") from None
    except (KeyError, TypeError):
        raise EndpointError(f"{target}: the ready file lists no bus {bus!r}") from None
