"""Small iPhone captures, written the way Record3D and Stray Scanner write them.

A few frames of the synthetic living room with known poses, rendered at a LiDAR iPhone's
geometry scaled by 1/4: colour 480x360 (1920x1440), depth 64x48 (256x192) over the same field
of view, so depth is 7.5 times coarser than colour, as on the phone. The writers follow the
apps' conventions (see client_sim/sources/record3d.py and stray.py for where each comes from),
spelled out here independently of the readers.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass, field
from fractions import Fraction
from io import BytesIO
from pathlib import Path

import av
import lzfse
import numpy as np
import open3d as o3d
from PIL import Image
from scipy.spatial.transform import Rotation

from client_sim.sources.phone import scale_intrinsics
from client_sim.sources.synthetic import SyntheticSource
from world.render import Camera, default_camera

CAPTURE_SIZE_PX = (480, 360)
DEPTH_SIZE_PX = (64, 48)
WALK_FRAMES, FRAME_STEP = 60, 6  # frames 0, 6, 12, ... of a 60-frame walk: a few cm apart
GL_FROM_CV = np.diag([1.0, -1.0, -1.0, 1.0])
"""ARKit's camera axes (x right, y up, z back) from OpenCV's: the same half turn about x
either way. Spelled out here so the writers do not borrow the reader's conversion."""
BOOT_TIME_S = 5123.25  # ARKit timestamps count from the phone's boot


@dataclass
class Capture:
    """What the phone saw; every list has one entry per frame."""

    rgb: list[np.ndarray] = field(default_factory=list)
    """uint8 [360, 480, 3]."""
    depth_m: list[np.ndarray] = field(default_factory=list)
    """float32 [48, 64]: the depth camera's z-depth, metres (0: nothing hit)."""
    confidence: list[np.ndarray] = field(default_factory=list)
    """uint8 [48, 64]: 0 in the top-left 8x8 block, 1 in the next 8 columns, 2 elsewhere."""
    truth_depth_m: list[np.ndarray] = field(default_factory=list)
    """float32 [360, 480]: the renderer's z-depth at colour size, the ground truth."""
    poses: list[np.ndarray] = field(default_factory=list)
    """float64 [4, 4] camera-to-world, OpenCV camera axes."""
    times_s: list[float] = field(default_factory=list)
    """Capture times, ARKit's clock (seconds since boot)."""
    camera: Camera = field(default_factory=lambda: default_camera(*CAPTURE_SIZE_PX))
    """The colour camera (intrinsics of the 480x360 image)."""
    surfaces: o3d.t.geometry.RaycastingScene | None = None
    """The room's meshes, to measure how far a point is from the nearest surface."""

    def distances_to_surface_m(self, points: np.ndarray) -> np.ndarray:
        """float [N]: how far each world point [N, 3] is from the room's nearest surface."""
        query = o3d.core.Tensor(np.asarray(points, np.float32))
        return self.surfaces.compute_distance(query).numpy()


def render_capture(n_frames: int = 4) -> Capture:
    """`n_frames` frames of a walk through the living room, FRAME_STEP frames apart."""
    walk = SyntheticSource("living_room", n_frames=WALK_FRAMES, noise="none")
    capture = Capture(surfaces=o3d.t.geometry.RaycastingScene())
    for obj in walk.scene.objects:
        capture.surfaces.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(obj.mesh))
    depth_camera = Camera(
        *DEPTH_SIZE_PX,
        *scale_intrinsics(capture.camera.intrinsics, CAPTURE_SIZE_PX, DEPTH_SIZE_PX),
    )
    for i in range(n_frames):
        pose = walk.poses[i * FRAME_STEP]
        view = walk.renderer.render(pose, capture.camera, texture_noise=0.03)
        confidence = np.full(DEPTH_SIZE_PX[::-1], 2, np.uint8)
        confidence[:8, :8] = 0
        confidence[:8, 8:16] = 1
        capture.rgb.append(view.rgb)
        capture.truth_depth_m.append(view.depth_m)
        capture.depth_m.append(walk.renderer.render(pose, depth_camera).depth_m)
        capture.confidence.append(confidence)
        capture.poses.append(pose)
        capture.times_s.append(BOOT_TIME_S + i * FRAME_STEP / 60)
    return capture


def jpeg_bytes(rgb: np.ndarray) -> bytes:
    buffer = BytesIO()
    Image.fromarray(rgb).save(buffer, format="JPEG", quality=95)
    return buffer.getvalue()


# --- Record3D ------------------------------------------------------------------------------


def record3d_metadata(capture: Capture) -> dict:
    """Record3D's metadata document of `capture`: K column-major, poses ARKit camera-to-world
    as [qx, qy, qz, qw, px, py, pz]."""
    camera = capture.camera
    poses = []
    for pose in capture.poses:
        arkit = pose @ GL_FROM_CV
        poses.append([*Rotation.from_matrix(arkit[:3, :3]).as_quat(), *arkit[:3, 3]])
    return {
        "w": CAPTURE_SIZE_PX[0],
        "h": CAPTURE_SIZE_PX[1],
        "dw": DEPTH_SIZE_PX[0],
        "dh": DEPTH_SIZE_PX[1],
        "K": [camera.fx, 0.0, 0.0, 0.0, camera.fy, 0.0, camera.cx, camera.cy, 1.0],
        "fps": 60,
        "poses": poses,
        "initPose": poses[0],
        "frameTimestamps": capture.times_s,
        "cameraType": 1,
    }


def write_r3d(path: Path, capture: Capture, metadata: dict | None = None) -> Path:
    """A .r3d zip of `capture` (with `metadata` instead of the true one, if given)."""
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("metadata", json.dumps(metadata or record3d_metadata(capture)))
        for i, rgb in enumerate(capture.rgb):
            archive.writestr(f"rgbd/{i}.jpg", jpeg_bytes(rgb))
            depth = capture.depth_m[i].astype("<f4")
            archive.writestr(f"rgbd/{i}.depth", lzfse.compress(depth.tobytes()))
            archive.writestr(f"rgbd/{i}.conf", lzfse.compress(capture.confidence[i].tobytes()))
    return path


def rewrite_r3d_entry(path: Path, entry: str, data: bytes | None) -> None:
    """Replace (None: remove) one entry of a .r3d archive."""
    with zipfile.ZipFile(path) as archive:
        entries = {name: archive.read(name) for name in archive.namelist()}
    if data is None:
        del entries[entry]
    else:
        entries[entry] = data
    with zipfile.ZipFile(path, "w") as archive:
        for name, content in entries.items():
            archive.writestr(name, content)


# --- Stray Scanner -------------------------------------------------------------------------

STRAY_HALF_TURN_ABOUT_X = Rotation.from_quat([1.0, 0.0, 0.0, 0.0])
"""Stray Scanner's q_AC (OdometryEncoder.swift): it writes q_WA * q_AC."""


def write_stray(folder: Path, capture: Capture, video_frames: int | None = None) -> Path:
    """A Stray Scanner capture folder of `capture` (the video cut to `video_frames`)."""
    (folder / "depth").mkdir(parents=True, exist_ok=True)
    (folder / "confidence").mkdir(exist_ok=True)
    write_hevc(folder / "rgb.mp4", capture.rgb[:video_frames])
    rows = ["timestamp, frame, x, y, z, qx, qy, qz, qw"]
    for i, pose in enumerate(capture.poses):
        arkit = pose @ GL_FROM_CV  # ARFrame.camera.transform
        q_wa = Rotation.from_matrix(arkit[:3, :3])
        qx, qy, qz, qw = (q_wa * STRAY_HALF_TURN_ABOUT_X).as_quat()
        x, y, z = arkit[:3, 3]
        rows.append(f"{capture.times_s[i]}, {i:06d}, {x}, {y}, {z}, {qx}, {qy}, {qz}, {qw}")
        depth_mm = (capture.depth_m[i] * 1000).astype(np.uint16)  # the app truncates
        Image.fromarray(depth_mm).save(folder / "depth" / f"{i:06d}.png")
        Image.fromarray(capture.confidence[i]).save(folder / "confidence" / f"{i:06d}.png")
    (folder / "odometry.csv").write_text("\n".join(rows) + "\n")
    camera = capture.camera
    (folder / "camera_matrix.csv").write_text(
        f"{camera.fx}, 0.0, {camera.cx}\n0.0, {camera.fy}, {camera.cy}\n0.0, 0.0, 1.0"
    )
    return folder


def write_hevc(path: Path, frames: list[np.ndarray]) -> None:
    """An HEVC mp4 of RGB frames at 60 fps, as the app records (quality high enough that the
    colour comes back within a few levels)."""
    with av.open(str(path), "w") as container:
        stream = container.add_stream(
            "libx265", rate=60, options={"crf": "10", "x265-params": "log-level=error"}
        )
        stream.width, stream.height = frames[0].shape[1], frames[0].shape[0]
        stream.pix_fmt = "yuv420p"
        stream.time_base = Fraction(1, 60)
        for rgb in frames:
            container.mux(stream.encode(av.VideoFrame.from_ndarray(rgb, format="rgb24")))
        container.mux(stream.encode())
