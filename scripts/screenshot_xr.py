"""Make the README's real-device screenshot (docs/img/xr.png) from a real run.

Starts the server in process with `--perception models` (tiny random models: nothing needs
downloading), imports the furniture of the emulated room as a map (the tiny models cannot
name things, so the question needs a map that can), opens /xr in headless Chromium under the
emulated WebXR phone the tests use (tests/xr/fake_webxr.js), starts AR, and mid-walk asks a
question. The server's answer would be "no match" (the tiny text tower is never confident),
so the query request is cut and the page answers from its own copy of the map, as it does
when the network drops; the screenshot shows what the phone's user sees: the camera image,
the answer drawn over the thing, the page's counters.

    .venv/bin/python scripts/screenshot_xr.py [--question "where is the sofa"] [--out docs/img/xr.png]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests" / "xr"), str(ROOT / "tests")]

import httpx  # noqa: E402
from fake_xr_browser import launch_chromium, open_with_fake_xr, wait_until  # noqa: E402
from models_server import tiny_models_server  # noqa: E402
from room_map import room_export  # noqa: E402
from scene_feed import SceneFeed  # noqa: E402
from xr_device import Phone, RuntimeOptions  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--question", default="where is the sofa")
    parser.add_argument("--frames", type=int, default=40, help="scene frames in the walk")
    parser.add_argument("--at", type=int, default=14, help="scene frame at which to ask")
    parser.add_argument("--out", default=str(ROOT / "docs" / "img" / "xr.png"))
    args = parser.parse_args()
    with tiny_models_server() as server:
        probe = httpx.post(f"{server.url}/v1/sessions", json={"perception": "models"}, timeout=30)
        feed = SceneFeed(
            Phone(),
            n_frames=args.frames,
            options=RuntimeOptions(on_walk_end="hold", display_every=1),
        )
        room = room_export(feed, probe.json()["embedding"])
        imported = httpx.post(f"{server.url}/v1/sessions/import", json=room, timeout=60).json()
        sid, token = imported["session_id"], imported["token"]
        with launch_chromium() as browser:
            page = browser.new_page(viewport={"width": 540, "height": 720}, device_scale_factor=1)
            open_with_fake_xr(page, f"{server.url}/xr#session={sid}&token={token}", feed)
            wait_until(page, "() => !document.querySelector('#start-ar').disabled")
            page.click("#start-ar")
            wait_until(page, f"() => window.semanticxr.objects >= {len(room['objects'])}")
            wait_until(page, f"() => fakeXR.sceneFrame >= {args.at}")
            page.route("**/v1/sessions/*/query*", lambda route: route.abort())
            page.fill("#ask-text", args.question)
            page.click("#ask-form button[type=submit]")
            wait_until(page, "() => window.semanticxr.answer !== null")
            wait_until(page, f"() => fakeXR.sceneFrame >= {args.at + 3}")
            page.screenshot(path=args.out)
            print(f"[screenshot] {page.inner_text('#answer')!r} -> {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
