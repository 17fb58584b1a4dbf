"""The esd web pages in a real headless browser (manual chapter 6; issue 11 "Tested in a real headless
browser (Chromium from Debian, installed by the Makefile when missing) with a screenshot check").

Playwright drives Debian's /usr/bin/chromium (never `playwright install`; see
../shared/notes/browser-tests.md). Skips, saying why, when Playwright or the browser is missing.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest
from browser_kit import chromium, require_browser
from esd_web_kit import FIGURE_39, FIGURE_41_LINES, FIRMWARE_MAGIC, FakeBackend, OwnedLock, png_pixels, serving

VIEWPORT = {"width": 1024, "height": 768}

sync_api = require_browser()


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    with chromium() as b:
        yield b


@pytest.fixture
def backend() -> FakeBackend:
    return FakeBackend(OwnedLock())


@pytest.fixture
def page(browser: Any, backend: FakeBackend, request: pytest.FixtureRequest) -> Iterator[tuple[Any, str]]:
    # the progress page reloads itself; a test that screenshots it asks for a slow reload (indirect param)
    refresh = float(getattr(request, "param", 1.0))
    with serving(backend, refresh=refresh) as url:
        context = browser.new_context(viewport=VIEWPORT)
        try:
            yield context.new_page(), url
        finally:
            context.close()


def _check_screenshot(png: bytes) -> None:
    width, height, colours = png_pixels(png)
    assert (width, height) == (VIEWPORT["width"], VIEWPORT["height"])
    assert len(colours) > 3, "the screenshot is blank"


def test_screenshot_check_sees_a_blank_page(page: tuple[Any, str]) -> None:
    """The check below can fail: a blank page's screenshot has one colour."""
    tab, _ = page
    tab.set_content("<html><body style='margin:0;background:#fff'></body></html>")
    width, height, colours = png_pixels(tab.screenshot())
    assert (width, height) == (VIEWPORT["width"], VIEWPORT["height"]) and len(colours) == 1


def test_status_can_page_in_chromium(page: tuple[Any, str]) -> None:
    """6.2.1 Figure 41 as a browser renders it: the text the user sees holds every field of the figure with
    the backend's values, the menu is there, and the screenshot is a non-blank PNG of the viewport."""
    tab, url = page
    response = tab.goto(url + "status/can")
    assert response is not None and response.status == 200
    assert tab.title() == "EtherCAT-CAN-Gateway - CAN"
    shown = tab.inner_text("#can")
    for line in FIGURE_41_LINES:
        assert line in shown.splitlines(), line
    menu = tab.inner_text("#menu")
    for label in ("Overview", "Firmware update", "Reboot", "CAN", "Information", "Contact"):
        assert label in menu
    _check_screenshot(tab.screenshot())


@pytest.mark.parametrize(("path", "heading", "text"), [
    ("", "Overview", "CAN-EtherCAT"),
    ("firmware", "Firmware Update", "This page is intended to upload new software to the EtherCAT-CAN-Gateway."),
    ("reboot", "Reboot", "Click the button to restart the EtherCAT-CAN-Gateway."),
    ("information", "Information", "0x00000017"),
    ("contact", "Contact", "Vahrenwalder Str. 207"),
])
def test_every_page_renders(page: tuple[Any, str], path: str, heading: str, text: str) -> None:
    """6.1.1-6.1.3 and the menu of Figure 37: each page loads, shows its heading and content, screenshots
    non-blank."""
    tab, url = page
    response = tab.goto(url + path)
    assert response is not None and response.status == 200
    assert tab.inner_text("h2") == heading
    assert text in tab.inner_text("#main")
    _check_screenshot(tab.screenshot())


def test_menu_navigation_reaches_the_can_status(page: tuple[Any, str]) -> None:
    """6.2.1: "Click the CAN menu item to access the CAN bus statistics"."""
    tab, url = page
    tab.goto(url)
    tab.click("#menu >> text=CAN")
    tab.wait_for_url(url + "status/can")
    assert "Rcv frames" in tab.inner_text("#can")


@pytest.mark.parametrize("page", [3600.0], indirect=True)
def test_firmware_update_through_the_form(page: tuple[Any, str], backend: FakeBackend, tmp_path: Any) -> None:
    """6.1.2: choose a file, click the button; a bad file is refused with the reason on the page, a good one
    starts the update and the page shows "Updating now..." and the output of Figure 39. Then 6.1.3:
    "Reboot now" restarts the device."""
    tab, url = page
    bad = tmp_path / "readme.txt"
    bad.write_bytes(b"not firmware")
    tab.goto(url + "firmware")
    tab.set_input_files("#file", str(bad))
    tab.click("#submit")
    assert "Update refused: readme.txt: not an esd firmware image" in tab.inner_text("#refused")
    good = tmp_path / "can_ethercat.bin"
    good.write_bytes(FIRMWARE_MAGIC + bytes(range(256)) * 64)
    tab.set_input_files("#file", str(good))
    tab.click("#submit")
    tab.wait_for_selector("#progress")
    assert "Updating now..." in tab.inner_text("#main")
    assert tab.inner_text("#progress").strip() == FIGURE_39
    assert backend.uploads == [("can_ethercat.bin", good.read_bytes())]
    _check_screenshot(tab.screenshot())
    backend.progress = None
    tab.goto(url + "reboot")
    tab.click("#reboot")
    tab.wait_for_selector("text=Rebooting now")
    assert backend.reboots == 1
    assert backend.calls_outside_lock == []


def test_progress_page_reloads_itself_until_the_device_is_back(page: tuple[Any, str], backend: FakeBackend) -> None:
    """6.1.2 Figure 39: the output grows while the update runs and "When finished the system will initiate
    an automatic restart": the open page follows by itself, without a click, and finally shows the form."""
    tab, url = page
    backend.progress = "End of file found. All good."
    tab.goto(url + "firmware")
    assert tab.inner_text("#progress").strip() == "End of file found. All good."
    with backend.lock:
        backend.progress = FIGURE_39
    sync_api.expect(tab.locator("#progress")).to_have_text(FIGURE_39, timeout=30_000)
    with backend.lock:
        backend.progress = None
    tab.wait_for_selector("#file", timeout=30_000)
    assert "Updating now..." not in tab.inner_text("#main")
