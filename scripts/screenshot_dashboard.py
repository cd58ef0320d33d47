"""Make the README's dashboard screenshot (docs/img/dashboard.png) from a real run.

Starts the server in process on a free loopback port, plays the first frames of the
synthetic living room through the device client (real encoder, real WebSockets), opens
the dashboard in headless Chromium, asks a query there and saves a screenshot.

    .venv/bin/python scripts/screenshot_dashboard.py [--frames 60] [--query "..."] [--dark]

Needs Debian's chromium (or chromium-headless-shell) and playwright (the dev extras).
"""

from __future__ import annotations

import argparse
import asyncio
import os
import shutil
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM_ARGS = [
    "--no-sandbox",  # may run as root in a container, where the sandbox cannot start
    "--disable-gpu",
    "--disable-background-networking",  # offline: no update checks or telemetry
    "--disable-component-update",
    "--no-first-run",
]
SESSION_KNOBS = {"keyframe_interval": 2}
"""Map every other frame: a short walk still confirms most of the room's objects."""
PAGE_TIMEOUT_MS = 30_000


async def stream_scene(server_url: str, scene: str, frames: int) -> str:
    """A session with the first `frames` frames of the walk mapped; its id."""
    from app.client import create_session
    from app.config import Knobs, updated_knobs
    from client_sim.sources.synthetic import SyntheticSource
    from client_sim.streaming import DeviceClient

    sid, token, answer = await create_session(
        server_url, name=scene.replace("_", " "), knobs=SESSION_KNOBS
    )
    client = DeviceClient(server_url, sid, token, knobs=updated_knobs(Knobs(), answer["knobs"]))
    # Follow the updates too, so the downstream counter shows a device's real traffic.
    follower = asyncio.create_task(client.follow_updates())
    try:
        stats = await client.stream(SyntheticSource(scene, n_frames=300), fps=None, limit=frames)
        await client.wait_synced(stats.server_seq, timeout_s=5.0)
    finally:
        await client.stop()
        await asyncio.gather(follower, return_exceptions=True)
    print(
        f"streamed {stats.frames_sent} frames, {stats.keyframes_acked} keyframes mapped",
        file=sys.stderr,
    )
    return sid


def screenshot(url: str, sid: str, query: str, out: Path, dark: bool) -> None:
    from playwright.sync_api import expect, sync_playwright

    executable = next(
        (p for p in map(shutil.which, ("chromium", "chromium-headless-shell")) if p), None
    )
    if executable is None:
        sys.exit("no chromium on PATH (Debian: apt-get install chromium)")
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=executable, args=CHROMIUM_ARGS)
        page = browser.new_page(
            viewport={"width": 1200, "height": 760}, color_scheme="dark" if dark else "light"
        )
        page.set_default_timeout(PAGE_TIMEOUT_MS)
        page.goto(url)
        card = page.locator(f'article[data-sid="{sid}"]')
        expect(card.locator(".stat-objects")).not_to_have_text("–")
        card.locator(".query-input").fill(query)
        card.locator(".query-button").click()
        expect(card.locator(".results tbody tr").first).to_be_visible()
        first = card.locator(".results tbody tr td.label").first.inner_text()
        out.parent.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(out), full_page=True)
        browser.close()
    print(f"query {query!r}: top result {first!r}; wrote {out}", file=sys.stderr)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="living_room", help="synthetic scene")
    parser.add_argument("--frames", type=int, default=60, help="frames of the walk to stream")
    parser.add_argument("--query", default="where can I sit down to watch a movie?")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "img" / "dashboard.png")
    parser.add_argument("--dark", action="store_true", help="dark colour scheme")
    args = parser.parse_args()
    os.environ.setdefault("HF_HUB_OFFLINE", "1")

    import tempfile

    from app.server.runner import ServerThread
    from app.server.settings import ServerSettings

    with tempfile.TemporaryDirectory() as data_dir:
        settings = ServerSettings(host="127.0.0.1", port=0, data_dir=data_dir)
        server = ServerThread(settings).start()  # the lifespan loads the text encoder
        try:
            sid = asyncio.run(stream_scene(server.url, args.scene, args.frames))
            screenshot(server.url, sid, args.query, args.out, args.dark)
        finally:
            server.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
