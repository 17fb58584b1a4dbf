"""HTTP transport of the esd web interface (manual chapter 6): stdlib ThreadingHTTPServer on 127.0.0.1.

The pages themselves are :mod:`.web_pages` (sans-I/O). This adapter reads one request with a body
size limit, hands it to :class:`~.web_pages.EsdWebApp` and writes the answer. Whatever a client
does (malformed request, huge or truncated body, disconnect mid-upload), it gets a 4xx or a closed
connection, never a traceback, and the server keeps serving.
"""

from __future__ import annotations

import contextlib
import ipaddress
import logging
import socket
import threading
from collections.abc import Callable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any, cast

from gatewaylab.common.errors import ConfigError
from gatewaylab.common.server_thread import ServerThread
from gatewaylab.devices.esd_can_ethercat.web_pages import EsdWebApp, EsdWebBackend, Request, Response

__all__ = ["DEFAULT_MAX_BODY", "EsdWebError", "EsdWebServer"]

log = logging.getLogger(__name__)

#: Largest request body accepted (a firmware image with room to spare); larger -> 413.
DEFAULT_MAX_BODY = 16 * 1024 * 1024
#: Seconds a connection may stay silent before the server drops it (a stalled upload).
DEFAULT_TIMEOUT = 10.0
#: At most this much of a refused body is read and discarded before the connection closes.
LINGER_BYTES = 1024 * 1024


class EsdWebError(ConfigError):
    """The web server cannot start (port in use, address not on this host's loopback)."""


class _HttpServer(ThreadingHTTPServer):
    daemon_threads = True

    def __init__(self, address: tuple[str, int], app: EsdWebApp, max_body: int, timeout: float) -> None:
        self.app = app
        self.max_body = max_body
        self.request_timeout = timeout
        self._active: set[socket.socket] = set()
        self._active_lock = threading.Lock()
        super().__init__(address, _Handler)

    def process_request(self, request: Any, client_address: Any) -> None:
        # registered in the accepting thread, so a connection accepted earlier is always known
        with self._active_lock:
            self._active.add(request)
        super().process_request(request, client_address)

    def process_request_thread(self, request: Any, client_address: Any) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            with self._active_lock:
                self._active.discard(request)

    def close_connections(self) -> None:
        """Cut every open connection (a stalled upload would otherwise hold its thread until the timeout)."""
        with self._active_lock:
            active = list(self._active)
        for sock in active:
            try:
                sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass

    def handle_error(self, request: object, client_address: object) -> None:
        # A client that vanished mid-request lands here; nothing to tell anyone but the debug log.
        log.debug("esd web: request from %s failed", client_address, exc_info=True)


class _Handler(BaseHTTPRequestHandler):
    _linger = False
    server_version = "esd-httpd/1.0"
    sys_version = ""
    # A request line the base class cannot parse is answered with a status line and headers too.
    default_request_version = "HTTP/1.0"

    def setup(self) -> None:
        super().setup()
        self.connection.settimeout(cast(_HttpServer, self.server).request_timeout)

    def log_message(self, format: str, *args: object) -> None:
        log.debug("esd web %s: " + format, self.address_string(), *args)

    def __getattr__(self, name: str) -> Callable[[], None]:
        # Every method name reaches _serve, so an unknown verb gets 405 with Allow, not 501.
        if name.startswith("do_"):
            return self._serve
        raise AttributeError(name)

    def send_error(self, code: int, message: str | None = None, explain: str | None = None) -> None:
        """The base class's errors (bad request line, 414, 431, 505) as a page in the device's frame."""
        title = message or self.responses.get(code, ("Error", ""))[0]
        text = explain or self.responses.get(code, ("", "The request cannot be served."))[1]
        self.close_connection = True
        self._write(cast(_HttpServer, self.server).app.error(code, title, text))

    def _serve(self) -> None:
        server = cast(_HttpServer, self.server)
        app = server.app
        self._linger = False
        try:
            response = self._answer(app, server.max_body)
        except Exception:
            log.exception("esd web: %s %s failed", self.command, self.path)
            response = app.error(500, "Internal Server Error", "The device could not answer this request.")
        if response is not None:
            self._write(response)
        if self._linger:
            self._lingering_close()

    def _refuse_body(self, response: Response) -> Response:
        # Answer without reading the body: close afterwards, but only after the client had a chance
        # to read the answer (closing on unread data would reset the connection under it).
        self.close_connection = True
        self._linger = True
        return response

    def _answer(self, app: EsdWebApp, max_body: int) -> Response | None:
        """The response to write, or None when the client is gone (connection closed silently)."""
        if self.headers.get("Transfer-Encoding"):
            return self._refuse_body(app.error(411, "Length Required", "Send the body with a Content-Length."))
        length_text = self.headers.get("Content-Length")
        if length_text is None:
            if self.command == "POST":
                return self._refuse_body(app.error(411, "Length Required", "Send the body with a Content-Length."))
            length_text = "0"
        length_text = length_text.strip()
        if not (length_text.isascii() and length_text.isdigit()):
            return self._refuse_body(app.error(400, "Bad Request", "Content-Length is not a number of bytes."))
        length = int(length_text)
        if length > max_body:
            return self._refuse_body(app.error(413, "Content Too Large", f"The body is larger than {max_body} bytes."))
        body = self._read_body(length)
        if len(body) < length:
            self.close_connection = True
            return None  # the client stopped sending (disconnect or timeout): nobody to answer
        return app.handle(Request(self.command, self.path, self.headers.get("Content-Type", ""), body))

    def _lingering_close(self) -> None:
        """Stop sending, then discard what the client still sends (up to LINGER_BYTES, until it closes
        or the timeout), so it reads the error answer instead of a connection reset."""
        try:
            self.connection.shutdown(socket.SHUT_WR)
            drained = 0
            while drained < LINGER_BYTES:
                chunk = self.connection.recv(65536)
                if not chunk:
                    break
                drained += len(chunk)
        except OSError:
            pass

    def _read_body(self, length: int) -> bytes:
        chunks: list[bytes] = []
        remaining = length
        try:
            while remaining:
                chunk = self.rfile.read(min(remaining, 65536))
                if not chunk:
                    break
                chunks.append(chunk)
                remaining -= len(chunk)
        except OSError:  # timeout or reset mid-upload
            pass
        return b"".join(chunks)

    def _write(self, response: Response) -> None:
        try:
            self.send_response(response.status)
            for name, value in response.headers:
                self.send_header(name, value)
            self.send_header("Content-Length", str(len(response.body)))
            if self.close_connection:
                self.send_header("Connection", "close")
            self.end_headers()
            if self.command != "HEAD":
                self.wfile.write(response.body)
        except OSError:
            self.close_connection = True


def _check_loopback(host: str) -> None:
    try:
        loopback = ipaddress.IPv4Address(host).is_loopback
    except ValueError:
        loopback = False
    if not loopback:
        raise EsdWebError(f"esd web server: host {host!r} is not an IPv4 loopback address (127.x.x.x)")


class EsdWebServer:
    """The web interface of one esd CAN-EtherCAT (manual chapter 6) on 127.0.0.1.

    The server thread calls ``backend`` only inside ``with lock:`` (the rig passes the clock's
    lock; docs/architecture.md "Threads"). ``port=0`` takes any free port; :meth:`start` returns
    the base URL. ``max_body`` bounds a request body (413 beyond), ``timeout`` drops a silent
    connection, ``refresh`` is the reload interval of the update progress page (Figure 39).
    """

    def __init__(self, backend: EsdWebBackend, lock: contextlib.AbstractContextManager[object],
                 host: str = "127.0.0.1", port: int = 0, *, max_body: int = DEFAULT_MAX_BODY,
                 timeout: float = DEFAULT_TIMEOUT, refresh: float = 1.0) -> None:
        _check_loopback(host)
        self.app = EsdWebApp(backend, lock, refresh)
        self.host = host
        self.port = port
        self.max_body = max_body
        self.timeout = timeout
        self._httpd: _HttpServer | None = None
        self._thread: ServerThread | None = None

    @property
    def url(self) -> str | None:
        """The base URL while running, else None."""
        if self._httpd is None:
            return None
        return f"http://{self.host}:{self._httpd.server_address[1]}/"

    def start(self) -> str:
        """Listen and serve in a daemon thread; returns ``"http://127.0.0.1:PORT/"``.

        A port in use raises one :class:`EsdWebError` and leaves no socket or thread behind.
        """
        if self._httpd is not None:
            raise EsdWebError("esd web server already started")
        self.app.closed = False
        try:
            httpd = _HttpServer((self.host, self.port), self.app, self.max_body, self.timeout)
        except OSError as exc:
            # socketserver closes its socket itself when bind/listen fail
            reason = exc.strerror or str(exc)
            raise EsdWebError(f"esd web server cannot listen on {self.host}:{self.port}: {reason}") from None
        thread = ServerThread(httpd, f"esd-web-{httpd.server_address[1]}")
        self._httpd, self._thread = httpd, thread
        thread.start()
        url = self.url
        assert url is not None
        return url

    def stop(self) -> None:
        """Stop serving, join the thread, close the listening socket and open connections; idempotent.

        After it returns the backend is not called again, also by a request that still waits for the
        lock (it gets 503). The caller may hold the lock (the rig stops its devices holding the clock's).
        """
        httpd, thread = self._httpd, self._thread
        self._httpd = self._thread = None
        if httpd is None:
            return
        with self.app.lock:
            self.app.closed = True
        if thread is not None:
            thread.stop()
        httpd.close_connections()
        httpd.server_close()
