"""The pages of the esd web interface over plain HTTP (manual chapter 6 "Webserver Interface")."""

from __future__ import annotations

import html
import re
from collections.abc import Iterator
from dataclasses import replace

import pytest
from esd_web_kit import (
    CAN_STATUS,
    DEVICE_INFO,
    FIGURE_41_LINES,
    FakeBackend,
    OwnedLock,
    request,
    serving,
)
from hypothesis import given
from hypothesis import strategies as st

from gatewaylab.devices.esd_can_ethercat.web import format_can_status
from gatewaylab.devices.esd_can_ethercat.web_pages import EsdWebApp, Request

PAGES = ("/", "/firmware", "/reboot", "/status/can", "/information", "/contact")
MENU = ("Overview", "Configuration", "Firmware update", "Reboot", "Status", "CAN", "Information", "Contact")


@pytest.fixture
def backend() -> FakeBackend:
    return FakeBackend(OwnedLock())


@pytest.fixture
def url(backend: FakeBackend) -> Iterator[str]:
    with serving(backend) as base:
        yield base


def _pre(page: str, element_id: str) -> str:
    match = re.search(rf'<pre id="{element_id}">\n(.*?)\n</pre>', page, re.S)
    assert match, f"no <pre id={element_id}> on the page"
    return html.unescape(match.group(1))


@pytest.mark.parametrize("path", PAGES)
def test_every_page_has_the_manuals_frame_and_menu(url: str, backend: FakeBackend, path: str) -> None:
    """6.1.1 Figure 37: "The browser window provides a menu on the left hand side"; the header reads
    "EtherCAT-CAN-Gateway" / "esd gmbh, Hannover" (Figures 38, 41). The backend is only called under the lock."""
    reply = request(url, "GET", path)
    assert reply.status == 200
    assert reply.headers["content-type"] == "text/html; charset=utf-8"
    assert int(reply.headers["content-length"]) == len(reply.body)
    page = reply.text
    assert "EtherCAT-CAN-Gateway" in page and "esd gmbh, Hannover" in page
    menu = re.search(r'<div id="menu">(.*?)<div id="logo">', page, re.S)
    assert menu is not None
    labels = re.findall(r">([^<>]+)</(?:a|span)>", menu.group(1))
    assert tuple(labels) == MENU
    links = dict(re.findall(r'href="([^"]+)">([^<]+)</a>', menu.group(1)))
    assert links == {"/": "Overview", "/firmware": "Firmware update", "/reboot": "Reboot",
                     "/status/can": "CAN", "/information": "Information", "/contact": "Contact"}
    assert f'class="sub here" href="{path}"' in page or f'class="here" href="{path}"' in page
    assert backend.calls_outside_lock == []


def test_can_status_page_reproduces_figure_41(url: str) -> None:
    """6.2.1 Figure 41 "CAN status output": bit rate value set, actual bit rate, time quanta, sample point,
    Rcv/Xmit frames "Std(Data/RTR): a/b Ext(Data/RTR) c/d", bytes, overruns, error frames, aborted frames,
    error counters and status, each on its line as the figure prints it, with the backend's values."""
    text = _pre(request(url, "GET", "/status/can").text, "can")
    lines = text.splitlines()
    for line in FIGURE_41_LINES:
        assert line in lines, line
    # the figure's order: bit rate block (test 84) before the bus statistic (test 64)
    assert lines.index("CAN bitrate:") < lines.index(FIGURE_41_LINES[0]) < lines.index("CAN bus statistic:")
    assert lines.index("CAN bus statistic:") < lines.index(FIGURE_41_LINES[6]) < lines.index(FIGURE_41_LINES[-1])
    assert "      Baudrate=00000002  Status=000a  Features=07f2" in lines


def test_can_status_page_follows_the_backend(backend: FakeBackend) -> None:
    """6.2.1: the page shows the current statistics, not a snapshot: new counters on the next load.
    The figure's own numbers (all 0, 500 kbit/s, 20 tq, 85 %) give the figure's lines."""
    figure = replace(CAN_STATUS, rx_std_data=0, rx_std_rtr=0, rx_ext_data=0, rx_ext_rtr=0, tx_std_data=0,
                     tx_std_rtr=0, tx_ext_data=0, tx_ext_rtr=0, rx_bytes=0, tx_bytes=0, overruns=0,
                     fifo_overruns=0, error_frames=0, aborted_frames=0, rx_error_counter=0, tx_error_counter=0,
                     status="00", rx_bits=0)
    with serving(backend) as url:
        backend.can_view = figure
        lines = _pre(request(url, "GET", "/status/can").text, "can").splitlines()
        assert "Rcv frames      : Std(Data/RTR): 0/0 Ext(Data/RTR) 0/0" in lines
        assert "Err counter     : (Rx/Tx): 0/0 Status: 00" in lines
        assert "Overruns       : (Controller/FIFO): 0/0" in lines
        backend.can_view = replace(figure, bitrate_set="0x7fffffff", bitrate_actual=0, time_quanta=0,
                                   sample_point=0.0, rx_error_counter=128, status="40")
        lines = _pre(request(url, "GET", "/status/can").text, "can").splitlines()
        assert "Value set by canSetBaudrate() : 0x7fffffff" in lines
        assert "Actual Bitrate                 : 0 Bits/s" in lines
        assert "Err counter     : (Rx/Tx): 128/0 Status: 40" in lines


def test_format_can_status_splits_the_time_quanta_at_the_sample_point() -> None:
    """6.2.1 Figure 41: 20 tq at 85.0 % -> 17 before, 3 after the sample point; 16 tq at 87.5 % -> 14/2."""
    text = format_can_status(replace(CAN_STATUS, time_quanta=16, sample_point=87.5, bitrate_actual=1_000_000))
    assert "Timequantas before samplepoint : 14" in text.splitlines()
    assert "Timequantas after samplepoint  : 2" in text.splitlines()
    assert "Position samplepoint           : 87.5%" in text.splitlines()
    assert "Actual Bitrate                 : 1000000 Bits/s" in text.splitlines()


def test_information_page_lists_the_identity(url: str) -> None:
    """Menu item "Information" (6.1.1 Figure 37): identity of 5.1.3.5 (vendor 0x17, product 2, revision,
    serial), versions of 5.1.3.3/5.1.3.4, EtherCAT state and the backend's extra rows."""
    page = request(url, "GET", "/information").text
    rows = dict(re.findall(r"<tr><td>([^<]*)</td><td>([^<]*)</td></tr>", page))
    assert rows == {
        "Product": "CAN-EtherCAT", "Serial number": "BDC1E240", "Hardware version": "1.2",
        "Firmware version": "2.1", "Bootloader version": "1.0", "Vendor ID": "0x00000017",
        "Product code": "0x00000002", "Revision": "0x00000001", "EtherCAT state": "OP",
        "Station address": "0x1001", "CAN bus": "can0",
    }


def test_overview_names_the_device(url: str) -> None:
    """6.1.1 Figure 37: the Overview is the start page at the device's address."""
    page = request(url, "GET", "/").text
    assert "<h2>Overview</h2>" in page
    assert "<td>Firmware version</td><td>2.1</td>" in page
    assert "<td>EtherCAT state</td><td>OP</td>" in page


def test_reboot_page_has_the_reboot_now_button(url: str, backend: FakeBackend) -> None:
    """6.1.3 Figure 40: "choose the menu item Reboot; then click the Reboot now command button"; only the
    button (a POST) restarts the device, loading the page does not."""
    page = request(url, "GET", "/reboot").text
    assert '<form method="post" action="/reboot">' in page and 'value="Reboot now"' in page
    assert backend.reboots == 0
    reply = request(url, "POST", "/reboot", b"", {"Content-Type": "application/x-www-form-urlencoded"})
    assert reply.status == 200 and "Rebooting now" in reply.text
    assert backend.reboots == 1


def test_every_value_is_html_escaped(backend: FakeBackend) -> None:
    """Chapter 6 pages show device values; none of them may become markup (e.g. a device name set over
    CoE or an upload's file name)."""
    evil = '<script>alert("x")</script>&'
    backend.info_view = replace(DEVICE_INFO, product=evil, firmware=evil, extra={evil: evil})
    backend.can_view = replace(CAN_STATUS, bitrate_set=evil, status=evil)
    with serving(backend) as url:
        for path in ("/", "/information", "/status/can"):
            page = request(url, "GET", path).text
            assert "<script>" not in page, path
            assert html.escape(evil) in page, path
        backend.progress = evil
        page = request(url, "GET", "/firmware").text
        assert "<script>" not in page and html.escape(evil) in page


@pytest.mark.parametrize("path", ["/nope", "/status", "/status/can/x", "/../etc/passwd", "/firmware.html", "//[",
                                  "http://127.0.0.1/status/cane"])
def test_unknown_paths_answer_404(url: str, path: str) -> None:
    """Only the pages of chapter 6 exist; anything else is 404 in the device's frame."""
    reply = request(url, "GET", path)
    assert reply.status == 404 and "404 Not Found" in reply.text


@pytest.mark.parametrize("target", ["/status/can?x=1", "/status/can#top", "http://127.0.0.1/status/can",
                                    "HTTP://localhost:80/status/can?y"])
def test_query_strings_and_absolute_form_reach_the_page(url: str, target: str) -> None:
    """A browser may append a query (cache busting); a client may send the absolute-form target
    (RFC 9112 3.2.2: a server must accept it): the same page."""
    reply = request(url, "GET", target)
    assert reply.status == 200 and '<pre id="can">' in reply.text


@pytest.mark.parametrize(("method", "path", "allow"), [
    ("POST", "/status/can", "GET, HEAD"), ("PUT", "/firmware", "GET, POST, HEAD"), ("DELETE", "/", "GET, HEAD"),
    ("PATCH", "/reboot", "GET, POST, HEAD"), ("FOO", "/information", "GET, HEAD"), ("POST", "/contact", "GET, HEAD"),
])
def test_wrong_methods_answer_405_with_allow(url: str, backend: FakeBackend, method: str, path: str,
                                             allow: str) -> None:
    """RFC 9110 15.5.6: a known page with a method it does not serve -> 405 and an Allow header; no side
    effect (no reboot, no update)."""
    reply = request(url, method, path, b"", {"Content-Length": "0"})
    assert reply.status == 405
    assert reply.headers["allow"] == allow
    assert backend.reboots == 0 and backend.uploads == []


def test_head_answers_headers_only(url: str) -> None:
    """HEAD on a page: same status and length as GET, no body."""
    get = request(url, "GET", "/status/can")
    head = request(url, "HEAD", "/status/can")
    assert head.status == 200 and head.body == b""
    assert head.headers["content-length"] == str(len(get.body))


@given(st.sampled_from(["GET", "HEAD", "POST", "PUT", "DELETE", "X"]),
       st.one_of(st.sampled_from(["/", "/firmware", "/reboot", "/status/can", "/information", "/contact"]),
                 st.text(max_size=40)),
       st.text(max_size=60), st.binary(max_size=200))
def test_pages_answer_any_request_without_raising(method: str, target: str, content_type: str, body: bytes) -> None:
    """The sans-I/O pages (EsdWebApp) answer any request line, content type and body with a page, a
    redirect or a 4xx, never an exception (no traceback can reach a client)."""
    backend = FakeBackend(OwnedLock())
    app = EsdWebApp(backend, backend.lock)
    response = app.handle(Request(method, target, content_type, body))
    assert response.status in {200, 303, 400, 404, 405, 415}
    assert backend.calls_outside_lock == []
