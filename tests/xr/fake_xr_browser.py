"""Headless Chromium for pages that use WebXR, with the fake runtime (fake_webxr.js) installed
before any page script and a scene feed (scene_feed.SceneFeed) answering its frame fetches.

    feed = SceneFeed(Phone(), n_frames=40).prerender()
    open_with_fake_xr(page, f"{server.url}/xr", feed)
    page.click("#start")                       # requestSession needs user activation
    wait_until(page, "() => fakeXR.done")      # never time.sleep: the feed answers only
                                               # while Playwright runs

WebGL needs SwiftShader here (`--use-angle=swiftshader`), not `--disable-gpu`.
"""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import pytest
from scene_feed import SceneFeed

try:  # optional: without playwright the browser tests skip
    from playwright.sync_api import sync_playwright
except ImportError:
    sync_playwright = None

FAKE_WEBXR_JS = Path(__file__).with_name("fake_webxr.js")
CHROMIUM_ARGS = [
    "--no-sandbox",  # tests may run as root in a container, where the sandbox cannot start
    "--use-angle=swiftshader",  # WebGL on the CPU: there is no GPU here
    "--enable-unsafe-swiftshader",
    "--disable-background-networking",  # no internet here: no update checks, no telemetry
    "--disable-component-update",
    "--no-first-run",
]


def chromium_path() -> str | None:
    """Debian's chromium (Playwright's own download needs internet)."""
    for name in ("chromium", "chromium-browser"):
        path = shutil.which(name)
        if path:
            return path
    return None


@contextmanager
def playwright_session() -> Iterator:
    """Playwright's sync API, or a pytest skip naming what is missing. Start it once: a second
    one on the same thread fails while the first runs; launch every browser from this one."""
    if sync_playwright is None:
        pytest.skip("playwright is not installed (pip install -e '.[dev]')")
    if chromium_path() is None:
        pytest.skip("no chromium on PATH (Debian: apt-get install chromium)")
    with sync_playwright() as playwright:
        yield playwright


def launch(playwright, extra_args: Sequence[str] = ()):
    """A headless Chromium that can run WebGL 2, with `extra_args` after CHROMIUM_ARGS (e.g.
    tests/spoken.py's fake microphone); close it when done."""
    args = [*CHROMIUM_ARGS, *extra_args]
    return playwright.chromium.launch(executable_path=chromium_path(), args=args)


@contextmanager
def launch_chromium(extra_args: Sequence[str] = ()) -> Iterator:
    """`launch` in a Playwright of its own (scripts and benches), or a pytest skip."""
    with playwright_session() as playwright:
        browser = launch(playwright, extra_args)
        try:
            yield browser
        finally:
            browser.close()


def install_fake_xr(page, feed: SceneFeed, **overrides) -> dict:
    """Install the runtime on `page` for every document it loads from now on, and route its
    frame fetches to `feed`; `overrides` replace keys of window.__fakeXRConfig. The config."""
    feed.prerender()
    config = {**feed.js_config(), **overrides}
    page.add_init_script(script=f"window.__fakeXRConfig = {json.dumps(config)};")
    page.add_init_script(path=str(FAKE_WEBXR_JS))
    feed.route(page)
    return config


def open_with_fake_xr(page, url: str, feed: SceneFeed, **overrides) -> dict:
    """`install_fake_xr`, then load `url` (same origin as the frames it will fetch)."""
    config = install_fake_xr(page, feed, **overrides)
    page.goto(url)
    return config


def wait_until(page, predicate: str, timeout_s: float = 60.0) -> None:
    """Poll a JavaScript function on the page until it returns true. Playwright's
    wait_for_function compiles its predicate with eval, which the pages' CSP (script-src
    'self') forbids, and the CSP stays on: the pages must work under it."""
    deadline = time.monotonic() + timeout_s
    while not page.evaluate(predicate):
        if time.monotonic() > deadline:
            raise AssertionError(f"not true within {timeout_s:.0f} s: {predicate}")
        page.wait_for_timeout(100)
