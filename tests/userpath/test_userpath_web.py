"""The web pages of a running rig in a real headless browser (issue 21, "The user's path as a suite"): the
rig's live page (``gatewaylab run --web``, docs/rig.md) and the esd CAN-EtherCAT web interface (manual
chapter 6; ``web_port``), both found through the ready file's ``web`` only. Playwright drives Debian's
chromium (shared/notes/browser-tests.md; never ``playwright install``); skips, saying why, without them.

The live page loads, shows the rig's buses and nodes, and follows the bus: a node's NMT state changes when a
python-can client sends NMT, frames a client sends show up in the decoded log. Latency: send -> shown on the
page for the first frame after the page loaded and for a stream of frames (p99), generous bounds for a
browser on a shared machine.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from typing import Any

import can
import pytest
from browser_kit import chromium, require_browser
from userpath_kit import Latencies, bound, measured

from gatewaylab.rig.process import RigProcess

require_browser()

RIG = """
clock = "realtime"

[[bus]]
name = "can0"
bitrate = 500000

[[drive]]
bus = "can0"
node_id = 2
serial = 0x1002

[[device]]
kind = "esd_can_ethercat"
name = "esd1"
bus = "can0"
web_port = 0
"""

WAIT_MS = 20_000    # the longest a page may take to show something (no timing assert)


@pytest.fixture(scope="module")
def rig(start_rig: Callable[..., RigProcess]) -> RigProcess:
    return start_rig(RIG, "--web")


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    with chromium() as b:
        yield b


@pytest.fixture
def page(browser: Any) -> Iterator[Any]:
    context = browser.new_context()
    try:
        yield context.new_page()
    finally:
        context.close()


@measured
def test_live_page_shows_buses_and_nodes_and_follows_the_bus(rig: RigProcess, page: Any) -> None:
    """docs/rig.md `--web`: the node table (bus can0, drive 2 and the NMT state a client commands, CiA 301
    7.2.8.3.1) and the decoded log update by server-sent events while the page stays open. Latency: a
    frame sent by a python-can client -> its bytes on the page, for the first and for 30 more."""
    url = rig.info["web"]["monitor"]
    loading = time.time()
    response = page.goto(url)
    assert response is not None and response.status == 200
    page.wait_for_selector("#buses h2", timeout=WAIT_MS)             # the first state event arrived
    print(f"\nlive page: loaded with state after {(time.time() - loading) * 1e3:.0f} ms")
    assert "can0" in page.inner_text("#buses")
    nmt = "document.querySelector('#node-can0-2 .nmt')"
    lat = Latencies("live page: frame sent -> shown in the log")
    with can.Bus(interface="gatewaylab", channel=rig.info["buses"]["can0"]["endpoint"]) as bus:
        bus.send(can.Message(arbitration_id=0x000, data=bytes((0x80, 2)), is_extended_id=False))  # pre-operational
        page.wait_for_function(f"{nmt} && {nmt}.textContent === 'Pre-operational'", timeout=WAIT_MS)
        bus.send(can.Message(arbitration_id=0x000, data=bytes((0x01, 2)), is_extended_id=False))  # start
        page.wait_for_function(f"{nmt}.textContent === 'Operational'", timeout=WAIT_MS)
        for seq in range(31):
            data = bytes((0xCA, 0xFE, 0x21, seq))
            sent = time.time()
            bus.send(can.Message(arbitration_id=0x123, data=data, is_extended_id=False))
            shown = data.hex(" ").upper()   # the log shows data as candump does: upper-case hex
            page.wait_for_function(f"document.getElementById('log').textContent.toUpperCase().includes('{shown}')",
                                   timeout=WAIT_MS, polling=5)
            if seq == 0:
                lat.first = time.time() - sent
            else:
                lat.add(time.time() - sent)
    # a browser driven through Playwright on a shared machine: generous
    lat.check(first_bound=2.0, median_bound=0.25, p99_bound=1.0)
    assert "Operational" in page.inner_text("#node-can0-2")


@measured
def test_esd_web_interface_is_served_by_a_rig_without_ethercat(rig: RigProcess, page: Any) -> None:
    """Manual 6.1.1 (Figure 37 menu) and 6.2.1 (Figure 41 'CAN' status): the esd gateway's pages, served by a
    rig that has the gateway on its CAN bus but no EtherCAT segment; with no master there is no bit rate set
    (the page says so in its fields) and the pages load and render in the browser."""
    url = rig.info["web"]["esd1"]
    loading = time.time()
    response = page.goto(url)
    assert response is not None and response.status == 200
    assert page.title().startswith("EtherCAT-CAN-Gateway")
    menu = page.inner_text("#menu")
    for label in ("Overview", "Firmware update", "Reboot", "CAN", "Information", "Contact"):
        assert label in menu
    page.click("#menu a[href='/status/can']")            # the user follows the menu
    page.wait_for_selector("#can", timeout=WAIT_MS)
    shown = page.inner_text("#can")
    first = time.time() - loading
    print(f"\nesd web: overview + CAN page in the browser after {first * 1e3:.0f} ms")
    for field in ("Actual Bitrate", "Rcv frames", "Xmit frames", "Err counter"):
        assert field in shown
    assert page.title() == "EtherCAT-CAN-Gateway - CAN"
    bound(first, 5.0, "esd web: overview + CAN page")
