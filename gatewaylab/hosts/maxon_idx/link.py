"""Byte links from a host to an IDX: pyserial (virtual port, socket URL, real port) and pyusb."""

from __future__ import annotations

from typing import Any, Protocol

from gatewaylab.common.endpoint import EndpointKind, parse_endpoint
from gatewaylab.common.errors import ConfigError

__all__ = ["USB_IDS", "Link", "SerialLink", "UsbLink", "open_link"]


#: USB identities seen in public udev rules (not a maxon document; untested without hardware):
#: EPOS2 enumerates as an FTDI chip 0403:A8B0; EPOS4/IDX as 24E7:3B01 (maxon's vendor id 0x24E7).
USB_IDS: tuple[tuple[int, int], ...] = ((0x24E7, 0x3B01), (0x0403, 0xA8B0))


class Link(Protocol):
    """What :class:`~.client.IdxClient` needs of a byte link, so serial, socket and USB ports are interchangeable."""

    def write(self, data: bytes) -> None:
        """Send the bytes of a stuffed frame to the device."""
        ...

    def read(self, size: int, timeout: float) -> bytes:
        """Up to ``size`` bytes; may return fewer (or none) once ``timeout`` seconds passed."""
        ...

    def reset_input(self) -> None:
        """Drop bytes received but not read yet, e.g. a late reply after a client timeout."""
        ...

    def close(self) -> None:
        """Release the port or device."""
        ...


class SerialLink:
    """pyserial: ``/dev/pts/N``, ``/dev/ttyACM0``, ``socket://127.0.0.1:PORT``, ``rfc2217://...``."""

    def __init__(self, url: str, baudrate: int = 1_000_000) -> None:
        import serial

        self.url = url
        self.port: Any = serial.serial_for_url(url, baudrate=baudrate, timeout=0.1)

    def write(self, data: bytes) -> None:
        """Write and flush, so the request is out before the client starts timing its reply."""
        self.port.write(data)
        self.port.flush()

    def read(self, size: int, timeout: float) -> bytes:
        """What is waiting (at least one byte, or none at the timeout), so the decoder sees bytes as they arrive."""
        self.port.timeout = max(timeout, 0.0)
        waiting = self.port.in_waiting
        data: bytes = self.port.read(max(1, min(size, waiting)) if waiting else 1)
        return data

    def reset_input(self) -> None:
        """Drop pyserial's input buffer (a late reply after a client timeout)."""
        self.port.reset_input_buffer()

    def close(self) -> None:
        """Close the serial port or socket."""
        self.port.close()


class UsbLink:
    """pyusb bulk endpoints of a real IDX/EPOS4 (maxon's USB driver is a vendor-class device).

    Untested against hardware: no device was available. The first bulk OUT and IN endpoints of
    the first interface carry the same stuffed frames as the serial port. ``backend`` is any pyusb
    backend, e.g. :class:`~.usb_backend.IdxUsbBackend` (the emulated IDX over USB; None: pyusb's
    default, libusb).
    """

    def __init__(self, vendor: int | None = None, product: int | None = None, backend: Any = None) -> None:
        import usb.core
        import usb.util

        ids = [(vendor, product)] if vendor is not None and product is not None else list(USB_IDS)
        dev: Any = None
        for vid, pid in ids:
            try:
                dev = usb.core.find(idVendor=vid, idProduct=pid, backend=backend)
            except usb.core.NoBackendError as exc:
                raise ConfigError("pyusb found no USB backend: install libusb-1.0") from exc
            if dev is not None:
                break
        if dev is None:
            looked = ", ".join(f"{v:04X}:{p:04X}" for v, p in ids)
            raise ConfigError(f"no maxon USB device found (looked for {looked})")
        dev.set_configuration()
        intf = dev.get_active_configuration()[(0, 0)]

        def direction(wanted: int) -> Any:
            return usb.util.find_descriptor(
                intf, custom_match=lambda e: usb.util.endpoint_direction(e.bEndpointAddress) == wanted)

        self.dev = dev
        self.ep_out = direction(usb.util.ENDPOINT_OUT)
        self.ep_in = direction(usb.util.ENDPOINT_IN)
        if self.ep_out is None or self.ep_in is None:
            raise ConfigError("the USB device has no bulk IN/OUT endpoint pair")

    def write(self, data: bytes) -> None:
        """Send stuffed frame bytes on the bulk OUT endpoint."""
        self.ep_out.write(data)

    def read(self, size: int, timeout: float) -> bytes:
        """One bulk IN transfer; no bytes when ``timeout`` expires, as :class:`Link` allows."""
        import usb.core

        try:
            return bytes(self.ep_in.read(max(size, self.ep_in.wMaxPacketSize), int(timeout * 1000) or 1))
        except usb.core.USBTimeoutError:
            return b""

    def reset_input(self) -> None:
        """Nothing to drop: pyusb keeps no input buffer between reads."""
        pass

    def close(self) -> None:
        """Release the device's interface and handles so another program can open it."""
        import usb.util

        usb.util.dispose_resources(self.dev)


def open_link(port: str) -> Link:
    """Any endpoint of :mod:`gatewaylab.common.endpoint`: ``usb`` / ``usb:VID:PID`` -> pyusb;
    ``tcp:HOST:PORT`` (or ``socket://HOST:PORT``, ``HOST:PORT``), a serial device or another
    pyserial URL -> pyserial."""
    ep = parse_endpoint(port, bare_path=EndpointKind.SERIAL)
    if ep.kind is EndpointKind.USB:
        return UsbLink(ep.vendor, ep.product)
    if ep.kind is EndpointKind.UNIX:
        raise ConfigError(f"{port}: an IDX has no Unix-socket port (use its pty, tcp:HOST:PORT or usb)")
    return SerialLink(ep.pyserial_url())
