"""Record3D captures (iPhone/iPad with LiDAR): the app's `.r3d` export.

An `.r3d` file is a zip archive:

    metadata        JSON: "w", "h" (colour image size), "dw", "dh" (depth size), "K" (3x3
                    intrinsics of the colour image, flattened column-major:
                    [fx, 0, 0, 0, fy, 0, cx, cy, 1]), "fps", "poses" (one
                    [qx, qy, qz, qw, px, py, pz] per frame: ARKit camera-to-world, the camera
                    looking down -z with y up), and optionally "frameTimestamps" (s),
                    "initPose", "cameraType"
    rgbd/<n>.jpg    colour, w x h
    rgbd/<n>.depth  LZFSE-compressed float32 depth in metres, dw x dh, row-major
    rgbd/<n>.conf   LZFSE-compressed uint8 ARKit confidence 0..2, dw x dh (optional)

Where the conventions come from (public readers of the format, no format spec is published):
K column-major and its fx, fy, cx, cy at K[0], K[4], K[6], K[7] (Record3D's own
marek-simonik/record3d_offline_unity_demo, `Record3DVideo.cs`; nerfstudio-project/viser's
`_record3d.py` and codekansas/usa's r3d dataset: `reshape(3, 3).T`); K for the w x h image and
depth at dh rows of dw (usa's `read_metadata`/`get_arrs`); poses scalar-last, camera-to-world in
ARKit's camera axes, turned to OpenCV's by flipping the camera's y and z (viser and usa: `pose @
diag(1, -1, -1, 1)`). Exports without "dw"/"dh" had depth at w x h (the Unity demo decodes
w x h depth), so those default to w and h.

Frame n is rgbd/<n>.jpg with poses[n]; `SourceFrame.t` is frameTimestamps[n] counted from the
first frame, or n / fps when the export has no timestamps. Frames are scaled to the device's
size and low-confidence depth dropped as `client_sim.sources.phone` says. A Record3D capture
carries no detections: map it with `semanticxr serve --perception models`.
"""

from __future__ import annotations

import io
import json
import math
import re
import threading
import zipfile
import zlib
from pathlib import Path

import lzfse
import numpy as np
from PIL import Image, UnidentifiedImageError

from client_sim.sources.base import (
    SourceError,
    SourceFrame,
    checked_pose,
    pinhole_intrinsics,
    quaternion_to_matrix,
)
from client_sim.sources.phone import (
    DEVICE_MAX_SIDE_PX,
    MIN_CONFIDENCE,
    PhoneCaptureSource,
    arkit_pose_to_opencv,
    check_same_aspect,
)

METADATA_ENTRY = "metadata"
_RGB_ENTRY = re.compile(r"^rgbd/(\d+)\.jpg$")


class Record3DSource(PhoneCaptureSource):
    """Frames of one Record3D `.r3d` capture, in frame-number order.

    path: the .r3d file. max_side_px: the frames' longer side at most (None: the capture's
    size). min_confidence: depth under this ARKit confidence (0..2) is dropped (see
    `client_sim.sources.phone`).
    """

    def __init__(
        self,
        path: str | Path,
        *,
        max_side_px: int | None = DEVICE_MAX_SIDE_PX,
        min_confidence: int = MIN_CONFIDENCE,
    ):
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"Record3D capture (.r3d) not found: {path}")
        self.path = path
        self.name = f"record3d:{path.stem}"
        try:
            self._zip = zipfile.ZipFile(path)
        except (zipfile.BadZipFile, OSError) as exc:
            raise SourceError(f"{path}: not a Record3D .r3d capture (not a zip: {exc})") from None
        self._lock = threading.Lock()  # frames are read from worker threads
        self._entries = set(self._zip.namelist())
        where = f"{path}:{METADATA_ENTRY}"
        metadata = _parse_metadata(self._read(METADATA_ENTRY), where)
        self.depth_size_px: tuple[int, int] = metadata["depth_size_px"]
        """(width, height) of the depth images."""
        self.fps: float = metadata["fps"]
        check_same_aspect(metadata["size_px"], self.depth_size_px, where)
        self._set_output(metadata["size_px"], metadata["intrinsics"], max_side_px, min_confidence)

        numbers = sorted(int(m.group(1)) for name in self._entries if (m := _RGB_ENTRY.match(name)))
        if not numbers:
            raise SourceError(f"{path}: no frames (rgbd/<n>.jpg) in the archive")
        poses = metadata["poses"]
        if numbers[-1] >= len(poses):
            raise SourceError(
                f"{where}: has {len(poses)} poses, but the archive holds frame rgbd/{numbers[-1]}.jpg"
            )
        for number in numbers:
            if f"rgbd/{number}.depth" not in self._entries:
                raise SourceError(f"{path}: frame {number} has no depth (rgbd/{number}.depth)")
        self._numbers = numbers
        # Every pose is checked now, not 200 frames into a run.
        self._poses = [
            checked_pose(
                arkit_pose_to_opencv(_pose_matrix(poses[n], f"{where} poses[{n}]")),
                f"{where} poses[{n}]",
            )
            for n in numbers
        ]
        timestamps = metadata["timestamps_s"]
        if timestamps is not None and len(timestamps) > numbers[-1]:
            first = timestamps[numbers[0]]
            self._times_s = [timestamps[n] - first for n in numbers]
        else:
            self._times_s = [n / self.fps for n in numbers]

    def __len__(self) -> int:
        return len(self._numbers)

    def frame(self, index: int) -> SourceFrame:
        index = self._check_index(index)
        number = self._numbers[index]
        rgb_entry = f"rgbd/{number}.jpg"
        rgb = _decode_jpeg(self._read(rgb_entry), f"{self.path}:{rgb_entry}")
        if (rgb.shape[1], rgb.shape[0]) != self.capture_size_px:
            raise SourceError(
                f"{self.path}:{rgb_entry}: image is {rgb.shape[1]}x{rgb.shape[0]}, but the "
                f"metadata says {self.capture_size_px[0]}x{self.capture_size_px[1]}"
            )
        depth_m = self._lzfse_image(f"rgbd/{number}.depth", np.float32)
        confidence = None
        if f"rgbd/{number}.conf" in self._entries:
            confidence = self._lzfse_image(f"rgbd/{number}.conf", np.uint8)
        where = f"{self.path}:rgbd/{number}"
        return self._phone_frame(
            index, self._times_s[index], rgb, depth_m, confidence, self._poses[index], where
        )

    def _read(self, entry: str) -> bytes:
        """The bytes of a zip entry; SourceError naming it if it is missing or corrupt."""
        where = f"{self.path}:{entry}"
        if entry not in self._entries:
            raise SourceError(f"{self.path}: no '{entry}' in the archive (not a Record3D .r3d?)")
        try:
            with self._lock:
                return self._zip.read(entry)
        except (zipfile.BadZipFile, zlib.error, EOFError, OSError) as exc:
            raise SourceError(f"{where}: corrupt zip entry ({exc})") from None

    def _lzfse_image(self, entry: str, dtype: type) -> np.ndarray:
        """The depth-sized [dh, dw] image of an LZFSE-compressed entry of `dtype` values."""
        where = f"{self.path}:{entry}"
        try:
            raw = lzfse.decompress(self._read(entry))
        except lzfse.error:
            raise SourceError(f"{where}: not LZFSE-compressed data") from None
        width_px, height_px = self.depth_size_px
        expected = width_px * height_px * np.dtype(dtype).itemsize
        if len(raw) != expected:
            raise SourceError(
                f"{where}: {len(raw)} bytes after LZFSE, expected {width_px}x{height_px} "
                f"{np.dtype(dtype).name} = {expected}"
            )
        return np.frombuffer(raw, dtype=np.dtype(dtype).newbyteorder("<")).reshape(
            height_px, width_px
        )


def _decode_jpeg(data: bytes, where: str) -> np.ndarray:
    """uint8 [H, W, 3] of JPEG bytes; SourceError naming `where` if they are not an image."""
    try:
        with Image.open(io.BytesIO(data)) as image:
            return np.asarray(image.convert("RGB"), dtype=np.uint8)
    except (UnidentifiedImageError, OSError, SyntaxError) as exc:
        raise SourceError(f"{where}: not a readable image ({exc})") from None


def _pose_matrix(values: object, where: str) -> np.ndarray:
    """float64 [4, 4] of Record3D's [qx, qy, qz, qw, px, py, pz]; ValueError naming `where`."""
    numbers = _finite_numbers(values, 7, where, "[qx, qy, qz, qw, px, py, pz]")
    pose = np.eye(4)
    pose[:3, :3] = quaternion_to_matrix(*numbers[:4], where)
    pose[:3, 3] = numbers[4:]
    return pose


def _finite_numbers(values: object, count: int, where: str, what: str) -> list[float]:
    """`values` as `count` finite floats, else SourceError naming `where` and `what`."""
    if (
        not isinstance(values, list)
        or len(values) != count
        or not all(
            isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
            for v in values
        )
    ):
        raise SourceError(f"{where}: expected {what} ({count} finite numbers), got {values!r}")
    return [float(v) for v in values]


def _positive_int(document: dict, key: str, where: str) -> int:
    value = document.get(key)
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise SourceError(f"{where}: '{key}' must be a positive integer, got {value!r}")
    return value


def _parse_metadata(data: bytes, where: str) -> dict:
    """The fields of Record3D's metadata document this source uses, checked."""
    try:
        document = json.loads(data)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise SourceError(f"{where}: not valid JSON ({exc})") from None
    if not isinstance(document, dict):
        raise SourceError(f"{where}: expected a JSON object")
    missing = [key for key in ("w", "h", "K", "poses") if key not in document]
    if missing:
        raise SourceError(f"{where}: lacks {', '.join(missing)}")
    size_px = (_positive_int(document, "w", where), _positive_int(document, "h", where))
    depth_size_px = (
        _positive_int(document, "dw", where) if "dw" in document else size_px[0],
        _positive_int(document, "dh", where) if "dh" in document else size_px[1],
    )
    flat_k = _finite_numbers(document["K"], 9, where, "K, a column-major 3x3")
    try:
        intrinsics = pinhole_intrinsics(np.reshape(flat_k, (3, 3)).T, f"{where} K (column-major)")
    except ValueError as exc:
        raise SourceError(str(exc)) from None
    fps = document.get("fps", 30)
    if isinstance(fps, bool) or not isinstance(fps, int | float) or not fps > 0:
        raise SourceError(f"{where}: 'fps' must be a positive number, got {fps!r}")
    poses = document["poses"]
    if not isinstance(poses, list):
        raise SourceError(f"{where}: 'poses' must be a list of [qx, qy, qz, qw, px, py, pz]")
    timestamps = document.get("frameTimestamps")
    if timestamps is not None:
        if not isinstance(timestamps, list):
            raise SourceError(f"{where}: 'frameTimestamps' must be a list of seconds")
        timestamps = _finite_numbers(timestamps, len(timestamps), where, "frameTimestamps (s)")
    return {
        "size_px": size_px,
        "depth_size_px": depth_size_px,
        "intrinsics": intrinsics,
        "fps": float(fps),
        "poses": poses,
        "timestamps_s": timestamps,
    }
