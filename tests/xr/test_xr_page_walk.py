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
from fake_xr_browser import open_with_fake_xr
from scene_feed import SceneFeed
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


def wait_until(page, predicate: str, timeout_s: float = 60.0) -> None:
    """Poll a JavaScript function until it returns true. Playwright's wait_for_function
    compiles its predicate with eval, which the page's CSP (script-src 'self') forbids, and the
    CSP stays on: the page must work under it."""
    deadline = time.monotonic() + timeout_s
    while not page.evaluate(predicate):
        if time.monotonic() > deadline:
            raise AssertionError(f"not true within {timeout_s:.0f} s: {predicate}")
        page.wait_for_timeout(100)


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
