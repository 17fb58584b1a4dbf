"""Debian's Chromium under Playwright for the web-page tests (../shared/notes/browser-tests.md: never
`playwright install`): one launch recipe, and a skip that says why when Playwright or the browser is
missing (the Makefile installs both)."""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import pytest

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"


def require_browser() -> Any:
    """Playwright's sync API, or a skip (inside a test, or at module level) saying what is missing."""
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (make install)")
    if not os.access(CHROMIUM, os.X_OK):
        pytest.skip(f"no browser: {CHROMIUM} is missing (the Makefile's apt step installs Debian's chromium)",
                    allow_module_level=True)
    return sync_api


@contextmanager
def chromium() -> Iterator[Any]:
    """A headless Chromium browser, closed afterwards."""
    sync_api = require_browser()
    with sync_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, headless=True, args=["--no-sandbox"])
        try:
            yield browser
        finally:
            browser.close()
