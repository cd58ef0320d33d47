"""The real-device page (/xr) walked through a room by the fake WebXR runtime, in real
Chromium against a real server with `--perception models` (tiny models), on both paths:
Chrome on Android (camera-access + CPU depth) and Quest (getUserMedia + GPU depth). The map's
points must lie on the room's surfaces: the check that depth scale, intrinsics, the pose
convention and up are right end to end. The counts the page shows must be the server's."""

from __future__ import annotations

import time

import httpx
import numpy as np
import pytest
from fake_xr_browser import open_with_fake_xr, wait_until
from room_map import room_export
from scene_feed import SceneFeed, project
from xr_device import Phone, Pinhole, Pose, Quest3, RuntimeOptions, quaternion_of

pytestmark = [pytest.mark.slow, pytest.mark.timeout(300)]

KNOBS = {"keyframe_interval": 1, "min_observations": 1, "min_mapping_bbox_area": 16}
"""Every page keyframe mapped and confirmed at once: a short walk makes a map."""
SURFACE_P95_M = 0.03


@pytest.fixture(scope="module")
def tiny_models(tmp_path_factory):
    from app.perception.models.tiny import write_tiny_models

    return str(write_tiny_models(tmp_path_factory.mktemp("models")))


def quest_as_the_page_calibrates_it(page) -> Quest3:
    """A Quest 3 whose passthrough camera is exactly where the page's calibration says (the
    page cannot know better on a real headset; here it is told the truth)."""
    cal = page.evaluate(
        """async () => {
            const c = await import('/static/xr/calibration.mjs');
            const q = c.CALIBRATIONS[c.DEFAULT_CALIBRATION];
            return {intrinsics: c.intrinsicsAt(q, 640, 480), matrix: q.cameraFromViewer};
        }"""
    )
    fx, fy, cx, cy = cal["intrinsics"]
    m = np.asarray(cal["matrix"], np.float64).reshape(4, 4).T  # column-major
    pose = Pose(tuple(m[:3, 3]), tuple(quaternion_of(m[:3, :3])))
    return Quest3(color=Pinhole(640, 480, fx, fy, cx, cy), color_from_viewer=pose)


def start_walk(page, server, device, n_frames=24):
    created = httpx.post(
        f"{server.url}/v1/sessions",
        json={"name": "walk", "perception": "models", "up": "+y", "knobs": KNOBS},
        timeout=30,
    ).json()
    sid, token = created["session_id"], created["token"]
    # The runtime ends the XR session when the walk ends, as a user taking the headset off.
    feed = SceneFeed(device, n_frames=n_frames, options=RuntimeOptions(on_walk_end="end"))
    open_with_fake_xr(page, f"{server.url}/xr#session={sid}&token={token}", feed)
    wait_until(page, "() => !document.querySelector('#start-ar').disabled")
    page.click("#start-ar")
    wait_until(page, "() => fakeXR.done && !window.semanticxr.streaming", timeout_s=120)
    sent = page.evaluate("window.semanticxr.counters")["frames"]

    def settled() -> bool:  # every frame received, and mapped or superseded (dropped)
        stats = httpx.get(f"{server.url}/v1/sessions/{sid}", timeout=10).json()
        return stats["frames"] >= sent and stats["keyframes"] + stats["dropped_frames"] >= sent

    deadline = time.monotonic() + 90
    while not settled():
        assert time.monotonic() < deadline, "the server did not take every frame the page sent"
        time.sleep(0.2)  # polling the server's counts: nothing to wait on
    return sid, feed


@pytest.mark.parametrize("path", ["phone", "quest"])
def test_a_walk_streamed_by_the_page_maps_points_on_the_rooms_surfaces(
    xr_page, live_server, tiny_models, path
):
    server = live_server(perception="models", models_dir=tiny_models)
    if path == "phone":
        device = Phone()
    else:
        xr_page.goto(f"{server.url}/healthz")
        device = quest_as_the_page_calibrates_it(xr_page)
    sid, feed = start_walk(xr_page, server, device)

    counters = xr_page.evaluate("window.semanticxr.counters")
    assert counters["errors"] == 0, counters["lastError"]
    assert counters["keyframes"] >= 5
    stats = httpx.get(f"{server.url}/v1/sessions/{sid}", timeout=10).json()
    # What the page shows is what the server counted.
    assert counters["frames"] == stats["frames"] == stats["keyframes"] + stats["dropped_frames"]
    assert counters["payloadBytes"] == stats["bytes_in"]["rgb"] + stats["bytes_in"]["depth"]
    assert stats["up"] == "+y"

    objects = httpx.get(
        f"{server.url}/v1/sessions/{sid}/objects", params={"points": "true"}, timeout=30
    ).json()
    points = np.concatenate([np.asarray(o["points"], np.float64) for o in objects if o["points"]])
    assert len(points) > 500
    distance = feed.truth.distance(points)
    p95 = float(np.percentile(distance, 95))
    assert p95 <= SURFACE_P95_M, f"map points p95 {p95 * 100:.1f} cm off the room's surfaces"


BEST_RGB = np.array([235, 80, 0])
"""The best hit's colour (static/xr/draw.mjs BEST_RGBA), opaque over the camera image."""


def display_pixels(page) -> np.ndarray:
    """uint8 [H, W, 3] of what the emulated device shows: camera image + the page's layer."""
    data = page.evaluate(
        """() => {
            const c = document.querySelector('#fakexr-display');
            const d = c.getContext('2d').getImageData(0, 0, c.width, c.height);
            return {w: c.width, h: c.height, px: Array.from(d.data)};
        }"""
    )
    return np.asarray(data["px"], np.uint8).reshape(data["h"], data["w"], 4)[..., :3]


def test_the_answer_is_drawn_over_the_thing_in_the_room(xr_page, live_server, tiny_models):
    """The page's local copy of a room (from the updates stream) answers with the network cut,
    and the page draws the answer over the thing in the camera image. Offline, because the
    tiny random models' text tower is never a confident match online; the page draws only
    matches, and the local answer by label words is one."""
    server = live_server(perception="models", models_dir=tiny_models)
    probe = httpx.post(f"{server.url}/v1/sessions", json={"perception": "models"}, timeout=30)
    feed = SceneFeed(
        Phone(), n_frames=16, options=RuntimeOptions(on_walk_end="hold", display_every=1)
    )
    room = room_export(feed, probe.json()["embedding"])
    imported = httpx.post(f"{server.url}/v1/sessions/import", json=room, timeout=60).json()
    sid, token = imported["session_id"], imported["token"]
    open_with_fake_xr(xr_page, f"{server.url}/xr#session={sid}&token={token}", feed)
    wait_until(xr_page, "() => !document.querySelector('#start-ar').disabled")
    xr_page.click("#start-ar")
    wait_until(xr_page, "() => fakeXR.done", timeout_s=120)

    # The piece of furniture that fills most of the last view, named by a word no label the
    # page's own (random) finds carry shares.
    last = feed.frame(len(feed) - 1)
    camera = feed.device.camera
    objects = httpx.get(f"{server.url}/v1/sessions/{sid}/objects", timeout=10).json()
    imported_ids = {o["id"] for o in room["objects"]}
    found_words = {w for o in objects if o["id"] not in imported_ids for w in o["label"].split()}

    def screen_box(obj):
        """The object's box on the screen, clipped to it, and its area (0 unless wholly in
        front of the camera)."""
        corners = np.array(
            np.meshgrid(*zip(obj["bbox"][:3], obj["bbox"][3:], strict=True))
        ).T.reshape(-1, 3)
        ahead = (corners - last.viewer[:3, 3]) @ last.viewer[:3, 2] < -0.1  # WebXR looks down -z
        uv = project(last.viewer, camera, corners)
        lo = np.clip(uv.min(0), 0, [camera.width, camera.height])
        hi = np.clip(uv.max(0), 0, [camera.width, camera.height])
        return lo, hi, float(np.prod(hi - lo)) if ahead.all() else 0.0

    named = [o for o in room["objects"] if not set(o["label"].split()) & found_words]
    named = [o for o in named if sum(p["label"] == o["label"] for p in room["objects"]) == 1]
    target = max(named, key=lambda o: screen_box(o)[2])
    wait_until(xr_page, f"() => window.semanticxr.objects >= {len(objects)}")

    xr_page.context.set_offline(True)
    xr_page.fill("#ask-text", f"where is the {target['label']}")
    xr_page.click("#ask-form button[type=submit]")
    wait_until(xr_page, "() => window.semanticxr.answer !== null")
    answer = xr_page.evaluate("window.semanticxr.answer")
    assert answer["source"] == "local" and answer["match"]
    assert answer["results"][0]["id"] == target["id"]
    assert "offline" in answer["note"]
    # Two animation frames: the answer is in the layer the display composites.
    xr_page.evaluate(
        "() => new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))"
    )

    pixels = display_pixels(xr_page)
    orange = np.all(np.abs(pixels.astype(int) - BEST_RGB) <= 12, axis=-1)
    rows, cols = np.nonzero(orange)
    assert len(rows) > 200, "the best hit is not drawn"
    lo, hi, _ = screen_box(target)
    margin = 8  # line width; the label stands above the box
    inside = (cols >= lo[0] - margin) & (cols <= hi[0] + margin) & (rows <= hi[1] + margin)
    assert inside.mean() > 0.95, "the answer is drawn away from the thing"
