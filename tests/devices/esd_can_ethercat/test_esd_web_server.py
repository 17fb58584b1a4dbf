"""The esd web server's transport (manual chapter 6: "The CAN-EtherCAT gateway uses an internal HTTP server"):
start/stop, a port in use, body limits, clients that misbehave, backend failures. Whatever a client does it
gets a 4xx (or a closed connection), never a traceback, and the next client is served."""

from __future__ import annotations

import http.client
import socket
import threading
from collections.abc import Iterator
from urllib.parse import urlsplit

import pytest
from esd_web_kit import FIRMWARE_MAGIC, FakeBackend, OwnedLock, multipart, request, serving, upload

from gatewaylab.common.errors import ConfigError
from gatewaylab.devices.esd_can_ethercat.web import EsdWebError, EsdWebServer


@pytest.fixture
def backend() -> FakeBackend:
    return FakeBackend(OwnedLock())


@pytest.fixture
def url(backend: FakeBackend) -> Iterator[str]:
    with serving(backend, max_body=4096, timeout=2.0) as base:
        yield base


def _port(url: str) -> int:
    port = urlsplit(url).port
    assert port is not None
    return port


def _raw(url: str, data: bytes, close_after_send: bool = False) -> bytes:
    """Send raw bytes, return everything the server answers until it closes the connection."""
    with socket.create_connection(("127.0.0.1", _port(url)), timeout=30) as sock:
        sock.sendall(data)
        if close_after_send:
            return b""
        chunks = []
        while True:
            try:
                chunk = sock.recv(65536)
            except ConnectionResetError:
                break
            if not chunk:
                break
            chunks.append(chunk)
        return b"".join(chunks)


def _web_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name.startswith("esd-web-")]


def test_start_returns_the_base_url_on_loopback_and_stop_releases_everything(backend: FakeBackend) -> None:
    """Issue 11 rig contract: the base URL "http://127.0.0.1:PORT/" (port 0 = any free port); stop() joins
    the thread and closes the listening socket (a new connection is refused)."""
    server = EsdWebServer(backend, backend.lock)  # type: ignore[arg-type]
    url = server.start()
    assert url.startswith("http://127.0.0.1:") and url.endswith("/") and _port(url) > 0
    assert server.url == url
    assert request(url, "GET", "/").status == 200
    assert len(_web_threads()) == 1
    server.stop()
    assert _web_threads() == [] and server.url is None
    with pytest.raises(ConnectionRefusedError):
        socket.create_connection(("127.0.0.1", _port(url)), timeout=5).close()
    server.stop()  # idempotent


def test_port_in_use_raises_one_clean_error_and_leaves_nothing_behind(backend: FakeBackend) -> None:
    """Issue 11 `web_port`: a port taken by someone else -> one EsdWebError (a ConfigError) naming the
    address, no thread, no socket; the same server object starts on a free port afterwards."""
    with socket.socket() as blocker:
        blocker.bind(("127.0.0.1", 0))
        blocker.listen()
        port = blocker.getsockname()[1]
        server = EsdWebServer(backend, backend.lock, port=port)  # type: ignore[arg-type]
        with pytest.raises(EsdWebError) as caught:
            server.start()
    assert isinstance(caught.value, ConfigError)
    assert f"127.0.0.1:{port}" in str(caught.value)
    assert caught.value.__cause__ is None and caught.value.__suppress_context__
    assert _web_threads() == [] and server.url is None
    server.port = 0
    url = server.start()
    try:
        assert request(url, "GET", "/").status == 200
    finally:
        server.stop()


@pytest.mark.parametrize("host", ["0.0.0.0", "192.168.1.1", "::1", "localhost.example"])
def test_only_loopback_addresses(backend: FakeBackend, host: str) -> None:
    """DEVELOPERS.md "servers bind to 127.0.0.1": any other address is refused before binding."""
    with pytest.raises(EsdWebError):
        EsdWebServer(backend, backend.lock, host=host)  # type: ignore[arg-type]


def test_body_over_the_limit_answers_413_without_reading_it(url: str, backend: FakeBackend) -> None:
    """A body larger than the server's limit is refused from its Content-Length alone (413)."""
    reply = _raw(url, b"POST /firmware HTTP/1.1\r\nHost: x\r\nContent-Type: multipart/form-data; boundary=b\r\n"
                      b"Content-Length: 1000000000\r\n\r\n")
    assert reply.startswith(b"HTTP/1.0 413 ")
    assert b"Traceback" not in reply
    assert backend.uploads == []
    assert request(url, "GET", "/").status == 200


def test_upload_just_under_and_over_the_limit(url: str, backend: FakeBackend) -> None:
    """The limit counts the whole body: a file that fits is taken, one byte more is 413; the client that
    sent the too-large body reads the 413 (the server discards the rest instead of resetting)."""
    _, body = multipart("fw.bin", b"")
    fits = FIRMWARE_MAGIC + bytes(4096 - len(body) - len(FIRMWARE_MAGIC))
    assert upload(url, "fw.bin", fits).status == 303
    backend.progress = None
    reply = upload(url, "fw.bin", fits + b"x")
    assert reply.status == 413 and "The body is larger than 4096 bytes." in reply.text
    assert len(backend.uploads) == 1


def test_huge_upload_streamed_in_full(url: str, backend: FakeBackend) -> None:
    """A client that sends a body far over the limit anyway gets the 413 or a closed connection, never a
    started update, and the server keeps serving."""
    try:
        status = upload(url, "huge.bin", FIRMWARE_MAGIC + bytes(8 * 1024 * 1024)).status
    except ConnectionError:  # the server closed after discarding its share of the body
        status = 413
    assert status == 413
    assert backend.uploads == []
    assert request(url, "GET", "/status/can").status == 200


@pytest.mark.parametrize(("method", "path", "status"), [("POST", "/nope", 404), ("POST", "/status/can", 405),
                                                          ("PUT", "/firmware", 405)])
def test_refused_requests_with_a_body_read_their_answer(url: str, method: str, path: str, status: int) -> None:
    """A body sent to a page that does not take it is read and dropped: the client gets the 404/405, not a
    reset connection."""
    content_type, body = multipart("fw.bin", FIRMWARE_MAGIC + bytes(3000))
    reply = request(url, method, path, body, {"Content-Type": content_type})
    assert reply.status == status


@pytest.mark.parametrize(("head", "status"), [
    (b"POST /firmware HTTP/1.1\r\nHost: x\r\n\r\n", b"411"),
    (b"POST /firmware HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n0\r\n\r\n", b"411"),
    (b"POST /firmware HTTP/1.1\r\nHost: x\r\nContent-Length: -5\r\n\r\n", b"400"),
    (b"POST /firmware HTTP/1.1\r\nHost: x\r\nContent-Length: zwei\r\n\r\n", b"400"),
    (b"POST /firmware HTTP/1.1\r\nHost: x\r\nContent-Length: 1_0\r\n\r\n", b"400"),
    (b"GET / HTTP/1.1\r\nHost: x\r\nContent-Length: 99999999999999999999999\r\n\r\n", b"413"),
    (b"GARBAGE\r\n\r\n", b"400"),
    (b"GET /" + b"a" * 70000 + b" HTTP/1.1\r\n\r\n", b"414"),
    (b"GET / HTTP/1.1\r\n" + b"X: y\r\n" * 200 + b"\r\n", b"431"),
    (b"GET / HTTP/9.9\r\n\r\n", b"505"),
])
def test_malformed_requests_answer_4xx(url: str, head: bytes, status: bytes) -> None:
    """Malformed request lines, lengths and header floods: an error status, never a traceback; then the
    next client is served. (505 is the one 5xx: RFC 9110 15.6.6 for an HTTP version not supported.)"""
    reply = _raw(url, head)
    assert reply.split(b" ", 2)[1] == status, reply[:200]
    assert b"Traceback" not in reply
    assert request(url, "GET", "/status/can").status == 200


def test_client_that_disconnects_mid_upload(url: str, backend: FakeBackend) -> None:
    """A browser closed during the upload (6.1.2 "if your browser times out"): the server drops the half
    body, starts nothing and keeps serving."""
    content_type, body = multipart("fw.bin", FIRMWARE_MAGIC + bytes(3000))
    head = (f"POST /firmware HTTP/1.1\r\nHost: x\r\nContent-Type: {content_type}\r\n"
            f"Content-Length: {len(body)}\r\n\r\n").encode()
    _raw(url, head + body[:1000], close_after_send=True)
    assert request(url, "GET", "/firmware").status == 200
    assert backend.uploads == []


def test_client_that_stalls_mid_upload_is_dropped(url: str, backend: FakeBackend) -> None:
    """A client that stops sending without closing is cut off after the server's timeout (closed
    connection, no answer, nothing started); meanwhile other clients are served."""
    content_type, body = multipart("fw.bin", FIRMWARE_MAGIC + bytes(3000))
    head = (f"POST /firmware HTTP/1.1\r\nHost: x\r\nContent-Type: {content_type}\r\n"
            f"Content-Length: {len(body)}\r\n\r\n").encode()
    with socket.create_connection(("127.0.0.1", _port(url)), timeout=30) as sock:
        sock.sendall(head + body[:1000])
        assert request(url, "GET", "/status/can").status == 200  # served while the other one stalls
        assert sock.recv(1000) == b""  # the server closed it, without an answer
    assert backend.uploads == []


def test_backend_failure_answers_500_without_details(url: str, backend: FakeBackend) -> None:
    """A failing device (a bug, not a refusal) gives a generic 500 page: no traceback, no exception text
    to the client; the server keeps serving."""
    backend.fail_with = RuntimeError("secret internal detail")
    reply = request(url, "GET", "/status/can")
    assert reply.status == 500
    assert "Traceback" not in reply.text and "secret internal detail" not in reply.text
    assert "500 Internal Server Error" in reply.text
    reply = upload(url, "fw.bin", FIRMWARE_MAGIC)
    assert reply.status == 500 and "secret" not in reply.text
    backend.fail_with = None
    assert request(url, "GET", "/status/can").status == 200


def test_backend_is_called_only_under_the_lock_and_waits_for_it(backend: FakeBackend) -> None:
    """docs/architecture.md "Threads": the server thread touches the device only inside `with lock:`; while
    another thread (the rig's runtime) holds the lock, a page waits for it."""
    with serving(backend) as url:
        result: list[int] = []
        with backend.lock:
            worker = threading.Thread(target=lambda: result.append(request(url, "GET", "/status/can").status))
            worker.start()
            worker.join(0.5)
            assert worker.is_alive() and result == []  # blocked on the lock, not answered without it
        worker.join(30)
        assert result == [200]
        for path in ("/", "/firmware", "/information"):
            request(url, "GET", path)
        upload(url, "fw.bin", FIRMWARE_MAGIC)
        request(url, "POST", "/reboot", b"")
    assert backend.calls_outside_lock == []
    assert backend.reboots == 1 and len(backend.uploads) == 1


def test_stop_cuts_stalled_clients(backend: FakeBackend) -> None:
    """stop() closes open connections too: a client stalled mid-upload sees its connection end at once
    (the server's own idle timeout here is an hour), and the upload never reaches the device."""
    server = EsdWebServer(backend, backend.lock, timeout=3600.0)  # type: ignore[arg-type]
    url = server.start()
    content_type, body = multipart("fw.bin", FIRMWARE_MAGIC + bytes(3000))
    head = (f"POST /firmware HTTP/1.1\r\nHost: x\r\nContent-Type: {content_type}\r\n"
            f"Content-Length: {len(body)}\r\n\r\n").encode()
    with socket.create_connection(("127.0.0.1", _port(url)), timeout=30) as sock:
        sock.sendall(head + body[:1000])
        assert request(url, "GET", "/").status == 200  # accepted after the stalled one, so that one is known
        server.stop()
        try:
            assert sock.recv(1000) == b""
        except ConnectionResetError:
            pass
    assert backend.uploads == []


def test_no_backend_call_after_stop_even_for_a_waiting_request(backend: FakeBackend) -> None:
    """The rig stops its devices holding the clock's lock (docs/architecture.md "Threads"); a request
    waiting for that lock must not reach the device after stop() returned: it gets 503 or a closed
    connection."""
    server = EsdWebServer(backend, backend.lock)  # type: ignore[arg-type]
    url = server.start()
    outcome: list[object] = []

    def fetch() -> None:
        try:
            outcome.append(request(url, "GET", "/status/can").status)
        except (ConnectionError, http.client.HTTPException) as exc:
            outcome.append(type(exc))

    with backend.lock:
        worker = threading.Thread(target=fetch)
        worker.start()
        worker.join(0.5)  # usually blocked on the lock by now; either way the outcome below holds
        server.stop()
        calls_at_stop = len(backend.calls)
    worker.join(30)
    assert not worker.is_alive()
    assert len(backend.calls) == calls_at_stop == 0
    assert outcome and outcome[0] != 200
    server.stop()


def test_restart_after_stop(backend: FakeBackend) -> None:
    """A rig that stops and starts a device again (reboot of the rig) gets a working server again."""
    server = EsdWebServer(backend, backend.lock)  # type: ignore[arg-type]
    server.start()
    server.stop()
    url = server.start()
    try:
        assert request(url, "GET", "/status/can").status == 200
    finally:
        server.stop()


def test_many_clients_at_once(url: str) -> None:
    """ThreadingHTTPServer: concurrent browsers each get their page."""
    statuses: list[int] = []
    lock = threading.Lock()

    def fetch() -> None:
        status = request(url, "GET", "/status/can").status
        with lock:
            statuses.append(status)

    workers = [threading.Thread(target=fetch) for _ in range(16)]
    for worker in workers:
        worker.start()
    for worker in workers:
        worker.join(60)
    assert statuses == [200] * 16
