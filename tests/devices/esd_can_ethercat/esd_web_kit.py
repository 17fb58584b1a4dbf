"""Helpers of the esd web interface tests (manual chapter 6): a fake backend with fixed data, a lock that
knows who holds it, an HTTP client, a multipart encoder and a PNG decoder for the screenshot check."""

from __future__ import annotations

import http.client
import struct
import threading
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from urllib.parse import urlsplit

from gatewaylab.devices.esd_can_ethercat.web import CanStatusView, DeviceInfoView, EsdWebServer

#: Every counter a different number, so a value in the wrong place shows (Figure 41 fields).
CAN_STATUS = CanStatusView(
    bitrate_set="0x00000002", bitrate_actual=500000, time_quanta=20, sample_point=85.0,
    rx_std_data=11, rx_std_rtr=12, rx_ext_data=13, rx_ext_rtr=14,
    tx_std_data=21, tx_std_rtr=22, tx_ext_data=23, tx_ext_rtr=24,
    rx_bytes=1234, tx_bytes=5678, overruns=3, error_frames=5, aborted_frames=6,
    rx_error_counter=7, tx_error_counter=8, status="0a", fifo_overruns=4, rx_bits=98765,
)

#: The lines of Figure 41 (manual 6.2.1) with CAN_STATUS's values, spaced as the figure prints them.
FIGURE_41_LINES = (
    "Value set by canSetBaudrate() : 0x00000002",
    "Actual Bitrate                 : 500000 Bits/s",
    "Timequantas per Bit           : 20",
    "Timequantas before samplepoint : 17",
    "Timequantas after samplepoint  : 3",
    "Position samplepoint           : 85.0%",
    "Rcv frames      : Std(Data/RTR): 11/12 Ext(Data/RTR) 13/14",
    "Xmit frames     : Std(Data/RTR): 21/22 Ext(Data/RTR) 23/24",
    "Bytes           : (Rcv/Xmit): 1234/5678",
    "Overruns       : (Controller/FIFO): 3/4",
    "Err frames      : 5",
    "Aborted frames  : 6",
    "Err counter     : (Rx/Tx): 7/8 Status: 0a",
    "Rcv bits        : 98765",
)

DEVICE_INFO = DeviceInfoView(
    product="CAN-EtherCAT", serial="BDC1E240", hardware="1.2", firmware="2.1", bootloader="1.0",
    vendor_id="0x00000017", product_code="0x00000002", revision="0x00000001",
    ethercat_state="OP", station_address=0x1001, extra={"CAN bus": "can0"},
)

#: What the fake takes as firmware: files that start with this (the real check is the device's).
FIRMWARE_MAGIC = b"ESDFW"
#: Progress text the fake reports while "updating" (the lines of Figure 39, manual 6.1.2).
FIGURE_39 = ("End of file found. All good.\nUnpacking updater. Please wait...\nimg_upd.raw\n"
             "Flashing updater and rebooting...")


class OwnedLock:
    """An RLock that knows whether the calling thread holds it (to check the server's discipline)."""

    def __init__(self) -> None:
        self._lock = threading.RLock()
        self._owner: int | None = None
        self._depth = 0

    def __enter__(self) -> bool:
        self._lock.acquire()
        self._owner = threading.get_ident()
        self._depth += 1
        return True

    def __exit__(self, *exc: object) -> None:
        self._depth -= 1
        if not self._depth:
            self._owner = None
        self._lock.release()

    def held(self) -> bool:
        return self._owner == threading.get_ident()


@dataclass
class FakeBackend:
    """Fixed views (frozen data) plus a record of what the server asked; checks every call holds ``lock``."""

    lock: OwnedLock
    info_view: DeviceInfoView = DEVICE_INFO
    can_view: CanStatusView = CAN_STATUS
    progress: str | None = None
    uploads: list[tuple[str, bytes]] = field(default_factory=list)
    reboots: int = 0
    calls_outside_lock: list[str] = field(default_factory=list)
    fail_with: Exception | None = None
    calls: list[str] = field(default_factory=list)

    def _check(self, name: str) -> None:
        self.calls.append(name)
        if not self.lock.held():
            self.calls_outside_lock.append(name)
        if self.fail_with is not None:
            raise self.fail_with

    def info(self) -> DeviceInfoView:
        self._check("info")
        return self.info_view

    def can_status(self) -> CanStatusView:
        self._check("can_status")
        return self.can_view

    def start_firmware_update(self, filename: str, data: bytes) -> None:
        self._check("start_firmware_update")
        if self.progress is not None:
            raise ValueError("an update is already running")
        if not data.startswith(FIRMWARE_MAGIC):
            raise ValueError(f"{filename}: not an esd firmware image")
        self.uploads.append((filename, data))
        self.progress = FIGURE_39

    def update_progress(self) -> str | None:
        self._check("update_progress")
        return self.progress

    def reboot(self) -> None:
        self._check("reboot")
        self.reboots += 1


@contextmanager
def serving(backend: FakeBackend, **options: float) -> Iterator[str]:
    """An EsdWebServer for ``backend`` on a free port; yields its base URL, stops it afterwards."""
    server = EsdWebServer(backend, backend.lock, **options)  # type: ignore[arg-type]
    url = server.start()
    try:
        yield url
    finally:
        server.stop()


@dataclass(frozen=True)
class Reply:
    status: int
    headers: dict[str, str]
    body: bytes

    @property
    def text(self) -> str:
        return self.body.decode("utf-8")


def request(url: str, method: str, path: str, body: bytes | None = None,
            headers: dict[str, str] | None = None) -> Reply:
    """One HTTP request with http.client (no redirects followed)."""
    parts = urlsplit(url)
    assert parts.hostname is not None and parts.port is not None
    conn = http.client.HTTPConnection(parts.hostname, parts.port, timeout=30)
    try:
        conn.request(method, path, body=body, headers=headers or {})
        response = conn.getresponse()
        return Reply(response.status, {k.lower(): v for k, v in response.getheaders()}, response.read())
    finally:
        conn.close()


def multipart(filename: str, data: bytes, name: str = "file", boundary: str = "----esdweb7MA4YWxk") -> \
        tuple[str, bytes]:
    """(Content-Type, body) of a form with one file field, as a browser sends it (RFC 7578)."""
    body = (f"--{boundary}\r\nContent-Disposition: form-data; name=\"{name}\"; filename=\"{filename}\"\r\n"
            f"Content-Type: application/octet-stream\r\n\r\n").encode() + data + f"\r\n--{boundary}--\r\n".encode()
    return f"multipart/form-data; boundary={boundary}", body


def upload(url: str, filename: str, data: bytes) -> Reply:
    content_type, body = multipart(filename, data)
    return request(url, "POST", "/firmware", body, {"Content-Type": content_type})


def png_pixels(png: bytes) -> tuple[int, int, set[bytes]]:
    """(width, height, distinct pixel values) of an 8-bit RGB/RGBA non-interlaced PNG (what Chromium writes)."""
    assert png.startswith(b"\x89PNG\r\n\x1a\n"), "not a PNG"
    position, idat = 8, b""
    width = height = channels = 0
    while position < len(png):
        length, kind = struct.unpack_from(">I4s", png, position)
        chunk = png[position + 8: position + 8 + length]
        if kind == b"IHDR":
            width, height, depth, colour, _, _, interlace = struct.unpack(">IIBBBBB", chunk)
            assert depth == 8 and interlace == 0 and colour in (2, 6), (depth, colour, interlace)
            channels = 3 if colour == 2 else 4
        elif kind == b"IDAT":
            idat += chunk
        position += 12 + length
    raw = zlib.decompress(idat)
    stride = width * channels
    previous = bytearray(stride)
    colours: set[bytes] = set()
    for row in range(height):
        start = row * (stride + 1)
        kind_byte, line = raw[start], bytearray(raw[start + 1: start + 1 + stride])
        for i in range(stride):
            left = line[i - channels] if i >= channels else 0
            up = previous[i]
            upper_left = previous[i - channels] if i >= channels else 0
            if kind_byte == 1:
                line[i] = (line[i] + left) & 0xFF
            elif kind_byte == 2:
                line[i] = (line[i] + up) & 0xFF
            elif kind_byte == 3:
                line[i] = (line[i] + (left + up) // 2) & 0xFF
            elif kind_byte == 4:
                p = left + up - upper_left
                pa, pb, pc = abs(p - left), abs(p - up), abs(p - upper_left)
                predictor = left if pa <= pb and pa <= pc else (up if pb <= pc else upper_left)
                line[i] = (line[i] + predictor) & 0xFF
        colours.update(bytes(line[i: i + channels]) for i in range(0, stride, channels * 7))
        previous = line
    return width, height, colours
