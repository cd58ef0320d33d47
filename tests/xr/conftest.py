"""Fixtures for pages under the fake WebXR runtime: one headless Chromium per test session
(skipped with the reason when chromium or playwright is missing) and a fresh page per test
that fails the test on any uncaught JavaScript error."""

from __future__ import annotations

import pytest
from fake_xr_browser import launch_chromium

BROWSER_TIMEOUT_MS = 30_000


@pytest.fixture(scope="session")
def xr_browser():
    with launch_chromium() as browser:
        yield browser


@pytest.fixture
def xr_page(xr_browser):
    context = xr_browser.new_context(viewport={"width": 960, "height": 720})
    page = context.new_page()
    page.set_default_timeout(BROWSER_TIMEOUT_MS)
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    yield page
    context.close()
    assert not errors, f"JavaScript errors on the page: {errors}"
