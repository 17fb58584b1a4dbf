"""``gatewaylab run --web`` (issue 14, "Watch": a page on 127.0.0.1 with the node table and decoded log
updating live by server-sent events, and a drive plot; tested in a real browser: Playwright driving Debian's
chromium, a node's state changes on the page when a client sends NMT, and the page shows the frame a client
sent)."""

from __future__ import annotations

import json
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import can
import pytest
from browser_kit import chromium

from gatewaylab.rig.process import RigProcess

RIG = """
clock = "realtime"
[[bus]]
name = "can0"
bitrate = 1000000
[[drive]]
bus = "can0"
node_id = 2
serial = 0x1002
"""


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[RigProcess]:
    rig_file = tmp_path / "rig.toml"
    rig_file.write_text(RIG)
    with RigProcess(rig_file, "--web", workdir=tmp_path, timeout=30) as process:
        yield process


def get(url: str) -> tuple[int, str, bytes]:
    try:
        with urllib.request.urlopen(url, timeout=10) as r:
            return r.status, r.headers.get("Content-Type", ""), r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, "", b""


def send(rig: RigProcess, can_id: int, data: bytes) -> None:
    with can.Bus(interface="gatewaylab", channel=rig.endpoint("can0")) as bus:
        bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))


def wait_state(url: str, check: object, timeout: float = 20) -> dict:
    deadline = time.monotonic() + timeout
    while True:
        state = json.loads(get(url + "state")[2])
        if check(state):   # type: ignore[operator]
            return state
        assert time.monotonic() < deadline, state
        time.sleep(0.1)


def node(state: dict, node_id: int) -> dict | None:
    return next((n for n in state["buses"]["can0"]["nodes"] if n["node"] == node_id), None)


def test_state_and_events_over_plain_http(rig: RigProcess) -> None:
    """The ready file lists the page (web.monitor); /state follows NMT (CiA 301 7.2.8.3.1) as a client sends
    it; /events is a text/event-stream; unknown paths are 404."""
    url = rig.info["web"]["monitor"]
    assert url.startswith("http://127.0.0.1:")
    status, ctype, body = get(url)
    assert status == 200 and ctype.startswith("text/html") and b"EventSource" in body
    send(rig, 0x000, bytes((0x01, 2)))          # NMT start node 2
    state = wait_state(url, lambda s: (node(s, 2) or {}).get("nmt") == "Operational")
    assert any("NMT start" in e["text"] for e in state["log"])
    with urllib.request.urlopen(url + "events", timeout=10) as stream:
        assert stream.headers["Content-Type"] == "text/event-stream"
        first = stream.readline().decode()
        assert first.startswith("event: ")
    assert get(url + "nope")[0] == 404


def test_page_in_a_real_browser(rig: RigProcess, tmp_path: Path) -> None:
    """Chromium (Playwright, Debian's browser) shows node 2 changing to Operational when a client sends NMT
    start, and the frame another client sent in the decoded log; a screenshot is written."""
    url = rig.info["web"]["monitor"]
    with chromium() as browser:
        page = browser.new_page()
        page.goto(url)
        page.wait_for_selector("#buses h2", timeout=20_000)        # the first state event arrived
        nmt = "document.querySelector('#node-can0-2 .nmt')"
        # a lone drive's boot-up waits for an acknowledging node: the client's connection is one
        send(rig, 0x000, bytes((0x80, 2)))                       # enter pre-operational
        page.wait_for_function(f"{nmt} && {nmt}.textContent === 'Pre-operational'", timeout=20_000)
        send(rig, 0x000, bytes((0x01, 2)))                       # start: the page's table changes
        page.wait_for_function(f"{nmt}.textContent === 'Operational'", timeout=20_000)
        send(rig, 0x123, b"\xde\xad\xbe\xef")
        page.wait_for_function("document.getElementById('log').textContent.includes('DE AD BE EF')",
                               timeout=20_000)
        shot = tmp_path / "page.png"
        page.screenshot(path=str(shot))
        assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
