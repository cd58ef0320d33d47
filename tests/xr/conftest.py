"""Fixtures for pages under the fake WebXR runtime: one Playwright and one headless Chromium
per test module (skipped with the reason when chromium or playwright is missing; a test
needing other flags launches its own from `xr_playwright`) and a fresh page per test that
fails the test on any uncaught JavaScript error: `xr_page`, and `page` (in `context`) for the
answers test page."""

from __future__ import annotations

import pytest
from browser_pages import BROWSER_TIMEOUT_MS, checked_page
from fake_xr_browser import launch, playwright_session

VIEWPORT = {"width": 960, "height": 720}


@pytest.fixture(scope="module")
def xr_playwright():
    """The one Playwright of the module: every browser of its tests is launched from it. Not
    kept for the session: Playwright's sync API holds an event loop running on the main
    thread, so a later test elsewhere that calls `asyncio.run` would fail."""
    with playwright_session() as playwright:
        yield playwright


@pytest.fixture(scope="module")
def xr_browser(xr_playwright):
    browser = launch(xr_playwright)
    yield browser
    browser.close()


@pytest.fixture
def xr_page(xr_browser):
    yield from checked_page(xr_browser, VIEWPORT)


@pytest.fixture
def context(xr_browser):
    """A context for the answers test page (answers_page.py). That page is fulfilled by
    Playwright, not fetched from 127.0.0.1, so Chromium's Local Network Access checks would
    take its calls to the server as reaching into the local network and block them (the real
    /xr page is served by the server itself)."""
    context = xr_browser.new_context(permissions=["local-network-access"])
    yield context
    context.close()


@pytest.fixture
def page(context):
    """A page of `context` that fails the test on any uncaught JavaScript error."""
    page = context.new_page()
    page.set_default_timeout(BROWSER_TIMEOUT_MS)
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    yield page
    assert not errors, f"JavaScript errors on the page: {errors}"
