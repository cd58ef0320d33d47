"""Fixtures for pages under the fake WebXR runtime: one Playwright and one headless Chromium
per test module (skipped with the reason when chromium or playwright is missing; a test
needing other flags launches its own from `xr_playwright`) and a fresh page per test that
fails the test on any uncaught JavaScript error."""

from __future__ import annotations

import pytest
from browser_pages import checked_page
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
