"""The real-device page's pure modules (static/xr/), run in real Chromium as the page runs
them: the one conversion from WebXR's camera to the protocol's, the keyframe rule, the 16-bit
PNG encoder, depth onto the protocol's grid; and the page's wire names against app/protocol."""

from __future__ import annotations

import io
import math
import re

import msgpack
import numpy as np
import pytest
from PIL import Image

from app.keyframes import is_keyframe
from app.mapping.geometry import project_to_pixels
from app.server.routes.pages import STATIC_DIR


@pytest.fixture
def modules(xr_browser, live_server):
    """A page on the server's origin that can import /static/xr/*.mjs."""
    server = live_server()
    page = xr_browser.new_page()
    page.goto(f"{server.url}/healthz")
    yield page
    page.close()


def run(page, body: str, arg=None):
    """Run `body` (an async function body that may `await import(...)`) in the page."""
    return page.evaluate(f"async (arg) => {{ {body} }}", arg)


def webxr_pose(position, yaw_rad, pitch_rad):
    """A WebXR camera transform (column-major list, camera looking down its -z, y up): turned
    by yaw about +y, then pitched about its x axis, at `position`."""
    cy, sy, cp, sp = math.cos(yaw_rad), math.sin(yaw_rad), math.cos(pitch_rad), math.sin(pitch_rad)
    yaw = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    pitch = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    m = np.eye(4)
    m[:3, :3] = yaw @ pitch
    m[:3, 3] = position
    return m


def gl_projection(fx, fy, cx, cy, width, height, near=0.1, far=20.0):
    """The OpenGL projection of a pinhole camera (pixel centres at integers, row 0 at the top),
    as a 4x4 array; an off-centre principal point makes P[8], P[9] non-zero."""
    p = np.zeros((4, 4))
    p[0, 0] = 2 * fx / width
    p[1, 1] = 2 * fy / height
    p[0, 2] = 1 - 2 * (cx + 0.5) / width
    p[1, 2] = 2 * (cy + 0.5) / height - 1
    p[2, 2] = -(far + near) / (far - near)
    p[2, 3] = -2 * far * near / (far - near)
    p[3, 2] = -1
    return p


def webxr_pixel(transform, projection, point, width, height):
    """Where WebXR's own pipeline puts a world point: clip = P V p, NDC, the viewport with row 0
    at the top (u, v pixel centres at integers)."""
    view = np.linalg.inv(transform)
    clip = projection @ view @ np.append(point, 1.0)
    ndc = clip[:3] / clip[3]
    return (ndc[0] + 1) * width / 2 - 0.5, (1 - ndc[1]) * height / 2 - 0.5


@pytest.mark.slow
def test_a_known_point_lands_on_the_same_pixel_through_webxr_and_through_the_protocol(modules):
    width, height = 640, 480
    fx, fy, cx, cy = 500.0, 505.0, 330.2, 236.7
    transform = webxr_pose([0.4, 1.5, -0.3], yaw_rad=0.6, pitch_rad=-0.3)
    projection = gl_projection(fx, fy, cx, cy, width, height)
    point = transform[:3, :3] @ np.array([0.3, -0.2, -2.0]) + transform[:3, 3]  # 2 m ahead
    expected = webxr_pixel(transform, projection, point, width, height)

    got = run(
        modules,
        """
        const c = await import('/static/xr/conventions.mjs');
        const camera = c.protocolCamera(arg.transform, arg.projection, arg.width, arg.height);
        return {pose: Array.from(camera.pose), intrinsics: camera.intrinsics,
                pixel: c.projectPoint(camera, arg.point)};
        """,
        {
            "transform": transform.T.ravel().tolist(),  # column-major, as WebXR gives it
            "projection": projection.T.ravel().tolist(),
            "width": width,
            "height": height,
            "point": point.tolist(),
        },
    )
    np.testing.assert_allclose(got["intrinsics"], [fx, fy, cx, cy], atol=1e-3)
    assert got["pixel"]["u"] == pytest.approx(expected[0], abs=1e-3)
    assert got["pixel"]["v"] == pytest.approx(expected[1], abs=1e-3)
    assert got["pixel"]["z"] == pytest.approx(2.0, abs=1e-4)
    # The server's own projection (app/mapping/geometry.py) of the pose as it goes on the wire.
    pose = np.frombuffer(np.asarray(got["pose"], np.float32).tobytes(), np.float32).reshape(4, 4)
    u, v, z = project_to_pixels(point[None], pose.astype(np.float64), (fx, fy, cx, cy))
    assert (u[0], v[0]) == (round(expected[0]), round(expected[1]))
    assert z[0] == pytest.approx(2.0, abs=1e-4)


@pytest.mark.slow
def test_the_page_picks_the_keyframes_the_python_selector_picks(modules):
    picked = run(
        modules,
        """
        const k = await import('/static/xr/keyframes.mjs');
        const out = [];
        for (const interval of [1, 3, 5]) for (let i = 0; i < 23; i++) out.push(k.isKeyframe(i, interval));
        // Sampled at 5 fps from a 72 Hz loop: one frame in every 200 ms, none in between.
        const sampler = new k.FrameSampler(5);
        const taken = [];
        for (let f = 0; f < 72 * 2; f++) if (sampler.take(f * 1000 / 72)) taken.push(f * 1000 / 72);
        return {out, taken};
        """,
    )
    expected = [is_keyframe(i, interval) for interval in (1, 3, 5) for i in range(23)]
    assert picked["out"] == expected
    taken = np.array(picked["taken"])
    assert len(taken) == 10  # two seconds at 5 fps
    assert np.all(np.diff(taken) >= 200 - 1000 / 72)


@pytest.mark.slow
def test_the_page_png_decodes_to_the_same_uint16_depth(modules):
    rng = np.random.default_rng(3)
    depth = (rng.integers(0, 65536, size=(96, 128))).astype(np.uint16)
    depth[:10] = 0
    depth[50:60, 20:30] = 65535
    data = run(
        modules,
        """
        const png = await import('/static/xr/png.mjs');
        const bytes = await png.encodeUint16Png(Uint16Array.from(arg.values), arg.w, arg.h);
        return Array.from(bytes);
        """,
        {"values": depth.ravel().tolist(), "w": 128, "h": 96},
    )
    image = Image.open(io.BytesIO(bytes(data)))
    assert image.size == (128, 96)
    np.testing.assert_array_equal(np.asarray(image).astype(np.uint16), depth)


@pytest.mark.slow
def test_cpu_depth_is_read_through_norm_depth_buffer_from_norm_view(modules):
    """A depth buffer stored transposed (a phone's sensor orientation): the page must index it
    through normDepthBufferFromNormView, or every depth lands on the wrong pixel."""
    width, height, ratio = 640, 480, 5
    dw, dh = 120, 160  # the buffer is stored rotated: rows of the buffer are columns of the view
    # truth[v, u] in the view's orientation, 1 mm steps so every pixel is distinct
    u = np.arange(width)
    v = np.arange(height)
    truth = 0.5 + 0.001 * (u[None, :] // 16) + 0.05 * (v[:, None] // 16)
    # Buffer pixel (col c, row r) holds the view at x = r / dh, y = c / dw (a transpose).
    buffer = np.zeros((dh, dw), np.uint16)
    for r in range(dh):
        for c in range(dw):
            x, y = (r + 0.5) / dh, (c + 0.5) / dw
            buffer[r, c] = round(truth[int(y * height), int(x * width)] / 0.001)
    transpose = [0, 1, 0, 0, 1, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]  # column-major: x' = y, y' = x
    got = run(
        modules,
        """
        const d = await import('/static/xr/depth.mjs');
        const values = d.rawDepthValues(Uint16Array.from(arg.buffer).buffer, 'luminance-alpha');
        const out = d.resampleCpuDepth({values, depthWidth: arg.dw, depthHeight: arg.dh,
            rawValueToMeters: 0.001, normDepthFromNormView: arg.m}, arg.width, arg.height, arg.ratio);
        return Array.from(out);
        """,
        {
            "buffer": buffer.ravel().tolist(),
            "dw": dw,
            "dh": dh,
            "m": transpose,
            "width": width,
            "height": height,
            "ratio": ratio,
        },
    )
    got = np.asarray(got, np.float32).reshape(height // ratio, width // ratio)
    centres_v = np.arange(height // ratio) * ratio + ratio // 2
    centres_u = np.arange(width // ratio) * ratio + ratio // 2
    expected = truth[np.ix_(centres_v, centres_u)]
    # Nearest buffer pixel: within one buffer pixel's worth of the 1 mm / 16 px ramp.
    np.testing.assert_allclose(got, expected, atol=0.0015 + 0.05 * (height / dh) / 16)
    assert np.mean(np.abs(got - expected) < 1e-3) > 0.8


@pytest.mark.slow
def test_reprojected_depth_lifts_back_onto_the_surface_it_came_from(modules):
    """A depth view looking at a plane from one pose, reprojected into a colour camera at
    another: every depth the colour camera gets lifts back onto the plane."""
    dw = dh = 96
    depth_transform = webxr_pose([0.0, 1.5, 0.0], yaw_rad=0.0, pitch_rad=0.0)
    depth_projection = gl_projection(60.0, 60.0, 47.5, 47.5, dw, dh)
    # The wall z = -2.5 (in front of the depth view): metric depth along its -z is 2.5.
    depth = np.full((dh, dw), 2.5, np.float32)
    colour = webxr_pose([0.05, 1.48, -0.06], yaw_rad=0.05, pitch_rad=-0.04)
    width, height, ratio = 320, 240, 4
    projection = gl_projection(260.0, 260.0, 159.5, 119.5, width, height)
    got = run(
        modules,
        """
        const c = await import('/static/xr/conventions.mjs');
        const d = await import('/static/xr/depth.mjs');
        const camera = c.protocolCamera(arg.colour, arg.projection, arg.width, arg.height);
        const out = d.reprojectDepth({depth: Float32Array.from(arg.depth), depthWidth: arg.dw,
            depthHeight: arg.dh, normDepthFromNormView: [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1],
            depthProjection: arg.depthProjection, depthTransform: arg.depthTransform},
            camera, arg.width, arg.height, arg.ratio);
        return {depth: Array.from(out), pose: Array.from(camera.pose), intrinsics: camera.intrinsics};
        """,
        {
            "depth": depth.ravel().tolist(),
            "dw": dw,
            "dh": dh,
            "depthProjection": depth_projection.T.ravel().tolist(),
            "depthTransform": depth_transform.T.ravel().tolist(),
            "colour": colour.T.ravel().tolist(),
            "projection": projection.T.ravel().tolist(),
            "width": width,
            "height": height,
            "ratio": ratio,
        },
    )
    z = np.asarray(got["depth"], np.float32).reshape(height // ratio, width // ratio)
    assert np.mean(z > 0) > 0.6  # most of the colour view sees the wall
    fx, fy, cx, cy = got["intrinsics"]
    pose = np.asarray(got["pose"], np.float64).reshape(4, 4)
    vv, uu = np.nonzero(z > 0)
    u_rgb, v_rgb = uu * ratio + ratio // 2, vv * ratio + ratio // 2
    zs = z[vv, uu]
    cam = np.stack([(u_rgb - cx) / fx * zs, (v_rgb - cy) / fy * zs, zs], axis=1)
    world = cam @ pose[:3, :3].T + pose[:3, 3]
    # The lifted points lie on the wall within the nearest-sample error (half a block).
    assert np.percentile(np.abs(world[:, 2] - (-2.5)), 95) < 0.02


def test_the_page_speaks_the_protocol_names_the_server_parses():
    """Every wire name the page writes is one app/protocol reads (a page cannot drift)."""
    worker = (STATIC_DIR / "xr" / "encode-worker.mjs").read_text()
    stream = (STATIC_DIR / "xr" / "stream.mjs").read_text()
    frame_py = (STATIC_DIR.parent / "app" / "protocol" / "frame.py").read_text()
    replies_py = (STATIC_DIR.parent / "app" / "protocol" / "replies.py").read_text()
    sighting_py = (STATIC_DIR.parent / "app" / "protocol" / "sighting.py").read_text()
    literal = worker[worker.index("const frame = {") :].split("};")[0]
    frame_keys = set(re.findall(r"^\s+(\w+)(?::|,$)", literal, re.M))  # key: value, or shorthand
    frame_keys |= set(re.findall(r"frame\.(\w+) =", worker))
    assert frame_keys >= {"type", "seq", "t", "pose", "intrinsics", "rgb", "depth", "pose_skew_s"}
    for key in frame_keys:
        assert f'"{key}"' in frame_py, (
            f"the page sends {key!r}, which app/protocol/frame.py never reads"
        )
    for part in ("codec", "w", "h", "scale", "data"):
        assert f'"{part}"' in frame_py
    for key in ("objects", "update_seq", "dropped"):
        assert f"reply.{key}" in stream and f'"{key}"' in replies_py
    subprotocol = re.search(r'SIGHTINGS_SUBPROTOCOL = "([^"]+)"', stream).group(1)
    assert f'"{subprotocol}"' in sighting_py
    assert msgpack  # the server's codec for these messages
