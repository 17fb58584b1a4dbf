"""A pyusb backend that presents an emulated IDX as a USB device (docs/devices/maxon_idx.md).

pyusb programs reach USB devices through a *backend* (``usb.backend.IBackend``: libusb1, libusb0,
openusb). :class:`IdxUsbBackend` is one more: it enumerates one device per emulated IDX, with
the identity a real EPOS4/IDX shows (24E7:3B01, see :data:`~.link.USB_IDS`), its device,
configuration, interface, endpoint and string descriptors, and two bulk endpoints (0x01 OUT,
0x81 IN) that carry the IDX guide's stuffed frames (chapter 2). So ::

    dev = usb.core.find(idVendor=0x24E7, idProduct=0x3B01, backend=IdxUsbBackend("tcp:127.0.0.1:PORT"))
    dev.set_configuration()
    dev.write(0x01, request_bytes)
    reply = dev.read(0x81, 64, timeout=1000)

and :class:`~.link.UsbLink` (``IdxClient``'s USB path) talk to the emulator unchanged. What
it connects to is either a running rig's IDX (its ``"usb": {"idx1": {"tcp": ...}}`` entry of the
ready file; :meth:`IdxUsbBackend.from_ready_file`) or an in-process
:class:`~..device.IdxDevice` (real-time rig thread or simulated clock).

Errors follow the libusb1 backend's conventions, so callers see what they see with hardware:
a bulk IN that gets nothing within its timeout raises ``usb.core.USBTimeoutError`` (libusb's
LIBUSB_ERROR_TIMEOUT, errno ETIMEDOUT), timeout 0 waits for ever (libusb semantics), an
endpoint the device does not have or an unsupported control request stalls (LIBUSB_ERROR_PIPE),
a device whose rig went away is LIBUSB_ERROR_NO_DEVICE.
"""

from __future__ import annotations

import array
import errno
import json
import socket
import struct
import threading
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import usb.backend
import usb.core
import usb.util

from gatewaylab.common.endpoint import EndpointKind, parse_endpoint
from gatewaylab.common.errors import ConfigError, LocalError
from gatewaylab.hosts.maxon_idx.link import USB_IDS

__all__ = [
    "CONFIGURATION_VALUE",
    "EP_IN",
    "EP_OUT",
    "LANGID_EN_US",
    "MAX_PACKET",
    "ChannelOwner",
    "ConfigurationDescriptor",
    "DeviceDescriptor",
    "DevicePipe",
    "EmulatedDevice",
    "EndpointDescriptor",
    "IdxUsbBackend",
    "InterfaceDescriptor",
    "NoSuchDescriptor",
    "Pipe",
    "TcpPipe",
    "string_descriptor",
]


#: The identity of a real EPOS4/IDX in public udev rules (maxon's vendor id 0x24E7).
IDX_VENDOR_ID, IDX_PRODUCT_ID = USB_IDS[0]
#: Bulk endpoint addresses (USB 2.0 9.6.6: bit 7 = direction IN).
EP_OUT = 0x01
EP_IN = 0x81
#: Full-speed bulk endpoints carry at most 64 bytes per packet (USB 2.0 5.8.3).
MAX_PACKET = 64
CONFIGURATION_VALUE = 1
LANGID_EN_US = 0x0409

# libusb error codes the libusb1 backend raises with (libusb.h), and their texts.
_LIBUSB_ERROR_INVALID_PARAM = -2
_LIBUSB_ERROR_NO_DEVICE = -4
_LIBUSB_ERROR_TIMEOUT = -7
_LIBUSB_ERROR_PIPE = -9

# USB 2.0 9.4 standard requests and 9.4 table 9-5 descriptor types.
_GET_STATUS, _CLEAR_FEATURE, _SET_FEATURE = 0x00, 0x01, 0x03
_GET_DESCRIPTOR, _GET_CONFIGURATION, _SET_CONFIGURATION = 0x06, 0x08, 0x09
_GET_INTERFACE, _SET_INTERFACE = 0x0A, 0x0B
_DT_DEVICE, _DT_CONFIG, _DT_STRING, _DT_INTERFACE, _DT_ENDPOINT = 1, 2, 3, 4, 5

_DEVICE = struct.Struct("<BBHBBBBHHHBBBB")
_CONFIG = struct.Struct("<BBHBBBBB")
_INTERFACE = struct.Struct("<BBBBBBBBB")
_ENDPOINT = struct.Struct("<BBBBHB")
_U16 = struct.Struct("<H")


class NoSuchDescriptor(LocalError, IndexError):
    """A descriptor the IDX does not have (it has one configuration, one interface, two endpoints);
    an IndexError too, as pyusb's backend protocol expects when it walks the descriptors."""


def _error(code: int, text: str, err: int) -> usb.core.USBError:
    return usb.core.USBError(text, code, err)


def _timeout_error() -> usb.core.USBTimeoutError:
    return usb.core.USBTimeoutError("Operation timed out", _LIBUSB_ERROR_TIMEOUT, errno.ETIMEDOUT)


def _stall() -> usb.core.USBError:
    return _error(_LIBUSB_ERROR_PIPE, "Pipe error", errno.EPIPE)


# -- descriptors (USB 2.0 9.6), with the attribute names pyusb reads --------------------------------
@dataclass(frozen=True, slots=True)
class EndpointDescriptor:
    """USB 2.0 9.6.6; ``bmAttributes`` 2 = bulk."""

    bEndpointAddress: int
    bmAttributes: int = 0x02
    wMaxPacketSize: int = MAX_PACKET
    bInterval: int = 0
    bLength: int = 7
    bDescriptorType: int = _DT_ENDPOINT
    bRefresh: int = 0
    bSynchAddress: int = 0
    extra_descriptors: tuple[int, ...] = ()

    def pack(self) -> bytes:
        """The 7 bytes of the descriptor (USB 2.0 table 9-13)."""
        return _ENDPOINT.pack(self.bLength, self.bDescriptorType, self.bEndpointAddress, self.bmAttributes,
                              self.wMaxPacketSize, self.bInterval)


@dataclass(frozen=True, slots=True)
class InterfaceDescriptor:
    """USB 2.0 9.6.5: one vendor-specific interface (class 0xFF) with the two bulk endpoints."""

    bInterfaceNumber: int = 0
    bAlternateSetting: int = 0
    bNumEndpoints: int = 2
    bInterfaceClass: int = 0xFF
    bInterfaceSubClass: int = 0x00
    bInterfaceProtocol: int = 0x00
    iInterface: int = 0
    bLength: int = 9
    bDescriptorType: int = _DT_INTERFACE
    extra_descriptors: tuple[int, ...] = ()

    def pack(self) -> bytes:
        """The 9 bytes of the descriptor (USB 2.0 table 9-12)."""
        return _INTERFACE.pack(self.bLength, self.bDescriptorType, self.bInterfaceNumber, self.bAlternateSetting,
                               self.bNumEndpoints, self.bInterfaceClass, self.bInterfaceSubClass,
                               self.bInterfaceProtocol, self.iInterface)


@dataclass(frozen=True, slots=True)
class ConfigurationDescriptor:
    """USB 2.0 9.6.3: self-powered (the drive has its own supply), 100 mA from the bus."""

    wTotalLength: int = 9 + 9 + 7 + 7
    bNumInterfaces: int = 1
    bConfigurationValue: int = CONFIGURATION_VALUE
    iConfiguration: int = 0
    bmAttributes: int = 0xC0
    bMaxPower: int = 50
    bLength: int = 9
    bDescriptorType: int = _DT_CONFIG
    extra_descriptors: tuple[int, ...] = ()

    def pack(self) -> bytes:
        """The 9 bytes of the descriptor (USB 2.0 table 9-10)."""
        return _CONFIG.pack(self.bLength, self.bDescriptorType, self.wTotalLength, self.bNumInterfaces,
                            self.bConfigurationValue, self.iConfiguration, self.bmAttributes, self.bMaxPower)


@dataclass(frozen=True, slots=True)
class DeviceDescriptor:
    """USB 2.0 9.6.1 plus where pyusb finds the device (bus, address, port, speed)."""

    idVendor: int = IDX_VENDOR_ID
    idProduct: int = IDX_PRODUCT_ID
    bcdUSB: int = 0x0200
    bDeviceClass: int = 0x00            # the class is given per interface
    bDeviceSubClass: int = 0x00
    bDeviceProtocol: int = 0x00
    bMaxPacketSize0: int = 64
    bcdDevice: int = 0x0100
    iManufacturer: int = 1
    iProduct: int = 2
    iSerialNumber: int = 3
    bNumConfigurations: int = 1
    bLength: int = 18
    bDescriptorType: int = _DT_DEVICE
    bus: int = 1
    address: int = 1
    port_number: int = 1
    port_numbers: tuple[int, ...] = (1,)
    speed: int = usb.util.SPEED_FULL

    def pack(self) -> bytes:
        """The 18 bytes of the descriptor (USB 2.0 table 9-8)."""
        return _DEVICE.pack(self.bLength, self.bDescriptorType, self.bcdUSB, self.bDeviceClass,
                            self.bDeviceSubClass, self.bDeviceProtocol, self.bMaxPacketSize0, self.idVendor,
                            self.idProduct, self.bcdDevice, self.iManufacturer, self.iProduct,
                            self.iSerialNumber, self.bNumConfigurations)


def string_descriptor(text: str) -> bytes:
    """USB 2.0 9.6.7: bLength, type 3, UTF-16LE."""
    body = text.encode("utf-16-le")
    return bytes((2 + len(body), _DT_STRING)) + body


# -- byte pipes to an emulated IDX ------------------------------------------------------------------
class Pipe(Protocol):
    """The USB byte channel of one opened device: what bulk OUT sends and bulk IN receives."""

    def send(self, data: bytes) -> None:
        """Bytes the host writes to the bulk OUT endpoint."""

    def receive(self, size: int, timeout: float | None) -> bytes:
        """Up to ``size`` bytes; ``b""`` when none came within ``timeout`` seconds (None: for ever)."""
        ...

    def close(self) -> None:
        """End the connection to the IDX."""


class TcpPipe:
    """A connection to the IDX's TCP port of a running rig (``"usb": {"idx1": {"tcp": ...}}``)."""

    def __init__(self, host: str, port: int) -> None:
        try:
            self.sock = socket.create_connection((host, port), timeout=5.0)
        except OSError as exc:
            raise _error(_LIBUSB_ERROR_NO_DEVICE, f"No such device (it may have been disconnected): "
                                                  f"tcp:{host}:{port}: {exc.strerror or exc}", errno.ENODEV) from None
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def send(self, data: bytes) -> None:
        """Send to the rig's IDX TCP port; a closed connection is a libusb I/O error."""
        try:
            self.sock.settimeout(5.0)
            self.sock.sendall(data)
        except OSError as exc:
            raise _error(_LIBUSB_ERROR_NO_DEVICE, "No such device (it may have been disconnected)",
                         errno.ENODEV) from exc

    def receive(self, size: int, timeout: float | None) -> bytes:
        """Up to ``size`` bytes from the rig; ``b""`` when none came within ``timeout`` seconds."""
        self.sock.settimeout(timeout)
        try:
            data = self.sock.recv(size)
        except TimeoutError:
            return b""
        except OSError as exc:
            raise _error(_LIBUSB_ERROR_NO_DEVICE, "No such device (it may have been disconnected)",
                         errno.ENODEV) from exc
        if not data:            # the rig closed the connection: the device is gone
            raise _error(_LIBUSB_ERROR_NO_DEVICE, "No such device (it may have been disconnected)", errno.ENODEV)
        return data

    def close(self) -> None:
        """Close the TCP connection."""
        self.sock.close()


class ChannelOwner(Protocol):
    """What :class:`DevicePipe` needs of an in-process IDX (an :class:`~..device.IdxDevice`)."""

    @property
    def clock(self) -> Any:
        """The clock the device's protocol runs on (a simulated one is advanced by the caller)."""

    def open_channel(self, send: Any) -> Any:
        """A new host channel whose replies go to ``send``."""


class DevicePipe:
    """A USB channel of an in-process :class:`~..device.IdxDevice`.

    Real time (a rig loop runs the clock in its thread): requests are handed to that thread with
    ``clock.call_soon_threadsafe`` and replies wait on a condition. Simulated clock: the request
    is fed at once and a read runs the clock's events until a reply is there or the read's
    timeout has passed in simulated time, so a test needs nobody to advance the clock.
    """

    def __init__(self, device: ChannelOwner) -> None:
        self.clock = device.clock
        self._replies: deque[bytes] = deque()
        self._ready = threading.Condition()
        with self.clock.lock:
            self.channel = device.open_channel(self._on_reply)

    def _on_reply(self, data: bytes) -> None:          # rig thread (or the simulating caller)
        with self._ready:
            self._replies.append(bytes(data))
            self._ready.notify_all()

    def send(self, data: bytes) -> None:
        """Feed the host's bytes to the in-process IDX's channel."""
        if self.clock.is_simulated:
            with self.clock.lock:
                self.channel.receive(bytes(data))
        else:
            self.clock.call_soon_threadsafe(self.channel.receive, bytes(data))

    def _take(self, size: int) -> bytes:
        chunk = self._replies.popleft()
        if len(chunk) > size:
            self._replies.appendleft(chunk[size:])
        return chunk[:size]

    def receive(self, size: int, timeout: float | None) -> bytes:
        """Up to ``size`` bytes the IDX answered; ``b""`` when none came within ``timeout`` seconds."""
        if self.clock.is_simulated:
            return self._receive_simulated(size, timeout)
        with self._ready:
            if not self._ready.wait_for(lambda: bool(self._replies), timeout):
                return b""
            return self._take(size)

    def _receive_simulated(self, size: int, timeout: float | None) -> bytes:
        clock = self.clock
        deadline = None if timeout is None else clock.now() + timeout
        with clock.lock:
            while not self._replies:
                due = clock.next_deadline()
                if due is None or (deadline is not None and due > deadline):
                    break
                clock.step()
            if not self._replies:
                if deadline is not None:
                    clock.run_until(deadline)
                return b""
            return self._take(size)

    def close(self) -> None:
        """Close the IDX channel."""
        if self.clock.is_simulated:
            with self.clock.lock:
                self.channel.close()
        else:
            self.clock.call_soon_threadsafe(self.channel.close)


# -- the backend ------------------------------------------------------------------------------------
@dataclass
class EmulatedDevice:
    """What :meth:`IdxUsbBackend.enumerate_devices` yields: one IDX, its descriptors and how to reach it."""

    target: str | ChannelOwner
    descriptor: DeviceDescriptor
    strings: tuple[str, ...]
    configuration: ConfigurationDescriptor = field(default_factory=ConfigurationDescriptor)
    interface: InterfaceDescriptor = field(default_factory=InterfaceDescriptor)
    endpoints: tuple[EndpointDescriptor, ...] = (EndpointDescriptor(EP_OUT), EndpointDescriptor(EP_IN))

    def open_pipe(self) -> Pipe:
        """A fresh connection to the IDX (open, or a USB bus reset)."""
        if isinstance(self.target, str):
            ep = parse_endpoint(self.target)
            return TcpPipe(ep.host, ep.port)
        return DevicePipe(self.target)

    def config_bytes(self) -> bytes:
        """GET_DESCRIPTOR(CONFIGURATION): the configuration with its interface and endpoints (USB 2.0 9.4.3)."""
        return self.configuration.pack() + self.interface.pack() + b"".join(e.pack() for e in self.endpoints)


class _Handle:
    """One ``open_device``: its pipe, active configuration and claimed interfaces."""

    def __init__(self, device: EmulatedDevice) -> None:
        self.device = device
        self.pipe: Pipe = device.open_pipe()
        # Linux configures a device with its first configuration when it enumerates.
        self.configuration = CONFIGURATION_VALUE
        self.claimed: set[int] = set()
        self.halted: set[int] = set()


class IdxUsbBackend(usb.backend.IBackend):  # type: ignore[misc]
    """pyusb backend with one USB device per target: a ``tcp:HOST:PORT`` endpoint of a running rig's
    IDX, or an in-process :class:`~..device.IdxDevice`.

    ``serial_numbers`` gives each device's iSerialNumber string (default: the in-process IDX's LSS
    serial 0x1018:04 in hex, ``"0"`` for a TCP target whose dictionary is not at hand).
    """

    def __init__(self, *targets: str | ChannelOwner, vendor: int = IDX_VENDOR_ID, product: int = IDX_PRODUCT_ID,
                 serial_numbers: tuple[str, ...] | None = None) -> None:
        super().__init__()
        if not targets:
            raise ConfigError("IdxUsbBackend needs at least one IDX (a tcp:HOST:PORT endpoint or an IdxDevice)")
        self.devices: list[EmulatedDevice] = []
        for i, target in enumerate(targets):
            if isinstance(target, str):
                ep = parse_endpoint(target)
                if ep.kind is not EndpointKind.TCP:
                    raise ConfigError(f"{target}: the pyusb backend reaches a rig's IDX by its tcp:HOST:PORT endpoint")
                target = str(ep)
            serial = serial_numbers[i] if serial_numbers is not None else _default_serial(target)
            descriptor = DeviceDescriptor(idVendor=vendor, idProduct=product, address=i + 1, port_number=i + 1,
                                          port_numbers=(i + 1,))
            self.devices.append(EmulatedDevice(target, descriptor, ("maxon", "IDX (gatewaylab emulation)", serial)))

    @classmethod
    def from_ready_file(cls, path: str | Path, name: str | None = None, **kwargs: Any) -> IdxUsbBackend:
        """The IDX (every IDX when ``name`` is None) of a ``gatewaylab run --ready-file`` file, by its TCP port."""
        info = json.loads(Path(path).read_text())
        usb_info: dict[str, dict[str, str]] = info.get("usb", {})
        names = [name] if name is not None else sorted(usb_info)
        targets: list[str] = []
        for n in names:
            tcp = usb_info.get(n, {}).get("tcp")
            if tcp is None:
                raise ConfigError(f"{path}: no IDX {n!r} with a TCP port (usb.tcp_port) in this ready file")
            targets.append(tcp)
        if not targets:
            raise ConfigError(f"{path}: this rig has no IDX")
        return cls(*targets, **kwargs)

    # -- enumeration and descriptors ------------------------------------------------------------------
    def enumerate_devices(self) -> list[EmulatedDevice]:
        """pyusb backend: the emulated IDXs this backend was given."""
        return list(self.devices)

    def get_parent(self, dev: EmulatedDevice) -> None:
        """pyusb backend: no hub above the emulated device."""
        return None

    def get_device_descriptor(self, dev: EmulatedDevice) -> DeviceDescriptor:
        """pyusb backend: the IDX's device descriptor (maxon vendor and product IDs)."""
        return dev.descriptor

    def get_configuration_descriptor(self, dev: EmulatedDevice, config: int) -> ConfigurationDescriptor:
        """pyusb backend: the one configuration; IndexError (NoSuchDescriptor) for any other."""
        if config != 0:
            raise NoSuchDescriptor(f"configuration {config} (the IDX has one)")
        return dev.configuration

    def get_interface_descriptor(self, dev: EmulatedDevice, intf: int, alt: int, config: int) -> InterfaceDescriptor:
        """pyusb backend: the one interface; IndexError (NoSuchDescriptor) for any other."""
        if config != 0 or intf != 0 or alt != 0:
            raise NoSuchDescriptor(f"interface {intf} alternate setting {alt} of configuration {config}")
        return dev.interface

    def get_endpoint_descriptor(self, dev: EmulatedDevice, ep: int, intf: int, alt: int,
                                config: int) -> EndpointDescriptor:
        """pyusb backend: the bulk IN/OUT endpoints; IndexError (NoSuchDescriptor) for any other."""
        if config != 0 or intf != 0 or alt != 0 or not 0 <= ep < len(dev.endpoints):
            raise NoSuchDescriptor(f"endpoint {ep} of interface {intf}")
        return dev.endpoints[ep]

    # -- handles ----------------------------------------------------------------------------------------
    def open_device(self, dev: EmulatedDevice) -> _Handle:
        """pyusb backend: a handle with its own connection to the IDX."""
        return _Handle(dev)

    def close_device(self, dev_handle: _Handle) -> None:
        """pyusb backend: close the handle's connection."""
        dev_handle.pipe.close()

    def set_configuration(self, dev_handle: _Handle, config_value: int) -> None:
        """pyusb backend: SET_CONFIGURATION (0 unconfigures); other values stall, as on the device."""
        if config_value not in (0, CONFIGURATION_VALUE):
            raise _stall()
        dev_handle.configuration = config_value
        dev_handle.halted.clear()

    def get_configuration(self, dev_handle: _Handle) -> int:
        """pyusb backend: the configuration value set last."""
        return dev_handle.configuration

    def set_interface_altsetting(self, dev_handle: _Handle, intf: int, altsetting: int) -> None:
        """pyusb backend: only interface 0 alternate setting 0 exists; others stall."""
        if intf != 0 or altsetting != 0:
            raise _stall()

    def claim_interface(self, dev_handle: _Handle, intf: int) -> None:
        """pyusb backend: claim interface 0 (libusb's 'entity not found' for others)."""
        if intf != 0:
            raise _error(-5, "Entity not found", errno.ENOENT)
        dev_handle.claimed.add(intf)

    def release_interface(self, dev_handle: _Handle, intf: int) -> None:
        """pyusb backend: release a claimed interface."""
        dev_handle.claimed.discard(intf)

    def is_kernel_driver_active(self, dev_handle: _Handle, intf: int) -> bool:
        """pyusb backend: no kernel driver binds the emulated device."""
        return False

    def detach_kernel_driver(self, dev_handle: _Handle, intf: int) -> None:
        """pyusb backend: libusb's answer when no driver is attached."""
        raise _error(-5, "Entity not found", errno.ENOENT)     # libusb: no driver attached

    def attach_kernel_driver(self, dev_handle: _Handle, intf: int) -> None:
        """pyusb backend: libusb's answer when there is no driver to attach."""
        raise _error(-5, "Entity not found", errno.ENOENT)

    def clear_halt(self, dev_handle: _Handle, ep: int) -> None:
        """pyusb backend: CLEAR_FEATURE(ENDPOINT_HALT) lifts a stall of ``ep``."""
        dev_handle.halted.discard(ep)

    def reset_device(self, dev_handle: _Handle) -> None:
        """A bus reset: the IDX's USB channel starts anew (a fresh protocol channel, nothing pending)."""
        dev_handle.pipe.close()
        dev_handle.pipe = dev_handle.device.open_pipe()
        dev_handle.configuration = CONFIGURATION_VALUE
        dev_handle.halted.clear()

    # -- transfers ----------------------------------------------------------------------------------------
    def _check_bulk(self, dev_handle: _Handle, ep: int, wanted: int) -> None:
        if ep != wanted:
            raise _error(_LIBUSB_ERROR_INVALID_PARAM, "Invalid parameter", errno.EINVAL)
        if dev_handle.configuration != CONFIGURATION_VALUE:
            raise _error(_LIBUSB_ERROR_INVALID_PARAM, "Invalid parameter", errno.EINVAL)
        if ep in dev_handle.halted:
            raise _stall()

    def bulk_write(self, dev_handle: _Handle, ep: int, intf: int, data: array.array[int], timeout: int) -> int:
        """pyusb backend: bytes to the bulk OUT endpoint, on to the IDX."""
        self._check_bulk(dev_handle, ep, EP_OUT)
        payload = data.tobytes()
        dev_handle.pipe.send(payload)
        return len(payload)

    def bulk_read(self, dev_handle: _Handle, ep: int, intf: int, buff: array.array[int], timeout: int) -> int:
        """What the IDX answered, at most ``len(buff)`` bytes; libusb's timeout in ms (0 = for ever)."""
        self._check_bulk(dev_handle, ep, EP_IN)
        size = len(buff) * buff.itemsize
        data = dev_handle.pipe.receive(size, timeout / 1000.0 if timeout > 0 else None)
        if not data:
            raise _timeout_error()
        memoryview(buff).cast("B")[:len(data)] = data
        return len(data)

    def intr_write(self, dev_handle: _Handle, ep: int, intf: int, data: array.array[int], timeout: int) -> int:
        """pyusb backend: the IDX has no interrupt endpoint (invalid parameter)."""
        raise _error(_LIBUSB_ERROR_INVALID_PARAM, "Invalid parameter", errno.EINVAL)   # no interrupt endpoint

    def intr_read(self, dev_handle: _Handle, ep: int, intf: int, buff: array.array[int], timeout: int) -> int:
        """pyusb backend: the IDX has no interrupt endpoint (invalid parameter)."""
        raise _error(_LIBUSB_ERROR_INVALID_PARAM, "Invalid parameter", errno.EINVAL)

    def ctrl_transfer(self, dev_handle: _Handle, bmRequestType: int, bRequest: int, wValue: int, wIndex: int,
                      data: array.array[int], timeout: int) -> int:
        """The standard requests of USB 2.0 9.4 on endpoint 0; anything else stalls (vendor requests
        included: the IDX protocol runs on the bulk endpoints only)."""
        device_in = bmRequestType == 0x80
        answer: bytes | None = None
        if bmRequestType & 0x60:                      # class or vendor request
            raise _stall()
        if device_in and bRequest == _GET_DESCRIPTOR:
            answer = self._descriptor(dev_handle.device, wValue >> 8, wValue & 0xFF, wIndex)
        elif device_in and bRequest == _GET_CONFIGURATION:
            answer = bytes((dev_handle.configuration,))
        elif bmRequestType & 0x80 and bRequest == _GET_STATUS:
            halted = bmRequestType & 0x1F == 2 and wIndex in dev_handle.halted
            answer = _U16.pack(0x0001 if device_in or halted else 0)   # device: self-powered
        elif bmRequestType == 0x81 and bRequest == _GET_INTERFACE:
            answer = b"\x00"
        elif bmRequestType == 0x00 and bRequest == _SET_CONFIGURATION:
            self.set_configuration(dev_handle, wValue & 0xFF)
            return 0
        elif bmRequestType == 0x01 and bRequest == _SET_INTERFACE:
            self.set_interface_altsetting(dev_handle, wIndex, wValue)
            return 0
        elif bmRequestType == 0x02 and bRequest in (_CLEAR_FEATURE, _SET_FEATURE) and wValue == 0:
            if wIndex not in (EP_OUT, EP_IN):
                raise _stall()
            if bRequest == _SET_FEATURE:
                dev_handle.halted.add(wIndex)
            else:
                dev_handle.halted.discard(wIndex)
            return 0
        if answer is None:
            raise _stall()
        n = min(len(answer), len(data) * data.itemsize)
        memoryview(data).cast("B")[:n] = answer[:n]
        return n

    def _descriptor(self, dev: EmulatedDevice, kind: int, index: int, langid: int) -> bytes:
        if kind == _DT_DEVICE and index == 0:
            return dev.descriptor.pack()
        if kind == _DT_CONFIG and index == 0:
            return dev.config_bytes()
        if kind == _DT_STRING:
            if index == 0:
                return bytes((4, _DT_STRING)) + _U16.pack(LANGID_EN_US)
            if 1 <= index <= len(dev.strings) and dev.strings[index - 1]:
                return string_descriptor(dev.strings[index - 1])
        raise _stall()


def _default_serial(target: str | ChannelOwner) -> str:
    node = getattr(target, "node", None)
    if node is None:
        return "0"
    return f"{int(node.get(0x1018, 4)):08X}"
