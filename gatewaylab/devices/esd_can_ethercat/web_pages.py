"""The esd CAN-EtherCAT web interface as pages (manual chapter 6 "Webserver Interface"), sans-I/O.

:class:`EsdWebApp` turns a :class:`Request` into a :class:`Response`; it never touches a socket.
The HTTP transport is :mod:`.web_server`; :mod:`.web` is the public face of both.

Pages (manual 6.1.1 Figure 37 menu: Overview, Configuration > Firmware update / Reboot,
Status > CAN, Information, Contact):

* ``/`` Overview (6.1.1, Figure 37)
* ``/firmware`` Firmware update: upload form (6.1.2, Figure 38), progress (Figure 39)
* ``/reboot`` Reboot (6.1.3, Figure 40)
* ``/status/can`` CAN statistics (6.2.1, Figure 41)
* ``/information`` Information, ``/contact`` Contact (menu items of Figure 37)

Every value is HTML-escaped; the backend is called only inside ``with lock:`` (the rig passes the
clock's lock, docs/architecture.md "Threads").
"""

from __future__ import annotations

import contextlib
import html
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from email.message import Message
from typing import Protocol, TypeVar

from gatewaylab.common.errors import GatewaylabError, RemoteError

__all__ = [
    "CanStatusView",
    "DeviceInfoView",
    "EsdWebApp",
    "EsdWebBackend",
    "MultipartError",
    "Request",
    "Response",
    "format_can_status",
    "parse_multipart",
]

#: CPU master clock of the AT91SAM9263 (manual 5.1.5.9 "CPU Master Clock: 120 MHz"), Figure 41's
#: "Controller clockrate".
CONTROLLER_CLOCK_MHZ = 120.0
#: Figure 41: "TimestampFreq=500000  Hz".
TIMESTAMP_FREQ_HZ = 500_000


@dataclass(frozen=True, slots=True)
class CanStatusView:
    """What the Status/CAN page shows (manual 6.2.1, Figure 41 "CAN status output").

    ``bitrate_set`` is the value as canSetBaudrate() got it, shown verbatim (e.g. ``"0x00000002"``);
    ``bitrate_actual`` in bit/s; ``sample_point`` in percent. ``overruns`` is the CAN controller's
    overrun count (0x2010:34), ``fifo_overruns`` the driver FIFO's (0x2010:35): Figure 41 prints
    "Overruns : (Controller/FIFO): a/b". ``status`` is the controller status byte as hex text
    ("00" in Figure 41). The fields after ``status`` have defaults (Figure 41 details a backend
    may leave alone).
    """

    bitrate_set: str
    bitrate_actual: int
    time_quanta: int
    sample_point: float
    rx_std_data: int
    rx_std_rtr: int
    rx_ext_data: int
    rx_ext_rtr: int
    tx_std_data: int
    tx_std_rtr: int
    tx_ext_data: int
    tx_ext_rtr: int
    rx_bytes: int
    tx_bytes: int
    overruns: int
    error_frames: int
    aborted_frames: int
    rx_error_counter: int
    tx_error_counter: int
    status: str
    #: Figure 41 "Overruns : (Controller/FIFO)": the FIFO half (0x2010:35).
    fifo_overruns: int = 0
    #: Figure 41 "Synchronization Jump Width" in time quanta.
    sjw: int = 1
    #: Figure 41 "Deviation from configured rate" in percent.
    deviation: float = 0.0
    #: Figure 41 "Rcv bits": bits received on the bus.
    rx_bits: int = 0
    #: Figure 41 "Timestamp=": the driver's timestamp in ticks of TIMESTAMP_FREQ_HZ.
    timestamp: int = 0


@dataclass(frozen=True, slots=True)
class DeviceInfoView:
    """What the Overview and Information pages show (manual 6.1.1 Figure 37, menu "Information").

    Identity values as text the way the device reports them (e.g. ``vendor_id="0x00000017"``,
    manual 5.1.3.5); ``extra`` adds rows to the Information page in its order.
    """

    product: str
    serial: str
    hardware: str
    firmware: str
    bootloader: str
    vendor_id: str
    product_code: str
    revision: str
    ethercat_state: str
    station_address: int
    extra: Mapping[str, str] = field(default_factory=dict)


class EsdWebBackend(Protocol):
    """What the web pages need from the device; called only inside the server's lock."""

    def info(self) -> DeviceInfoView:
        """Identity and state for Overview/Information."""
        ...

    def can_status(self) -> CanStatusView:
        """Bit timing and statistics for Status/CAN (6.2.1)."""
        ...

    def start_firmware_update(self, filename: str, data: bytes) -> None:
        """Start an update with an uploaded file (6.1.2); raise ValueError(one-line reason) to refuse."""
        ...

    def update_progress(self) -> str | None:
        """The update's output so far, like Figure 39; None when no update is running."""
        ...

    def reboot(self) -> None:
        """Restart the device (6.1.3 "Reboot now")."""
        ...


@dataclass(frozen=True, slots=True)
class Request:
    """One HTTP request as the transport read it (body complete and within the size limit)."""

    method: str
    target: str
    content_type: str = ""
    body: bytes = b""


@dataclass(frozen=True, slots=True)
class Response:
    """One HTTP response; ``headers`` excludes Content-Length (the transport adds it)."""

    status: int
    body: bytes
    headers: tuple[tuple[str, str], ...] = ()


class ServerClosed(GatewaylabError):
    """The server stopped while a request waited for the lock (answered 503, backend untouched)."""


class MultipartError(RemoteError, ValueError):
    """A multipart/form-data body that does not follow RFC 7578 / RFC 2046 5.1 (the client's fault;
    a ValueError too, for callers that catch that)."""


@dataclass(frozen=True, slots=True)
class FormPart:
    """One part of a multipart/form-data body."""

    name: str
    filename: str | None
    data: bytes


def _header_params(value: str, header: str = "content-type") -> Message:
    message = Message()
    message[header] = value
    return message


def parse_multipart(content_type: str, body: bytes) -> list[FormPart]:
    """Parts of a multipart/form-data ``body`` (RFC 7578); anything malformed -> MultipartError."""
    params = _header_params(content_type)
    if params.get_content_type() != "multipart/form-data":
        raise MultipartError("not multipart/form-data")
    boundary = params.get_param("boundary")
    if not isinstance(boundary, str) or not 1 <= len(boundary) <= 70:
        raise MultipartError("no valid boundary")
    try:
        delimiter = b"--" + boundary.encode("ascii")
    except UnicodeEncodeError:
        raise MultipartError("boundary is not ASCII") from None
    if not body.startswith(delimiter):
        raise MultipartError("body does not start with the boundary")
    parts: list[FormPart] = []
    position = len(delimiter)
    separator = b"\r\n" + delimiter
    while True:
        if body.startswith(b"--", position):
            return parts  # closing delimiter; the epilogue after it is ignored (RFC 2046 5.1.1)
        line_end = body.find(b"\r\n", position)
        if line_end < 0 or body[position:line_end].strip(b" \t"):
            raise MultipartError("garbage after a boundary")
        header_end = body.find(b"\r\n\r\n", line_end)
        if header_end < 0:
            raise MultipartError("part headers do not end")
        next_delimiter = body.find(separator, header_end + 4)
        if next_delimiter < 0:
            raise MultipartError("no closing boundary")
        parts.append(_part(body[line_end + 2 : header_end], body[header_end + 4 : next_delimiter]))
        position = next_delimiter + len(separator)


def _part(raw_headers: bytes, data: bytes) -> FormPart:
    disposition = ""
    for line in raw_headers.split(b"\r\n"):
        name, colon, value = line.partition(b":")
        if not colon:
            raise MultipartError("malformed part header")
        if name.strip().lower() == b"content-disposition":
            disposition = value.decode("utf-8", "replace").strip()
    params = _header_params(disposition, "content-disposition")
    if params.get_content_disposition() != "form-data":
        raise MultipartError("part without Content-Disposition: form-data")
    field_name = params.get_param("name", header="content-disposition")
    if not isinstance(field_name, str):
        raise MultipartError("part without a name")
    filename = params.get_param("filename", header="content-disposition")
    return FormPart(field_name, filename if isinstance(filename, str) else None, data)


_T = TypeVar("_T")

_MENU: tuple[tuple[str, str | None, int], ...] = (
    # (label, path or None for a heading, indent) as in the menu of Figure 37/38/41
    ("Overview", "/", 0),
    ("Configuration", None, 0),
    ("Firmware update", "/firmware", 1),
    ("Reboot", "/reboot", 1),
    ("Status", None, 0),
    ("CAN", "/status/can", 1),
    ("Information", "/information", 0),
    ("Contact", "/contact", 0),
)

_STYLE = """
body{margin:0;font-family:Arial,Helvetica,sans-serif;font-size:14px;color:#000;background:#fff}
#head{background:#1c4f9c;color:#fff;padding:10px 16px;display:flex;justify-content:space-between}
#head b{font-size:20px}
#menu{float:left;width:180px;padding:12px;background:#e8eef8;min-height:500px}
#menu a,#menu span{display:block;padding:3px 0;color:#1c4f9c;text-decoration:none}
#menu span{color:#000;font-weight:bold}
#menu .sub{padding-left:14px}
#menu .here{font-weight:bold;text-decoration:underline}
#logo{margin-top:30px;color:#1c4f9c;font-weight:bold}
#main{margin-left:220px;padding:12px 20px}
pre{background:#f4f4f4;border:1px solid #ccc;padding:8px;font-size:13px}
table.info td{padding:2px 12px 2px 0}
.refused{color:#b00000;font-weight:bold}
"""


def _path(target: str) -> str:
    """The path of a request target: origin-form ``/path?query`` or absolute-form
    ``http://host/path`` (RFC 9112 3.2: a server must accept both); never raises."""
    if target[:8].lower().startswith(("http://", "https://")):
        authority_and_path = target.partition("://")[2]
        slash = authority_and_path.find("/")
        target = authority_and_path[slash:] if slash >= 0 else "/"
    return target.partition("?")[0].partition("#")[0]


def _e(value: object) -> str:
    """HTML-escape any value (manual text and backend values alike)."""
    return html.escape(str(value), quote=True)


class EsdWebApp:
    """The pages of manual chapter 6 for one device; thread-safe through ``lock``."""

    def __init__(self, backend: EsdWebBackend, lock: contextlib.AbstractContextManager[object],
                 refresh: float = 1.0) -> None:
        self.backend = backend
        self.lock = lock
        #: Seconds between the progress page's reloads while an update runs (Figure 39).
        self.refresh = refresh
        #: Set (under ``lock``) when the server stops: no backend call happens after that.
        self.closed = False
        self._routes: dict[str, dict[str, Callable[[Request], Response]]] = {
            "/": {"GET": self._overview},
            "/firmware": {"GET": self._firmware, "POST": self._firmware_upload},
            "/reboot": {"GET": self._reboot, "POST": self._reboot_now},
            "/status/can": {"GET": self._can},
            "/information": {"GET": self._information},
            "/contact": {"GET": self._contact},
        }

    # -- dispatch -----------------------------------------------------------------------------

    def allowed(self, target: str) -> tuple[str, ...] | None:
        """Methods ``target`` answers (HEAD with GET), or None for an unknown path."""
        methods = self._routes.get(_path(target))
        if methods is None:
            return None
        return (*methods, "HEAD") if "GET" in methods else tuple(methods)

    def handle(self, request: Request) -> Response:
        """Answer one request: a page, 303 after an accepted upload, 4xx for anything wrong."""
        methods = self._routes.get(_path(request.target))
        if methods is None:
            return self.error(404, "Not Found", "There is no such page on this device.")
        method = "GET" if request.method == "HEAD" else request.method
        page = methods.get(method)
        if page is None:
            allowed = ", ".join(self.allowed(request.target) or ())
            response = self.error(405, "Method Not Allowed", f"This page answers {allowed}.")
            return Response(405, response.body, (*response.headers, ("Allow", allowed)))
        try:
            return page(request)
        except ServerClosed:
            return self.error(503, "Service Unavailable", "The web interface is stopping.")

    def error(self, status: int, title: str, text: str) -> Response:
        """An error page in the device's frame (no backend call, so it is safe from any state)."""
        body = f"<h2>{_e(status)} {_e(title)}</h2>\n<p>{_e(text)}</p>\n"
        return self._page(title, "", body, status=status)

    def _call(self, fn: Callable[[], _T]) -> _T:
        with self.lock:
            if self.closed:
                raise ServerClosed("the web interface is stopped")
            return fn()

    # -- frame --------------------------------------------------------------------------------

    def _page(self, title: str, here: str, content: str, status: int = 200,
              refresh: float | None = None) -> Response:
        menu = []
        for label, path, indent in _MENU:
            cls = "sub" if indent else ""
            if path is None:
                menu.append(f'<span class="{cls}">{_e(label)}</span>')
            else:
                if path == here:
                    cls = f"{cls} here".strip()
                menu.append(f'<a class="{cls}" href="{_e(path)}">{_e(label)}</a>')
        meta = f'<meta http-equiv="refresh" content="{refresh:g}">\n' if refresh is not None else ""
        document = (
            "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
            f"{meta}<title>EtherCAT-CAN-Gateway - {_e(title)}</title>\n<style>{_STYLE}</style>\n</head>\n<body>\n"
            '<div id="head"><b>EtherCAT-CAN-Gateway</b><span>esd gmbh, Hannover</span></div>\n'
            '<div id="menu">\n' + "\n".join(menu) + "\n"
            '<div id="logo">esd electronic system<br>design gmbh</div>\n</div>\n'
            f'<div id="main">\n{content}</div>\n</body>\n</html>\n'
        )
        headers = (("Content-Type", "text/html; charset=utf-8"), ("Cache-Control", "no-store"),
                   ("X-Content-Type-Options", "nosniff"))
        return Response(status, document.encode("utf-8"), headers)

    # -- pages --------------------------------------------------------------------------------

    def _overview(self, request: Request) -> Response:
        """6.1.1 Figure 37: the start page with the menu on the left."""
        info = self._call(self.backend.info)
        content = (
            "<h2>Overview</h2>\n"
            "<p>This is the web interface of the EtherCAT-CAN-Gateway. Use the menu on the left to "
            "update the firmware, reboot the device or look at the CAN status.</p>\n"
            '<table class="info">\n'
            + _rows((("Product", info.product), ("Serial number", info.serial),
                     ("Firmware version", info.firmware), ("EtherCAT state", info.ethercat_state)))
            + "</table>\n"
        )
        return self._page("Overview", "/", content)

    def _firmware(self, request: Request, refused: str | None = None) -> Response:
        """6.1.2 Figure 38 (upload form) or, while an update runs, Figure 39 (its output)."""
        progress = self._call(self.backend.update_progress)
        content = (
            "<h2>Firmware Update</h2>\n"
            "<p>This page is intended to upload new software to the EtherCAT-CAN-Gateway.</p>\n"
            "<p><b>Important:</b><br>\nAfter clicking the Submit button it can take some time until the "
            "update is finished. Usually you just have to wait, but if your browser times out you have to "
            "reload this page by clicking the <b>Firmware Update</b> link on the left.</p>\n"
        )
        if refused is not None:
            content += f'<p class="refused" id="refused">Update refused: {_e(refused)}</p>\n'
        if progress is not None:
            content += f'<p>Updating now...</p>\n<pre id="progress">\n{_e(progress)}\n</pre>\n'
        else:
            content += (
                '<form method="post" action="/firmware" enctype="multipart/form-data">\n'
                '<input type="file" name="file" id="file"><br><br>\n'
                '<input type="submit" value="Start update" id="submit">\n</form>\n'
            )
        content += ('<p>Please be patient after clicking "Submit", <b>do not power off the device!</b></p>\n')
        status = 200 if refused is None else 400
        return self._page("Firmware Update", "/firmware", content, status=status,
                          refresh=self.refresh if progress is not None else None)

    def _firmware_upload(self, request: Request) -> Response:
        """6.1.2: "The firmware update starts after confirmation ... with the command button Submit"."""
        if _header_params(request.content_type).get_content_type() != "multipart/form-data":
            return self.error(415, "Unsupported Media Type", "Upload the file with a multipart/form-data form.")
        try:
            parts = parse_multipart(request.content_type, request.body)
        except MultipartError as exc:
            return self.error(400, "Bad Request", f"Malformed upload: {exc}.")
        upload = next((part for part in parts if part.name == "file"), None)
        if upload is None or (not upload.filename and not upload.data):
            return self._firmware(request, refused="no file selected")
        filename = upload.filename or ""
        try:
            self._call(lambda: self.backend.start_firmware_update(filename, upload.data))
        except ValueError as exc:
            return self._firmware(request, refused=str(exc).splitlines()[0] if str(exc) else "file refused")
        return Response(303, b"", (("Location", "/firmware"), ("Cache-Control", "no-store")))

    def _reboot(self, request: Request) -> Response:
        """6.1.3 Figure 40: "click the Reboot now command button"."""
        content = (
            "<h2>Reboot</h2>\n<p>Click the button to restart the EtherCAT-CAN-Gateway.</p>\n"
            '<form method="post" action="/reboot">\n'
            '<input type="submit" value="Reboot now" id="reboot">\n</form>\n'
        )
        return self._page("Reboot", "/reboot", content)

    def _reboot_now(self, request: Request) -> Response:
        """6.1.3: the system restart after "Reboot now"."""
        self._call(self.backend.reboot)
        content = ("<h2>Reboot</h2>\n<p>Rebooting now... The EtherCAT-CAN-Gateway restarts; reload the "
                   '<a href="/">Overview</a> in a moment.</p>\n')
        return self._page("Reboot", "/reboot", content)

    def _can(self, request: Request) -> Response:
        """6.2.1 Figure 41: the CAN test tool's bit rate (test 84) and bus statistics (test 64)."""
        status = self._call(self.backend.can_status)
        content = f'<h2>CAN</h2>\n<pre id="can">\n{_e(format_can_status(status))}\n</pre>\n'
        return self._page("CAN", "/status/can", content)

    def _information(self, request: Request) -> Response:
        """Menu item "Information" (Figure 37): identity of 5.1.3 and the EtherCAT state."""
        info = self._call(self.backend.info)
        rows: list[tuple[str, str]] = [
            ("Product", info.product), ("Serial number", info.serial),
            ("Hardware version", info.hardware), ("Firmware version", info.firmware),
            ("Bootloader version", info.bootloader), ("Vendor ID", info.vendor_id),
            ("Product code", info.product_code), ("Revision", info.revision),
            ("EtherCAT state", info.ethercat_state), ("Station address", f"0x{info.station_address:04X}"),
            *info.extra.items(),
        ]
        content = '<h2>Information</h2>\n<table class="info" id="info">\n' + _rows(rows) + "</table>\n"
        return self._page("Information", "/information", content)

    def _contact(self, request: Request) -> Response:
        """Menu item "Contact" (Figure 37): the address printed in the manual's front matter."""
        content = (
            "<h2>Contact</h2>\n<p>esd electronic system design gmbh<br>\nVahrenwalder Str. 207<br>\n"
            "30165 Hannover<br>\nGermany</p>\n<p>E-Mail: info@esd.eu<br>\nInternet: www.esd.eu</p>\n"
        )
        return self._page("Contact", "/contact", content)


def _rows(rows: Iterable[tuple[str, str]]) -> str:
    return "".join(f"<tr><td>{_e(k)}</td><td>{_e(v)}</td></tr>\n" for k, v in rows)


def format_can_status(s: CanStatusView) -> str:
    """The text of Figure 41 (manual 6.2.1) with the values of ``s``, column for column."""
    before = round(s.time_quanta * s.sample_point / 100)
    after = s.time_quanta - before
    baud_hex = s.bitrate_set[2:] if s.bitrate_set.lower().startswith("0x") else s.bitrate_set
    return "\n".join((
        "CAN Test Rev 2.10.0  -- (c) 1997-2010 esd electronic system design gmbh",
        "",
        "Available CAN-Devices:",
        "Net  0: ID=CAN_AT91SAM  S/N=n/a",
        "      Versions (hex): Dll=3.3.00  Drv=3.9.00  FW=0.0.00  HW=1.0.00",
        f"      Baudrate={baud_hex}  Status={s.status.rjust(4, '0')}  Features=07f2",
        "      Controller=NXIP SJA1000",
        f"      TimestampFreq={TIMESTAMP_FREQ_HZ}  Hz  Timestamp={s.timestamp:016x}",
        "",
        "test=84 net=0 id-1st=0 id-last=0 count=1",
        "txbuf=100 rxbuf=100 txtout=0 rxtout=0 baudrate=(don't change)",
        "testcount=1",
        "CAN bitrate:",
        "-----",
        f"Value set by canSetBaudrate() : {s.bitrate_set}",
        f"Actual Bitrate                 : {s.bitrate_actual} Bits/s",
        f"Timequantas per Bit           : {s.time_quanta}",
        f"Timequantas before samplepoint : {before}",
        f"Timequantas after samplepoint  : {after}",
        f"Synchronization Jump Width    : {s.sjw}",
        "Additional flags               : 0x00000000",
        f"Position samplepoint           : {s.sample_point:.1f}%",
        f"Deviation from configured rate : {s.deviation:.2f}%",
        f"Controller clockrate           : {CONTROLLER_CLOCK_MHZ:.1f}MHz",
        "Test-Duration=0 msec",
        "",
        "test=64 net=0 id-1st=0 id-last=0 count=1",
        "txbuf=100 rxbuf=100 txtout=0 rxtout=0 baudrate=(don't change)",
        "testcount=1",
        "CAN bus statistic:",
        "-----",
        f"Rcv frames      : Std(Data/RTR): {s.rx_std_data}/{s.rx_std_rtr} Ext(Data/RTR) {s.rx_ext_data}/{s.rx_ext_rtr}",
        f"Xmit frames     : Std(Data/RTR): {s.tx_std_data}/{s.tx_std_rtr} Ext(Data/RTR) {s.tx_ext_data}/{s.tx_ext_rtr}",
        f"Bytes           : (Rcv/Xmit): {s.rx_bytes}/{s.tx_bytes}",
        f"Overruns       : (Controller/FIFO): {s.overruns}/{s.fifo_overruns}",
        f"Err frames      : {s.error_frames}",
        f"Aborted frames  : {s.aborted_frames}",
        f"Err counter     : (Rx/Tx): {s.rx_error_counter}/{s.tx_error_counter} Status: {s.status}",
        f"Rcv bits        : {s.rx_bits}",
        "Test-Duration=0 msec",
    ))
