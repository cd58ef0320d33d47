"""iPhone and iPad captures as device sources: Record3D's .r3d and Stray Scanner's folder.

The captures are written by the tests (phone_captures.py: the synthetic living room rendered
at a LiDAR iPhone's geometry, scaled by 1/4), not recorded on a phone. What the sources give
back is checked against what was rendered: frames, intrinsics, depth in metres, OpenCV
camera-to-world poses, and world points that land where the renderer put the surface.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import httpx
import lzfse
import numpy as np
import pytest
from phone_captures import (
    DEPTH_SIZE_PX,
    Capture,
    jpeg_bytes,
    record3d_metadata,
    render_capture,
    rewrite_r3d_entry,
    write_r3d,
    write_stray,
)
from PIL import Image

from app.mapping.geometry import backproject
from client_sim.sources import SourceError, make_source
from client_sim.sources.phone import (
    arkit_pose_to_opencv,
    output_size_px,
    scale_intrinsics,
)
from client_sim.sources.record3d import Record3DSource
from client_sim.sources.stray import StraySource

pytestmark = pytest.mark.timeout(120)

REPO_ROOT = Path(__file__).resolve().parents[3]
N_FRAMES = 4


@pytest.fixture(scope="module")
def capture() -> Capture:
    return render_capture(N_FRAMES)


@pytest.fixture(scope="module")
def captures(capture, tmp_path_factory) -> dict[str, Path]:
    """One capture of each kind, written once (tests that break one write their own)."""
    folder = tmp_path_factory.mktemp("captures")
    return {
        "record3d": write_r3d(folder / "living.r3d", capture),
        "stray": write_stray(folder / "living", capture),
    }


def sensor_centre_pixels(size_px: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(u, v) int [N] of the colour pixels (of an image of `size_px`) nearest the centres of
    the depth sensor's pixels: where a depth pixel's value was measured."""
    scale_x, scale_y = size_px[0] / DEPTH_SIZE_PX[0], size_px[1] / DEPTH_SIZE_PX[1]
    u = np.round((np.arange(DEPTH_SIZE_PX[0]) + 0.5) * scale_x - 0.5).astype(int)
    v = np.round((np.arange(DEPTH_SIZE_PX[1]) + 0.5) * scale_y - 0.5).astype(int)
    v, u = np.meshgrid(v, u, indexing="ij")
    return u.ravel(), v.ravel()


def distances_to_surface_m(frame, capture: Capture) -> np.ndarray:
    """How far (m) the frame's depth, back-projected at the colour pixels nearest the sensor's
    pixel centres (where each depth value was measured), lands from the room's surfaces."""
    u, v = sensor_centre_pixels((frame.rgb.shape[1], frame.rgb.shape[0]))
    z_m = frame.depth_m[v, u]
    keep = z_m > 0
    points = backproject(u[keep], v[keep], z_m[keep], frame.intrinsics, frame.pose)
    return capture.distances_to_surface_m(points)


# --- the conventions, one function each ---------------------------------------------------


def test_an_arkit_pose_turns_into_opencv_camera_axes_a_known_point_shows_it():
    # An ARKit camera at (1, 2, 3) with no rotation looks down the world's -z, y up.
    pose_arkit = np.eye(4)
    pose_arkit[:3, 3] = (1.0, 2.0, 3.0)
    world_from_camera = arkit_pose_to_opencv(pose_arkit)
    # 2 m ahead of it and 0.5 m above: OpenCV camera z = 2 (forward), y = -0.5 (up is -y).
    point = np.array([1.0, 2.5, 1.0, 1.0])
    np.testing.assert_allclose(np.linalg.inv(world_from_camera) @ point, [0.0, -0.5, 2.0, 1.0])
    # Turned 90 degrees to its left (about the world's y, up): it looks down the world's -x,
    # its right is the world's -z.
    pose_arkit[:3, :3] = [[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]
    world_from_camera = arkit_pose_to_opencv(pose_arkit)
    point = np.array([-1.0, 2.0, 2.0, 1.0])  # 2 m ahead, 1 m to the right
    np.testing.assert_allclose(
        np.linalg.inv(world_from_camera) @ point, [1.0, 0.0, 2.0, 1.0], atol=1e-12
    )
    assert np.linalg.det(world_from_camera[:3, :3]) == pytest.approx(1.0)


def test_frames_are_scaled_to_the_devices_size_with_their_intrinsics():
    assert output_size_px((1920, 1440), 640) == (640, 480)
    assert output_size_px((720, 960), 640) == (480, 640)  # portrait stays portrait
    assert output_size_px((480, 360), 640) == (480, 360)  # never scaled up
    assert output_size_px((1920, 1440), None) == (1920, 1440)
    # The same point seen in both images: x_small + 0.5 = (x_big + 0.5) / 3.
    fx, fy, cx, cy = scale_intrinsics((1500.0, 1500.0, 955.0, 721.0), (1920, 1440), (640, 480))
    x_cam, y_cam = 0.1, -0.2  # a ray (x/z, y/z)
    assert fx * x_cam + cx + 0.5 == pytest.approx((1500.0 * x_cam + 955.0 + 0.5) / 3)
    assert fy * y_cam + cy + 0.5 == pytest.approx((1500.0 * y_cam + 721.0 + 0.5) / 3)


# --- both sources give back what the phone saw -------------------------------------------


@pytest.mark.parametrize("kind", ["record3d", "stray"])
def test_a_capture_gives_back_its_frames_intrinsics_poses_and_times(kind, captures, capture):
    source = make_source(f"{kind}:{captures[kind]}")
    assert len(source) == N_FRAMES
    assert source.intrinsics == pytest.approx(capture.camera.intrinsics)
    for frame in source.frames():
        assert frame.rgb.shape == (360, 480, 3) and frame.rgb.dtype == np.uint8
        # JPEG (q95) and HEVC (crf 10) bring the colour back within a few levels
        assert np.abs(frame.rgb.astype(int) - capture.rgb[frame.index]).mean() < 4
        assert frame.depth_m.shape == (360, 480) and frame.depth_m.dtype == np.float32
        np.testing.assert_allclose(frame.pose, capture.poses[frame.index], atol=1e-6)
        assert frame.t == pytest.approx(capture.times_s[frame.index] - capture.times_s[0])
        assert frame.instance_ids is None and frame.instances is None  # the apps label nothing


@pytest.mark.parametrize("kind", ["record3d", "stray"])
def test_depth_is_metres_at_the_nearest_sensor_pixel(kind, captures, capture):
    frame = make_source(f"{kind}:{captures[kind]}").frame(2)
    sensor = capture.depth_m[2].copy()
    sensor[capture.confidence[2] < 1] = 0.0
    # Colour pixel (u, v) takes the sensor pixel its centre falls in (1920/256 = 7.5 here too);
    # a centre on a border between two (every 15th pixel) may take either.
    row_at, col_at = (np.arange(360) + 0.5) * 48 / 360, (np.arange(480) + 0.5) * 64 / 480
    inside = np.outer(row_at % 1 != 0, col_at % 1 != 0)
    expected = sensor[np.ix_(row_at.astype(int), col_at.astype(int))]
    tolerance_m = 1.0001e-3 if kind == "stray" else 0.0  # Stray's PNGs: whole millimetres
    np.testing.assert_allclose(frame.depth_m[inside], expected[inside], atol=tolerance_m, rtol=0)


@pytest.mark.parametrize("kind", ["record3d", "stray"])
def test_back_projected_depth_lands_on_the_rendered_surface(kind, captures, capture):
    for frame in make_source(f"{kind}:{captures[kind]}").frames():
        gaps_m = distances_to_surface_m(frame, capture)
        assert len(gaps_m) > 0.8 * DEPTH_SIZE_PX[0] * DEPTH_SIZE_PX[1]
        # A colour pixel is within a quarter pixel of the sensor pixel's centre; Stray
        # truncates to millimetres. (Measured: median 1.4 mm, at most 4.2 mm; with the camera's
        # y and z unflipped the median is 1.8 m.)
        assert np.median(gaps_m) < 3e-3
        assert np.max(gaps_m) < 1e-2


@pytest.mark.parametrize("kind", ["record3d", "stray"])
def test_a_smaller_device_size_scales_frames_and_intrinsics_and_depth_still_lands(
    kind, captures, capture
):
    source = make_source(f"{kind}:{captures[kind]}", max_side_px=240)
    frame = source.frame(1)
    assert source.size_px == (240, 180)
    assert frame.rgb.shape == (180, 240, 3) and frame.depth_m.shape == (180, 240)
    fx, fy, cx, cy = capture.camera.intrinsics
    assert frame.intrinsics == pytest.approx(
        (fx / 2, fy / 2, (cx + 0.5) / 2 - 0.5, (cy + 0.5) / 2 - 0.5)
    )
    gaps_m = distances_to_surface_m(frame, capture)  # within half a 240 px pixel: 2.7 mm median
    assert np.median(gaps_m) < 5e-3 and np.percentile(gaps_m, 90) < 1e-2


@pytest.mark.parametrize("kind", ["record3d", "stray"])
def test_low_confidence_depth_is_dropped_at_the_threshold(kind, captures):
    spec = f"{kind}:{captures[kind]}"
    # Sensor rows 0-7: columns 0-7 are "low" (0), 8-15 "medium" (1); colour pixels 0..59
    # cover those rows, columns 0..59 and 60..119 those columns.
    low, medium = (slice(0, 59), slice(0, 59)), (slice(0, 59), slice(61, 119))
    default = make_source(spec).frame(0).depth_m
    assert np.all(default[low] == 0) and np.all(default[medium] > 0)
    only_high = make_source(spec, min_confidence=2).frame(0).depth_m
    assert np.all(only_high[medium] == 0)
    keep_all = make_source(spec, min_confidence=0).frame(0).depth_m
    assert np.all(keep_all[low] > 0)


def test_record3d_without_timestamps_counts_time_at_its_fps(tmp_path, capture):
    metadata = record3d_metadata(capture)
    del metadata["frameTimestamps"]
    source = Record3DSource(write_r3d(tmp_path / "old.r3d", capture, metadata))
    assert [frame.t for frame in source.frames()] == pytest.approx([0.0, 1 / 60, 2 / 60, 3 / 60])


def test_stray_video_shorter_than_the_odometry_leaves_the_extra_rows_out(tmp_path, capture):
    source = StraySource(write_stray(tmp_path / "cut", capture, video_frames=3))
    assert len(source) == 3
    # read backwards: the video is decoded again from the start
    assert [f.index for f in (source.frame(2), source.frame(0))] == [2, 0]


# --- bad input: an error naming the file and what is wrong --------------------------------


def test_record3d_missing_or_not_a_zip_is_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.r3d"):
        Record3DSource(tmp_path / "nope.r3d")
    (tmp_path / "notes.r3d").write_text("this is not a zip")
    with pytest.raises(SourceError, match=r"notes\.r3d: not a Record3D .r3d capture \(not a zip"):
        Record3DSource(tmp_path / "notes.r3d")


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda m: m.pop("K"), r"metadata: lacks K"),
        (lambda m: m.update(w=0), r"metadata: 'w' must be a positive integer"),
        # row-major by mistake: cx, cy land in the bottom row
        (
            lambda m: m.update(K=[m["K"][0], 0, m["K"][6], 0, m["K"][4], m["K"][7], 0, 0, 1]),
            r"metadata K \(column-major\): not a pinhole",
        ),
        (lambda m: m["poses"][2].__setitem__(3, 3.0), r"metadata poses\[2\]: quaternion norm"),
        (lambda m: m["poses"][1].pop(), r"metadata poses\[1\]: expected \[qx, qy, qz, qw"),
        (lambda m: m["poses"].pop(), r"metadata: has 3 poses, but the archive holds frame rgbd/3"),
        (lambda m: m.update(dw=48, dh=64), r"metadata: depth is 48x64, which is not the aspect"),
    ],
)
def test_record3d_bad_metadata_is_named(tmp_path, capture, change, message):
    metadata = record3d_metadata(capture)
    change(metadata)
    path = write_r3d(tmp_path / "bad.r3d", capture, metadata)
    with pytest.raises(ValueError, match=message):  # a SourceError, or the pose check's
        Record3DSource(path)


def test_record3d_missing_metadata_or_depth_is_named(tmp_path, capture):
    path = write_r3d(tmp_path / "scan.r3d", capture)
    rewrite_r3d_entry(path, "rgbd/1.depth", None)
    with pytest.raises(SourceError, match=r"scan\.r3d: frame 1 has no depth \(rgbd/1\.depth\)"):
        Record3DSource(path)
    rewrite_r3d_entry(path, "metadata", None)
    with pytest.raises(SourceError, match=r"scan\.r3d: no 'metadata' in the archive"):
        Record3DSource(path)


@pytest.mark.parametrize(
    ("entry", "data", "message"),
    [
        (
            "rgbd/2.depth",
            lzfse.compress(b"\0" * 999),
            r"rgbd/2\.depth: 999 bytes after LZFSE, expected 64x48 float32",
        ),
        ("rgbd/2.depth", b"not lzfse at all", r"rgbd/2\.depth: not LZFSE-compressed data"),
        ("rgbd/2.conf", lzfse.compress(b"\2" * 10), r"rgbd/2\.conf: 10 bytes after LZFSE"),
        ("rgbd/2.jpg", b"\xff\xd8 broken", r"rgbd/2\.jpg: not a readable image"),
        (
            "rgbd/2.jpg",
            jpeg_bytes(np.zeros((10, 10, 3), np.uint8)),
            r"rgbd/2\.jpg: image is 10x10, but the metadata says 480x360",
        ),
    ],
)
def test_record3d_a_broken_frame_is_named_when_it_is_read(tmp_path, capture, entry, data, message):
    path = write_r3d(tmp_path / "scan.r3d", capture)
    rewrite_r3d_entry(path, entry, data)
    source = Record3DSource(path)
    source.frame(1)  # the others still read
    with pytest.raises(SourceError, match=message):
        source.frame(2)


def test_stray_missing_files_are_named(tmp_path, capture):
    with pytest.raises(FileNotFoundError, match="Stray Scanner capture folder not found"):
        StraySource(tmp_path / "nowhere")
    for name in ("camera_matrix.csv", "odometry.csv", "rgb.mp4", "depth/000002.png"):
        folder = write_stray(tmp_path / name.replace("/", "_"), capture)
        (folder / name).unlink()
        with pytest.raises(FileNotFoundError, match=name):
            StraySource(folder)


@pytest.mark.parametrize(
    ("name", "content", "message"),
    [
        ("rgb.mp4", "not a video", r"rgb\.mp4: not a readable video"),
        ("camera_matrix.csv", "1, 0, 2\n0, 1, 3", r"camera_matrix\.csv: expected a 3x3 matrix"),
        (
            "camera_matrix.csv",  # intrinsics of a 1920x1440 frame, not of the 480x360 video
            "1500, 0, 955\n0, 1500, 721\n0, 0, 1",
            r"camera_matrix\.csv: principal point \(955, 721\) is outside the 480x360 video",
        ),
        ("odometry.csv", "timestamp, x, y, z\n", r"odometry\.csv:1: header lacks frame, qx"),
        ("odometry.csv", "", r"odometry\.csv: empty"),
    ],
)
def test_stray_bad_files_are_named(tmp_path, capture, name, content, message):
    folder = write_stray(tmp_path / "scan", capture)
    (folder / name).write_text(content)
    with pytest.raises(SourceError, match=message):
        StraySource(folder)


def test_stray_a_pose_that_is_not_a_rotation_names_its_line(tmp_path, capture):
    folder = write_stray(tmp_path / "scan", capture)
    lines = (folder / "odometry.csv").read_text().splitlines()
    fields = lines[3].split(", ")
    fields[-1] = "2.5"  # qw: the quaternion is no longer a unit one
    lines[3] = ", ".join(fields)
    (folder / "odometry.csv").write_text("\n".join(lines))
    with pytest.raises(ValueError, match=r"odometry\.csv:4: quaternion norm is"):
        StraySource(folder)


def test_stray_a_broken_depth_image_is_named_when_it_is_read(tmp_path, capture):
    folder = write_stray(tmp_path / "scan", capture)
    Image.fromarray(np.zeros((48, 64), np.uint8)).save(folder / "depth" / "000001.png")
    (folder / "depth" / "000002.png").write_bytes(b"\x89PNG broken")
    Image.fromarray(np.zeros((48, 60), np.uint8)).save(folder / "confidence" / "000003.png")
    source = StraySource(folder)
    with pytest.raises(SourceError, match=r"000001\.png: expected a 16-bit"):
        source.frame(1)
    with pytest.raises(SourceError, match=r"000002\.png: not a readable PNG"):
        source.frame(2)
    with pytest.raises(SourceError, match=r"000003\.png: confidence is 60x48, depth 64x48"):
        source.frame(3)


# --- the factory and the device command ---------------------------------------------------


def test_make_source_for_a_phone_capture_does_not_import_the_synthetic_world(captures):
    code = (
        "import sys\n"
        "from client_sim.sources import make_source\n"
        f"make_source({'record3d:' + str(captures['record3d'])!r}).frame(0)\n"
        f"make_source({'stray:' + str(captures['stray'])!r}).frame(0)\n"
        "assert 'world.scene' not in sys.modules\n"
        "assert 'open3d' not in sys.modules\n"
    )
    subprocess.run([sys.executable, "-c", code], cwd=REPO_ROOT, check=True, timeout=60)


def device_args(*argv: str) -> argparse.Namespace:
    from app.cli.device import add_parser

    parser = argparse.ArgumentParser()
    add_parser(parser.add_subparsers(dest="command"))
    return parser.parse_args(["device", *argv])


@pytest.mark.slow
def test_the_device_streams_a_stray_capture_to_a_real_server(live_server, captures, capsys):
    server = live_server()
    args = device_args(
        "--server", server.url, "--create", "--source", f"stray:{captures['stray']}", "--fps", "0"
    )
    assert args.func(args) == 0
    err = capsys.readouterr().err
    sid = err.split("created session ")[1].split()[0]
    stats = httpx.get(f"{server.url}/v1/sessions/{sid}").json()
    assert stats["keyframes"] >= 1 and stats["frames"] >= 1
    # a capture carries no detections: the server says how to map it, once
    assert err.count("server warns: ") == 1 and "--perception models" in err


def test_the_device_names_a_capture_it_cannot_use_and_exits_2(tmp_path, capsys):
    missing = device_args("--server", "http://127.0.0.1:9", "--create")
    missing.source = f"record3d:{tmp_path / 'no.r3d'}"
    assert missing.func(missing) == 2
    assert f"Record3D capture (.r3d) not found: {tmp_path / 'no.r3d'}" in capsys.readouterr().err
    wrong_kind = device_args(
        "--server",
        "http://127.0.0.1:9",
        "--create",
        "--source",
        "tum:/x",
        "--source-max-side",
        "320",
    )
    assert wrong_kind.func(wrong_kind) == 2
    assert "--source-max-side applies to record3d and stray" in capsys.readouterr().err


@pytest.mark.slow
def test_a_frame_that_breaks_mid_stream_stops_the_device_naming_the_file(
    tmp_path, capture, capsys, live_server
):
    path = write_r3d(tmp_path / "scan.r3d", capture)
    rewrite_r3d_entry(path, "rgbd/2.depth", b"garbage")
    server = live_server()
    args = device_args(
        "--server", server.url, "--create", "--source", f"record3d:{path}", "--fps", "0"
    )
    assert args.func(args) == 2
    err = capsys.readouterr().err
    assert f"semanticxr device: {path}:rgbd/2.depth: not LZFSE-compressed data" in err
    assert "Traceback" not in err
