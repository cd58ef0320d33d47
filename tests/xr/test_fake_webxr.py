"""The fake WebXR runtime (fake_webxr.js) against a known scene, before any page is tested with
it: a test-only page (xr_probe.js, the spec surface only) reads depth, camera images, poses and
projections the way the specs say to, and every number is checked against the scene's truth
(scene_feed.SceneTruth) -- and the wrong ways of reading them are shown to miss."""

from __future__ import annotations

import base64
import math
from pathlib import Path

import numpy as np
import pytest
from fake_xr_browser import open_with_fake_xr
from scene_feed import SceneFeed, project
from xr_device import (
    NORM_DEPTH_BUFFER_FROM_NORM_VIEW,
    Phone,
    Pose,
    Quest3,
    RuntimeOptions,
    axis_angle,
)

from app.server.routes.pages import SECURITY_HEADERS

ORIGIN = "http://127.0.0.1:8765"
"""The probe page's origin: never contacted, Playwright answers every request it makes."""
PROBE_JS = Path(__file__).with_name("xr_probe.js")
PROBE_HTML = (
    "<!doctype html><meta charset=utf-8><title>fake WebXR probe</title>"
    "<div id=overlay></div><script src=/xr_probe.js></script>"
)
ARTIFACTS = Path(__file__).resolve().parents[2] / "out" / "test-artifacts"
HOLD = 2
PHONE = Phone()
QUEST = Quest3()
CPU_DEPTH = {"usagePreference": ["cpu-optimized"], "dataFormatPreference": []}
GPU_DEPTH = {"usagePreference": ["gpu-optimized"], "dataFormatPreference": ["float32"]}


@pytest.fixture(scope="module")
def phone_feed() -> SceneFeed:
    return SceneFeed(
        PHONE, n_frames=8, options=RuntimeOptions(xr_frames_per_scene_frame=HOLD)
    ).prerender()


@pytest.fixture(scope="module")
def quest_feed() -> SceneFeed:
    return SceneFeed(
        QUEST, n_frames=6, options=RuntimeOptions(xr_frames_per_scene_frame=HOLD)
    ).prerender()


def open_probe(page, feed: SceneFeed, **overrides) -> None:
    """The probe page, under the app's own security headers, with the fake device installed."""
    page.route(
        f"{ORIGIN}/probe.html",
        lambda route: route.fulfill(
            body=PROBE_HTML, content_type="text/html", headers=SECURITY_HEADERS
        ),
    )
    page.route(
        f"{ORIGIN}/xr_probe.js",
        lambda route: route.fulfill(
            path=PROBE_JS, content_type="text/javascript", headers=SECURITY_HEADERS
        ),
    )
    open_with_fake_xr(page, f"{ORIGIN}/probe.html", feed, **overrides)


def start(page, init: dict, space: str = "local-floor") -> dict:
    return page.evaluate("([init, space]) => probe.start(init, space)", [init, space])


def refusal(page, init: dict) -> str | None:
    """The name of the error requestSession rejects `init` with (None: a session started)."""
    return page.evaluate("init => probe.refusal(init)", init)


def matrix(column_major) -> np.ndarray:
    return np.asarray(column_major, np.float64).reshape(4, 4).T


def rgba(result: dict) -> np.ndarray:
    data = np.frombuffer(base64.b64decode(result["rgba"]), np.uint8)
    return data.reshape(result["height"], result["width"], 4)


def texel_centres(
    width: int, height: int, count: int, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) of `count` distinct depth texels spread over the buffer."""
    rng = np.random.default_rng(seed)
    flat = rng.choice(width * height, count, replace=False)
    return flat // width, flat % width


# --- the phone: CPU depth, the camera image -----------------------------------------------------


@pytest.mark.parametrize("data_format", ["luminance-alpha", "float32", "unsigned-short"])
def test_phone_cpu_depth_read_through_normDepthBufferFromNormView_is_the_scene_depth(
    xr_page, phone_feed, data_format
):
    open_probe(xr_page, phone_feed)
    info = start(
        xr_page,
        {
            "requiredFeatures": ["depth-sensing", "local-floor"],
            "depthSensing": {
                "usagePreference": ["cpu-optimized"],
                "dataFormatPreference": [data_format],
            },
        },
    )
    assert (info["depthUsage"], info["depthDataFormat"]) == ("cpu-optimized", data_format)
    width, height = PHONE.depth_size
    to_buffer = NORM_DEPTH_BUFFER_FROM_NORM_VIEW[PHONE.depth_orientation]
    rows, cols = texel_centres(width, height, 60)
    nd = np.stack([(cols + 0.5) / width, (rows + 0.5) / height, 0 * cols, 1 + 0 * cols], 1)
    nv = (nd @ np.linalg.inv(to_buffer).T)[:, :2]

    read = xr_page.evaluate("([points, skip]) => probe.cpuDepth(points, skip)", [nv.tolist(), 3])

    frame = phone_feed.frame(read["scene"])
    truth = phone_feed.truth.z_depth(frame.views[0], PHONE.camera, nv)
    sixteen_bit = data_format != "float32"
    assert (read["width"], read["height"]) == (width, height)
    assert read["bytes"] == width * height * (2 if sixteen_bit else 4)
    assert read["rawValueToMeters"] == pytest.approx(0.001 if sixteen_bit else 1.0)
    np.testing.assert_allclose(matrix(read["matrix"]), to_buffer, atol=1e-6)
    tolerance_m = 0.0006 if sixteen_bit else 0.00015  # the format's rounding + the feed's 0.2 mm
    np.testing.assert_allclose(read["manual"], truth, atol=tolerance_m)
    np.testing.assert_allclose(read["api"], read["manual"], rtol=1e-6)
    # A page that ignores normDepthBufferFromNormView reads other texels.
    assert np.mean(np.abs(np.asarray(read["naive"]) - truth) > 0.05) > 0.5
    # The phone's depth is aligned with its view: the same geometry (depth sensing, "If the
    # sensor is aligned with the associated view ... the same values").
    assert read["depthTransform"] == read["view"]["transform"]
    assert read["depthProjection"] == read["view"]["projection"]


def test_phone_session_negotiates_depth_as_the_spec_says(xr_page, phone_feed):
    open_probe(xr_page, phone_feed)
    gpu_only = {"usagePreference": ["gpu-optimized"], "dataFormatPreference": []}
    # No GPU depth on the phone: required, the session is refused; optional, it comes without.
    required = {"requiredFeatures": ["depth-sensing"], "depthSensing": gpu_only}
    assert refusal(xr_page, required) == "NotSupportedError"
    assert refusal(xr_page, {"requiredFeatures": ["depth-sensing"]}) == "NotSupportedError"
    assert refusal(xr_page, {"requiredFeatures": ["hit-test"]}) == "NotSupportedError"
    info = start(
        xr_page,
        {
            "optionalFeatures": ["depth-sensing", "hit-test", "camera-access"],
            "depthSensing": gpu_only,
        },
        "local",
    )
    assert "depth-sensing" not in info["features"] and "hit-test" not in info["features"]
    assert "camera-access" in info["features"]
    assert info["depthError"] == "InvalidStateError"
    xr_page.evaluate("probe.end()")
    # An empty preference gets the device's preferred format; a list, its first supported one.
    info = start(
        xr_page, {"requiredFeatures": ["depth-sensing"], "depthSensing": CPU_DEPTH}, "local"
    )
    assert info["depthDataFormat"] == PHONE.preferred_depth_format
    xr_page.evaluate("probe.end()")
    info = start(
        xr_page,
        {
            "requiredFeatures": ["depth-sensing"],
            "depthSensing": {
                "usagePreference": ["gpu-optimized", "cpu-optimized"],
                "dataFormatPreference": ["rgba8", "float32", "luminance-alpha"],
            },
        },
        "local",
    )
    assert (info["depthUsage"], info["depthDataFormat"]) == ("cpu-optimized", "float32")


def test_phone_camera_image_is_the_view_with_its_bottom_row_first(xr_page, phone_feed):
    open_probe(xr_page, phone_feed)
    start(xr_page, {"requiredFeatures": ["camera-access"]}, "local")

    read = xr_page.evaluate("probe.cameraImage(2)")

    truth = phone_feed.frame(read["scene"]).camera_rgb
    image = rgba(read)
    assert (read["width"], read["height"]) == (PHONE.camera.width, PHONE.camera.height)
    np.testing.assert_array_equal(image[::-1, :, :3], truth)
    assert np.abs(image[:, :, :3].astype(int) - truth).mean() > 10  # not top row first
    assert (image[:, :, 3] == 255).all()
    assert read["sameCamera"] and read["sameTexture"]
    assert read["textureAfterFrame"] is False  # an opaque texture lives for its frame only
    deleted = xr_page.evaluate("probe.deleteCameraTexture()")
    assert deleted["stillATexture"] is True
    assert any("INVALID_OPERATION" in e for e in deleted["errors"])


# --- poses and projections -------------------------------------------------------------------


@pytest.mark.parametrize("device", ["phone", "quest"])
def test_view_transform_and_projection_put_a_known_point_on_its_pixel(
    xr_page, phone_feed, quest_feed, device
):
    feed = phone_feed if device == "phone" else quest_feed
    pinholes = [PHONE.camera] if device == "phone" else QUEST.eye_pinholes()
    open_probe(xr_page, feed)
    start(xr_page, {"requiredFeatures": ["local-floor"]})
    frame = feed.frame(0)  # the session's first XR frame shows scene frame 0
    first = pinholes[0]
    uv = np.array(
        [
            [30.5, 40.0],
            [first.width / 2, first.height / 2],
            [first.width - 20, first.height - 60.25],
        ]
    )
    points = feed.truth.surface_points(frame.views[0], first, first.normalized(uv))

    read = xr_page.evaluate("points => probe.project(points)", points.tolist())

    assert read["scene"] == 0
    np.testing.assert_allclose(matrix(read["viewer"]), frame.viewer, atol=2e-6)
    np.testing.assert_allclose(read["views"][0]["pixels"], uv, atol=0.01)
    for view, pose, pinhole in zip(read["views"], frame.views, pinholes, strict=True):
        np.testing.assert_allclose(matrix(view["transform"]), pose, atol=2e-6)
        assert view["position"][3] == 1
        np.testing.assert_allclose(
            matrix(view["projection"]), pinhole.projection(0.05, 100.0), rtol=1e-5, atol=1e-6
        )
        np.testing.assert_allclose(view["pixels"], project(pose, pinhole, points), atol=0.01)
        assert view["viewport"][2:] == [pinhole.width, pinhole.height]
    if device == "quest":
        assert [v["eye"] for v in read["views"]] == ["left", "right"]
        assert read["views"][1]["viewport"][0] == QUEST.eye.width
        eyes = [matrix(v["transform"])[:3, 3] for v in read["views"]]
        assert np.linalg.norm(eyes[1] - eyes[0]) == pytest.approx(QUEST.ipd_m, abs=1e-5)


def test_poses_follow_the_walk_and_a_reset_moves_the_origin_before_the_next_frame(
    xr_page, phone_feed
):
    open_probe(xr_page, phone_feed)
    start(xr_page, {"requiredFeatures": ["local-floor"]})
    shift = Pose((0.5, 0.0, -0.2), axis_angle((0, 1, 0), 30.0))

    read = xr_page.evaluate("([count, at, t]) => probe.poses(count, at, t)", [8, 3, shift.to_js()])

    frames, events = read["frames"], read["events"]
    assert [f["scene"] for f in frames] == [k // HOLD for k in range(8)]
    assert all(b["time"] > a["time"] for a, b in zip(frames, frames[1:], strict=False))
    local_origin = np.eye(4)
    local_origin[:3, 3] = phone_feed.viewers[0][:3, 3]
    moved = shift.matrix()
    for k, f in enumerate(frames):
        truth = phone_feed.frame(f["scene"]).viewer
        expected = truth if k <= 3 else np.linalg.inv(moved) @ truth
        np.testing.assert_allclose(matrix(f["viewer"]), expected, atol=2e-6)
        np.testing.assert_allclose(
            matrix(f["local"]), np.linalg.inv(local_origin) @ expected, atol=2e-6
        )
        np.testing.assert_allclose(matrix(f["viewerSpace"]), matrix(f["viewer"]), atol=2e-6)
    # 'reset' fires on each space before the first frame that uses the new origin, carrying the
    # new native origin in the old coordinates.
    assert [f["events"] for f in frames] == [0, 0, 0, 0, 2, 2, 2, 2]
    assert {e["space"] for e in events} == {"probe", "local"}
    assert all(e["same"] and e["xrFrame"] == frames[4]["xrFrame"] for e in events)
    by_space = {e["space"]: matrix(e["transform"]) for e in events}
    np.testing.assert_allclose(by_space["probe"], moved, atol=2e-6)
    np.testing.assert_allclose(
        by_space["local"], np.linalg.inv(local_origin) @ moved @ local_origin, atol=2e-6
    )


def test_each_scene_frame_is_held_then_the_walk_holds_its_last(xr_page, phone_feed):
    open_probe(xr_page, phone_feed)
    start(xr_page, {}, "local")
    done = xr_page.evaluate(
        "skip => probe.inFrame(() => [fakeXR.done, fakeXR.sceneFrame], skip)",
        len(phone_feed) * HOLD,
    )
    assert done == [True, len(phone_feed) - 1]
    log = xr_page.evaluate("fakeXR.frameLog")
    assert [e["sceneFrame"] for e in log] == [
        min(k // HOLD, len(phone_feed) - 1) for k in range(len(log))
    ]


def test_a_walk_set_to_end_ends_the_session_after_its_last_frame(xr_page, phone_feed):
    open_probe(xr_page, phone_feed, onWalkEnd="end")
    start(xr_page, {}, "local")
    scenes = xr_page.evaluate(
        """() => new Promise((resolve) => {
            const session = probe.session;
            session.addEventListener("end", () => resolve(fakeXR.frameLog.map((e) => e.sceneFrame)));
            const onFrame = () => session.requestAnimationFrame(onFrame);
            onFrame();
        })"""
    )
    assert scenes == [k // HOLD for k in range(len(phone_feed) * HOLD)]
    assert xr_page.evaluate("fakeXR.session === null && fakeXR.done") is True


# --- the display --------------------------------------------------------------------------------


def test_the_display_shows_the_camera_under_the_apps_layer(xr_page, phone_feed):
    open_probe(xr_page, phone_feed, displayEvery=1)
    features = xr_page.evaluate(
        "() => probe.start({requiredFeatures: ['dom-overlay', 'local-floor'], "
        "domOverlay: {root: document.getElementById('overlay')}})"
    )["features"]
    assert "dom-overlay" in features
    assert (
        xr_page.evaluate("getComputedStyle(document.getElementById('overlay')).zIndex")
        == "2147483001"
    )
    x, y, w, h = 40, 60, 100, 50  # GL window coordinates: y from the bottom

    shown = xr_page.evaluate("rect => probe.paint(rect)", [x, y, w, h])

    image = rgba(shown)[:, :, :3].astype(int)
    height = shown["height"]
    red = np.zeros_like(image, bool)
    red[height - y - h : height - y, x : x + w] = True
    assert (image[red.all(axis=2)] == (255, 0, 0)).all()
    camera = phone_feed.frame(shown["scene"]).camera_rgb.astype(int)
    assert np.abs(image[~red.any(axis=2)] - camera[~red.any(axis=2)]).max() <= 1
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    xr_page.screenshot(path=str(ARTIFACTS / "fake_webxr_phone.png"))
    ended = xr_page.evaluate("probe.end()")
    assert ended == {"liveSession": False}
    assert xr_page.evaluate("document.getElementById('fakexr-display')") is None


# --- the Quest: GPU depth, no camera-access, colour from getUserMedia ---------------------------


@pytest.mark.parametrize("match_depth_view", [True, False])
def test_quest_gpu_depth_lifted_with_the_depth_views_geometry_lies_on_the_surfaces(
    xr_page, quest_feed, match_depth_view
):
    open_probe(xr_page, quest_feed)
    info = start(
        xr_page,
        {
            "requiredFeatures": ["depth-sensing", "local-floor"],
            "depthSensing": {**GPU_DEPTH, "matchDepthView": match_depth_view},
        },
    )
    assert (info["depthUsage"], info["depthDataFormat"]) == ("gpu-optimized", "float32")

    read = xr_page.evaluate("skip => probe.gpuDepth(8, skip)", 3)

    # Unmatched, the depth may be older than the frame: the pose it was captured from comes with it.
    captured = read["scene"] - (0 if match_depth_view else QUEST.stale_depth_scene_frames)
    assert read["scene"] >= 1
    frame = quest_feed.frame(captured)
    for k, view in enumerate(read["views"]):
        assert (view["eye"], view["textureType"], view["imageIndex"]) == (
            ("left", "right")[k],
            "texture-array",
            k,
        )
        assert (view["width"], view["height"]) == (QUEST.depth.width, QUEST.depth.height)
        assert (view["depthNear"], view["depthFar"]) == (QUEST.depth_near_m, None)
        np.testing.assert_allclose(matrix(view["normDepthBufferFromNormView"]), np.eye(4))
        sensor = matrix(view["transform"])
        np.testing.assert_allclose(sensor, frame.depth_sensors[k], atol=2e-6)
        assert np.linalg.norm(sensor[:3, 3] - matrix(view["view"]["transform"])[:3, 3]) > 0.04
        np.testing.assert_allclose(
            matrix(view["projection"]),
            QUEST.depth_pinholes()[k].projection(QUEST.depth_near_m, None),
            rtol=1e-5,
            atol=1e-6,
        )
        assert len(view["points"]) > 1000
        off = quest_feed.truth.distance(view["points"])
        assert np.median(off) < 0.001 and np.quantile(off, 0.99) < 0.005, (
            np.median(off),
            np.quantile(off, 0.99),
        )
        # The wrong ways: the render view's geometry, rows top first, the values as metres.
        for wrong in ("renderView", "topRowFirst", "asMetres"):
            assert np.median(quest_feed.truth.distance(view[wrong])) > 0.02, wrong


def test_quest_refuses_camera_access_and_has_no_camera_on_its_views(xr_page, quest_feed):
    open_probe(xr_page, quest_feed)
    assert xr_page.evaluate("navigator.xr.isSessionSupported('immersive-ar')") is True
    assert refusal(xr_page, {"requiredFeatures": ["camera-access"]}) == "NotSupportedError"
    info = start(xr_page, {"optionalFeatures": ["camera-access", "local-floor"]})
    assert "camera-access" not in info["features"] and "local-floor" in info["features"]
    cameras = xr_page.evaluate(
        "probe.inFrame((time, frame, pose) => pose.views.map((v) => v.camera))"
    )
    assert cameras == [None, None]


@pytest.mark.parametrize("delay", [0, 1])
def test_quest_getusermedia_shows_the_passthrough_camera_of_the_current_scene_frame(
    xr_page, quest_feed, delay
):
    open_probe(xr_page, quest_feed, videoDelaySceneFrames=delay)
    before = xr_page.evaluate("probe.video()")  # no session yet: the walk's first frame
    assert (before["width"], before["height"]) == (QUEST.color.width, QUEST.color.height)
    assert before["scene"] == 0
    start(xr_page, {}, "local")
    xr_page.evaluate("probe.inFrame(() => fakeXR.pause(), 5)")
    during = xr_page.evaluate("probe.video()")
    # The video shows the camera `delay` scene frames behind the pose of the XR frame.
    assert during["scene"] == 5 // HOLD - delay
    for shown in (before, during):
        image = rgba(shown)[:, :, :3].astype(int)
        truth = quest_feed.frame(shown["scene"]).camera_rgb.astype(int)
        assert np.abs(image - truth).mean() < 2.0
        assert np.abs(image[::-1] - truth).mean() > 10  # the right way up
    xr_page.evaluate("fakeXR.resume()")


def test_the_quest_eyes_mirror_each_other_and_its_depth_views_are_wider():
    left, right = QUEST.eye_pinholes()
    assert right.cx == pytest.approx(left.width - 1 - left.cx)
    fov = lambda p: 2 * math.degrees(math.atan(p.width / (2 * p.fx)))  # noqa: E731
    assert fov(QUEST.depth) > fov(QUEST.eye)
