"""Firmware update over the web pages (manual 6.1.2, Figures 38 and 39) and the multipart parser behind it."""

from __future__ import annotations

import html
from collections.abc import Iterator

import pytest
from esd_web_kit import FIGURE_39, FIRMWARE_MAGIC, FakeBackend, OwnedLock, multipart, request, serving, upload
from hypothesis import given
from hypothesis import strategies as st

from gatewaylab.devices.esd_can_ethercat.web_pages import MultipartError, parse_multipart


@pytest.fixture
def backend() -> FakeBackend:
    return FakeBackend(OwnedLock())


@pytest.fixture
def url(backend: FakeBackend) -> Iterator[str]:
    with serving(backend) as base:
        yield base


def test_form_is_figure_38(url: str) -> None:
    """6.1.2 Figure 38: "This page is intended to upload new software to the EtherCAT-CAN-Gateway.", the
    Important note, a file field, the "Start update" button, and "do not power off the device!"."""
    page = request(url, "GET", "/firmware").text
    assert "This page is intended to upload new software to the EtherCAT-CAN-Gateway." in page
    assert "<b>Important:</b>" in page and "if your browser times out you have to reload this page" in page
    assert '<form method="post" action="/firmware" enctype="multipart/form-data">' in page
    assert '<input type="file" name="file"' in page and 'value="Start update"' in page
    assert "<b>do not power off the device!</b>" in page
    assert "Updating now..." not in page


def test_good_file_starts_the_update_and_the_page_shows_its_progress(url: str, backend: FakeBackend) -> None:
    """6.1.2: "The firmware update starts after confirmation ... The progress of the update is recorded."
    The upload answers 303 to the Firmware update page, which shows "Updating now..." and the output of
    Figure 39 (and reloads itself) while the update runs, and the form again once the device is back."""
    image = FIRMWARE_MAGIC + bytes(range(256)) * 100 + b"\r\n--not-a-boundary\r\n"
    reply = upload(url, "can_ethercat_2.2.bin", image)
    assert reply.status == 303 and reply.headers["location"] == "/firmware"
    assert backend.uploads == [("can_ethercat_2.2.bin", image)]
    page = request(url, "GET", "/firmware").text
    assert "Updating now..." in page
    assert f'<pre id="progress">\n{html.escape(FIGURE_39)}\n</pre>' in page
    assert '<meta http-equiv="refresh" content="1">' in page
    assert "<form" not in page
    backend.progress = None  # the device rebooted after the update (6.1.2 "automatic restart")
    page = request(url, "GET", "/firmware").text
    assert "Updating now..." not in page and "<form" in page and "http-equiv" not in page
    assert backend.calls_outside_lock == []


def test_bad_file_is_refused_with_the_reason(url: str, backend: FakeBackend) -> None:
    """6.1.2: a file the device does not take is refused: 400, the form again and the backend's one-line
    reason on the page; nothing starts."""
    reply = upload(url, "notes<1>.txt", b"hello")
    assert reply.status == 400
    assert '<p class="refused" id="refused">Update refused: notes&lt;1&gt;.txt: not an esd firmware image</p>' \
        in reply.text
    assert "<form" in reply.text
    assert backend.uploads == [] and backend.progress is None


def test_second_upload_during_an_update_is_refused(url: str, backend: FakeBackend) -> None:
    """6.1.2 NOTICE (do not interrupt an update): while one runs the page shows its progress, the reason
    of the refusal is the backend's."""
    assert upload(url, "a.bin", FIRMWARE_MAGIC).status == 303
    reply = upload(url, "b.bin", FIRMWARE_MAGIC)
    assert reply.status == 400
    assert "Updating now..." in reply.text
    assert "Update refused: an update is already running" in reply.text
    assert backend.uploads == [("a.bin", FIRMWARE_MAGIC)]


def test_no_file_selected(url: str, backend: FakeBackend) -> None:
    """6.1.2: Submit without choosing a file (a browser sends an empty part with filename="")."""
    content_type, body = multipart("", b"")
    reply = request(url, "POST", "/firmware", body, {"Content-Type": content_type})
    assert reply.status == 400 and "Update refused: no file selected" in reply.text
    content_type, body = multipart("x.bin", FIRMWARE_MAGIC, name="other")
    reply = request(url, "POST", "/firmware", body, {"Content-Type": content_type})
    assert reply.status == 400 and "Update refused: no file selected" in reply.text
    assert backend.uploads == []


@pytest.mark.parametrize(("content_type", "body", "status"), [
    ("application/x-www-form-urlencoded", b"file=abc", 415),
    ("", b"abc", 415),
    ("multipart/form-data", b"--x\r\n\r\n", 400),  # no boundary
    ("multipart/form-data; boundary=xyz", b"garbage", 400),
    ("multipart/form-data; boundary=xyz", b"--xyz\r\nContent-Disposition: form-data; name=\"file\"\r\n\r\nabc", 400),
    ("multipart/form-data; boundary=xyz", b"--xyz\r\nno colon here\r\n\r\nabc\r\n--xyz--\r\n", 400),
    ("multipart/form-data; boundary=xyz", b"--xyz\r\nContent-Disposition: attachment\r\n\r\nabc\r\n--xyz--", 400),
    ("multipart/form-data; boundary=" + "b" * 71, b"--" + b"b" * 71 + b"--", 400),
])
def test_malformed_uploads_answer_4xx(url: str, backend: FakeBackend, content_type: str, body: bytes,
                                      status: int) -> None:
    """A malformed form body (RFC 7578 / RFC 2046 5.1.1) answers 400 (415 for a body that is no form at all)
    without a traceback, and the server keeps serving."""
    reply = request(url, "POST", "/firmware", body, {"Content-Type": content_type})
    assert reply.status == status
    assert "Traceback" not in reply.text
    assert backend.uploads == []
    assert request(url, "GET", "/firmware").status == 200


def test_parse_multipart_golden() -> None:
    """RFC 7578 4.1 example shape: two fields, preamble-free, quoted parameters, epilogue ignored."""
    body = (b"--AaB03x\r\nContent-Disposition: form-data; name=\"submit-name\"\r\n\r\nLarry\r\n"
            b"--AaB03x\r\nContent-Disposition: form-data; name=\"files\"; filename=\"file1.txt\"\r\n"
            b"Content-Type: text/plain\r\n\r\n... contents of file1.txt ...\r\n--AaB03x--\r\nepilogue")
    parts = parse_multipart('multipart/form-data; boundary="AaB03x"', body)
    assert [(p.name, p.filename, p.data) for p in parts] == [
        ("submit-name", None, b"Larry"), ("files", "file1.txt", b"... contents of file1.txt ...")]


def test_parse_multipart_byte_by_byte_truncation_is_an_error() -> None:
    """Every strict prefix of a valid body (a client that stopped early) is a MultipartError, never a part
    list that silently lost data."""
    content_type, body = multipart("fw.bin", FIRMWARE_MAGIC + b"\x00\r\n\xff")
    assert parse_multipart(content_type, body)[0].data == FIRMWARE_MAGIC + b"\x00\r\n\xff"
    end = body.rindex(b"\r\n--")  # the closing delimiter line starts here
    for cut in range(end + 4):
        with pytest.raises(MultipartError):
            parse_multipart(content_type, body[:cut])


@given(st.binary(max_size=300), st.sampled_from(["multipart/form-data; boundary=xyz", "multipart/form-data",
                                                  "text/plain", "multipart/form-data; boundary=\"a b\""]))
def test_parse_multipart_only_raises_multipart_error(body: bytes, content_type: str) -> None:
    """Any bytes: parts or MultipartError, nothing else (DEVELOPERS.md: parsers raise only spec errors)."""
    try:
        parts = parse_multipart(content_type, b"--xyz\r\n" + body)
    except MultipartError:
        return
    assert all(isinstance(p.data, bytes) for p in parts)


@given(st.binary(max_size=200), st.text(max_size=20))
def test_parse_multipart_round_trip(data: bytes, filename: str) -> None:
    """What a browser encodes comes back unchanged, whatever the file holds."""
    safe_name = filename.replace('"', "").replace("\\", "").replace("\r", "").replace("\n", "")
    content_type, body = multipart(safe_name, data)
    if b"\r\n------esdweb7MA4YWxk" in data:
        return  # a browser picks a boundary that is not in the file
    [part] = parse_multipart(content_type, body)
    assert part.data == data and part.name == "file" and part.filename == safe_name
