"""Screenshot of the viewer on a real synthetic scene, for the README (docs/img/viewer.png).

Everything runs in this process on loopback: a SemanticXR server (uvicorn) on a temporary
data dir, the device emulator streaming a walk through a synthetic room, the viewer
following the session, and Debian's headless chromium (via Playwright) taking the picture.

    .venv/bin/python scripts/screenshot_viewer.py [--scene living_room] [--frames 60]
        [--query "where can I sit"] [--out docs/img/viewer.png]
"""

from __future__ import annotations

import argparse
import asyncio
import os
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))  # runnable as a plain script from anywhere
os.environ.setdefault("HF_HUB_OFFLINE", "1")

CHROMIUM_ARGS = [
    "--no-sandbox",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
]
WAIT_S = 120.0
SESSION_KNOBS = {"keyframe_interval": 2, "min_observations": 2, "local_map_update_frequency": 1}
"""Denser than the defaults: a short walk still maps most of the room."""


def wait_for(condition: Callable[[], object], what: str, timeout_s: float = WAIT_S) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise TimeoutError(f"timed out after {timeout_s:g} s waiting for {what}")
        time.sleep(0.05)  # a polling period


def stream_scene(url: str, scene: str, frames: int) -> tuple[str, str, int]:
    """Create a session and play `frames` frames of the synthetic `scene` at 640x480 into it;
    (session id, token, the server's update seq)."""
    from app.client import SessionApi, create_session
    from app.config import Knobs, updated_knobs
    from client_sim.sources.synthetic import SyntheticSource
    from client_sim.streaming import DeviceClient
    from world.render import default_camera

    async def play() -> tuple[str, str, int]:
        sid, token, answer = await create_session(url, knobs=SESSION_KNOBS)
        knobs = updated_knobs(Knobs(), answer["knobs"])
        source = SyntheticSource(scene, n_frames=frames, camera=default_camera(640, 480))
        device = DeviceClient(url, sid, token, knobs=knobs)
        stats = await device.stream(source, fps=None, max_in_flight=1)
        await device.stop()
        async with SessionApi(url, sid, token) as api:
            session = await api.fetch()
        print(
            f"streamed {stats.frames_sent} frames ({stats.keyframes_acked} mapped): "
            f"{session.objects} objects",
            file=sys.stderr,
        )
        return sid, token, session.update_seq

    return asyncio.run(play())


def chromium_path() -> str:
    for candidate in ("/usr/bin/chromium", "/usr/bin/chromium-headless-shell"):
        if Path(candidate).exists():
            return candidate
    raise SystemExit("no chromium: install Debian's chromium (apt-get install chromium)")


def screenshot(viewer_url: str, object_nodes: set[str], out: Path, size: tuple[int, int]) -> None:
    """Open the viewer, wait until every object's cloud is mounted, and save the page."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=chromium_path(), args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": size[0], "height": size[1]})
            page.goto(viewer_url)
            page.wait_for_function(
                """names => {
                    const m = window.__viserMutable;
                    return m && names.every(n => m.nodeRefFromName[n]);
                }""",
                arg=sorted(object_nodes),
                timeout=WAIT_S * 1e3,
            )
            # The software-GL warning is for people, not for the README picture.
            warning = page.locator(".mantine-Notification-root", has_text="Software WebGL")
            if warning.count():
                warning.locator("button").first.click()
                warning.wait_for(state="detached", timeout=10_000)
            # A few rendered frames, so that labels are laid out (a frame count, not a sleep).
            page.evaluate(
                """() => new Promise(done => {
                    let left = 10;
                    const tick = () => (--left ? requestAnimationFrame(tick) : done());
                    requestAnimationFrame(tick);
                })"""
            )
            out.parent.mkdir(parents=True, exist_ok=True)
            page.screenshot(path=str(out))
        finally:
            browser.close()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="living_room", help="synthetic scene")
    parser.add_argument("--frames", type=int, default=60, help="frames of the walk")
    parser.add_argument("--query", default="where can I sit", help="query to highlight ('': none)")
    parser.add_argument("--k", type=int, default=3, help="hits to highlight")
    parser.add_argument("--out", default=str(REPO / "docs" / "img" / "viewer.png"))
    parser.add_argument("--width", type=int, default=1400)
    parser.add_argument("--height", type=int, default=860)
    args = parser.parse_args(argv)

    from app.semantics import get_text_encoder
    from app.server.runner import ServerThread
    from app.server.settings import ServerSettings
    from viewer.app import ViewerApp
    from viewer.scene import points_node

    with tempfile.TemporaryDirectory(prefix="semanticxr-shot-") as data_dir:
        settings = ServerSettings(host="127.0.0.1", port=0, data_dir=data_dir)
        server = ServerThread(settings, encoder=get_text_encoder()).start()
        url = server.url
        try:
            sid, token, seq = stream_scene(url, args.scene, args.frames)
            app = ViewerApp(url, sid, token, port=0, stats_period_s=0.5)
            app.start()
            try:
                wait_for(lambda: app.applied_seq >= seq, f"the viewer to apply seq {seq}")
                wait_for(lambda: app.status.stats_ok, "the viewer's first stats")
                if args.query:
                    app.gui.query_text.value = args.query  # as if typed: the GUI shows it
                    app.gui.top_k.value = args.k
                    hits = app.run_query(args.query, args.k)
                    print(
                        f"query {args.query!r}: "
                        + ", ".join(f"{h['label']} {h['score']:.2f}" for h in hits),
                        file=sys.stderr,
                    )
                with app._lock:
                    nodes = {points_node(oid) for oid in app.model.objects}
                    lo, hi = app.model.bounds() or ((), ())
                    print(f"map bounds {lo} .. {hi}; floor {app._floor}", file=sys.stderr)
                out = Path(args.out)
                screenshot(app.url, nodes, out, (args.width, args.height))
                print(f"wrote {out}", file=sys.stderr)
            finally:
                app.stop()
        finally:
            server.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
