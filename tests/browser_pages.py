"""A page for browser tests (the dashboard's and the real-device page's): fresh, in a context
of its own, failing the test on any uncaught JavaScript error."""

from __future__ import annotations

from collections.abc import Iterator

BROWSER_TIMEOUT_MS = 30_000
"""Longest wait for a page to show something."""


def checked_page(browser, viewport: dict, init_scripts: tuple[str, ...] = ()) -> Iterator:
    """Yield a new page of `browser` (its `init_scripts` run before the page's own), then
    close its context and fail on the JavaScript errors it had. Use as a fixture's body:
    `yield from checked_page(browser, {"width": 960, "height": 720})`."""
    context = browser.new_context(viewport=viewport)
    page = context.new_page()
    page.set_default_timeout(BROWSER_TIMEOUT_MS)
    for script in init_scripts:
        page.add_init_script(script=script)
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    yield page
    context.close()
    assert not errors, f"JavaScript errors on the page: {errors}"
