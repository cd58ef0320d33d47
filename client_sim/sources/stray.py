"""Stray Scanner captures (iPhone/iPad with LiDAR): the dataset folder the app records.

Layout of a capture folder:

    rgb.mp4              the colour frames (HEVC; 1920x1440 on LiDAR iPhones), one per row of
                         odometry.csv, in order; read with PyAV as stored (a display rotation
                         in the file's metadata is ignored: depth and intrinsics are in the
                         sensor's orientation too)
    depth/000000.png     uint16 depth in millimetres, 256x192, 0 = none
    confidence/000000.png  uint8 ARKit confidence 0..2 of each depth pixel (optional)
    odometry.csv         header "timestamp, frame, x, y, z, qx, qy, qz, qw" (later app
                         versions add columns, which are ignored); one row per frame
    camera_matrix.csv    3x3 intrinsics of the full-resolution colour frame, comma-separated

**Poses are already in OpenCV camera axes.** Stray Scanner writes ARKit's camera-to-world
with the camera turned half a turn about x (strayrobots/scanner, `OdometryEncoder.swift`:
`q_AC = simd_quatf(ix: 1, iy: 0, iz: 0, r: 0)`, written as `q_WA * q_AC`), so the camera
axes are x right, y down, z forward, in ARKit's world (y up). Its own visualiser uses them
unchanged as Open3D (OpenCV) extrinsics (kekeblom/StrayVisualizer, `stray_visualize.py`).
So, unlike `record3d:`, no camera flip is applied here (`phone.arkit_pose_to_opencv` is
not). The depth PNGs are the app's `uint16(metres * 1000)` (strayrobots/scanner,
`PngEncoder.mm`), the intrinsics file the rows of ARKit's `camera.intrinsics`
(`DatasetEncoder.writeIntrinsics`), timestamps ARKit's (seconds since the phone booted).

Frame i is row i of odometry.csv, depth/<frame>.png and the i-th frame of rgb.mp4 (the app
writes a video frame for each saved row); if the video is shorter, the rows past its end are
left out. `SourceFrame.t` is the row's timestamp counted from the first row. Frames are
scaled to the device's size and low-confidence depth dropped as `client_sim.sources.phone`
says. A Stray Scanner capture carries no detections: map it with
`semanticxr serve --perception models`.
"""

from __future__ import annotations

import csv
import threading
from collections.abc import Iterator
from pathlib import Path

import av
import numpy as np
from PIL import Image

from client_sim.sources.base import (
    Intrinsics,
    SourceError,
    SourceFrame,
    checked_pose,
    depth_png_to_m,
    parse_floats,
    pinhole_intrinsics,
    quaternion_to_matrix,
    read_uint16_png,
    require_file,
)
from client_sim.sources.phone import (
    DEVICE_MAX_SIDE_PX,
    MIN_CONFIDENCE,
    PhoneCaptureSource,
)

VIDEO_FILE = "rgb.mp4"
ODOMETRY_FILE = "odometry.csv"
CAMERA_MATRIX_FILE = "camera_matrix.csv"
DEPTH_UNITS_PER_M = 1000.0
ODOMETRY_COLUMNS = ("timestamp", "frame", "x", "y", "z", "qx", "qy", "qz", "qw")


class StraySource(PhoneCaptureSource):
    """Frames of one Stray Scanner capture folder, in recording order.

    root: the capture folder. max_side_px: the frames' longer side at most (None: the
    video's size). min_confidence: depth under this ARKit confidence (0..2) is dropped (see
    `client_sim.sources.phone`).
    """

    def __init__(
        self,
        root: str | Path,
        *,
        max_side_px: int | None = DEVICE_MAX_SIDE_PX,
        min_confidence: int = MIN_CONFIDENCE,
    ):
        root = Path(root)
        if not root.is_dir():
            raise FileNotFoundError(f"Stray Scanner capture folder not found: {root}")
        self.root = root
        self.name = f"stray:{root.name}"
        camera_matrix_path = require_file(root / CAMERA_MATRIX_FILE, "Stray Scanner intrinsics")
        capture_intrinsics = _read_camera_matrix(camera_matrix_path)
        odometry_path = require_file(root / ODOMETRY_FILE, "Stray Scanner odometry")
        times_s, numbers, poses = _read_odometry(odometry_path)
        self._video = _Video(require_file(root / VIDEO_FILE, "Stray Scanner video"))
        capture_size_px = self._video.size_px
        _check_principal_point(capture_intrinsics, capture_size_px, camera_matrix_path)
        self._set_output(capture_size_px, capture_intrinsics, max_side_px, min_confidence)

        n_frames = min(len(numbers), self._video.n_frames)
        if n_frames == 0:
            raise SourceError(f"{root}: no frames ({odometry_path} or {self._video.path} is empty)")
        self._numbers = numbers[:n_frames]
        self._times_s = [t - times_s[0] for t in times_s[:n_frames]]
        self._poses = poses[:n_frames]
        # Fail at construction, not 200 frames into a run, if a frame lacks its depth.
        for number in self._numbers:
            require_file(self._depth_path(number), "Stray Scanner depth image")

    def __len__(self) -> int:
        return len(self._numbers)

    def frame(self, index: int) -> SourceFrame:
        index = self._check_index(index)
        number = self._numbers[index]
        rgb = self._video.frame(index)
        depth_path = self._depth_path(number)
        try:
            raw = read_uint16_png(depth_path, "Stray Scanner depth image")
        except OSError as exc:  # missing, or not an image
            raise SourceError(f"{depth_path}: not a readable PNG ({exc})") from None
        except ValueError as exc:  # an image, but not 16-bit grey; the message names the file
            raise SourceError(str(exc)) from None
        confidence = _read_confidence(self.root / "confidence" / f"{number:06d}.png")
        return self._phone_frame(
            index,
            self._times_s[index],
            rgb,
            depth_png_to_m(raw, DEPTH_UNITS_PER_M),
            confidence,
            self._poses[index],
            str(depth_path),
        )

    def _depth_path(self, number: int) -> Path:
        return self.root / "depth" / f"{number:06d}.png"


class _Video:
    """The frames of a video in display order, decoded by PyAV. Reading forward decodes on from
    the last frame read; going back starts again from the first frame (the device reads
    forward)."""

    def __init__(self, path: Path):
        self.path = path
        self._lock = threading.Lock()  # frames are read from worker threads
        self._container: av.container.InputContainer | None = None
        self._decoded: Iterator[av.VideoFrame] | None = None
        self._next = 0
        try:
            with av.open(str(path)) as container:
                if not container.streams.video:
                    raise SourceError(f"{path}: has no video stream")
                stream = container.streams.video[0]
                self.size_px = (int(stream.codec_context.width), int(stream.codec_context.height))
                # mp4 keeps the frame count in its index; count packets if it is missing.
                self.n_frames = int(stream.frames) or sum(
                    1 for packet in container.demux(stream) if packet.size
                )
        except av.FFmpegError as exc:
            raise SourceError(f"{path}: not a readable video ({exc})") from None
        if min(self.size_px) < 1:
            raise SourceError(f"{path}: video has no frame size")

    def frame(self, index: int) -> np.ndarray:
        """uint8 [H, W, 3] RGB of frame `index` (0-based, in display order)."""
        with self._lock:
            try:
                if self._decoded is None or index < self._next:
                    self._restart()
                for decoded in self._decoded:
                    position, self._next = self._next, self._next + 1
                    if position == index:
                        return decoded.to_ndarray(format="rgb24")
            except av.FFmpegError as exc:
                self._close()
                raise SourceError(f"{self.path}: frame {index} cannot be decoded ({exc})") from None
            ends_at = self._next
            self._close()
        raise SourceError(
            f"{self.path}: the video ends after {ends_at} frames, before frame {index}"
        )

    def _restart(self) -> None:
        self._close()
        self._container = av.open(str(self.path))
        self._container.streams.video[0].thread_type = "AUTO"  # ~7 ms a 1920x1440 frame, 2 cores
        self._decoded = self._container.decode(video=0)
        self._next = 0

    def _close(self) -> None:
        if self._container is not None:
            self._container.close()
        self._container, self._decoded, self._next = None, None, 0


def _read_camera_matrix(path: Path) -> Intrinsics:
    """(fx, fy, cx, cy) of camera_matrix.csv: three rows of three comma-separated numbers."""
    values = parse_floats(path.read_text().replace(",", " "), str(path))
    if len(values) != 9:
        raise SourceError(f"{path}: expected a 3x3 matrix (9 numbers), got {len(values)} numbers")
    try:
        return pinhole_intrinsics(np.reshape(values, (3, 3)), str(path))
    except ValueError as exc:
        raise SourceError(str(exc)) from None


def _check_principal_point(intrinsics: Intrinsics, size_px: tuple[int, int], path: Path) -> None:
    """SourceError unless the principal point lies inside the video frame: intrinsics of
    another resolution or orientation than the video's would map every depth pixel wrong."""
    _, _, cx, cy = intrinsics
    if not (0 < cx < size_px[0] and 0 < cy < size_px[1]):
        raise SourceError(
            f"{path}: principal point ({cx:g}, {cy:g}) is outside the "
            f"{size_px[0]}x{size_px[1]} video: intrinsics of another size or orientation"
        )


def _read_odometry(path: Path) -> tuple[list[float], list[int], list[np.ndarray]]:
    """(timestamps s, frame numbers, OpenCV camera-to-world poses [4, 4]) of odometry.csv."""
    with path.open(newline="") as lines:
        rows = list(csv.reader(lines))
    if not rows:
        raise SourceError(f"{path}: empty (expected a header and one row per frame)")
    header = [name.strip() for name in rows[0]]
    missing = [name for name in ODOMETRY_COLUMNS if name not in header]
    if missing:
        raise SourceError(
            f"{path}:1: header lacks {', '.join(missing)} (expected "
            f"'{', '.join(ODOMETRY_COLUMNS)}')"
        )
    columns = [header.index(name) for name in ODOMETRY_COLUMNS]
    times_s, numbers, poses = [], [], []
    for line_number, row in enumerate(rows[1:], start=2):
        if not any(cell.strip() for cell in row):
            continue
        where = f"{path}:{line_number}"
        if len(row) < len(header):
            raise SourceError(f"{where}: {len(row)} fields, the header names {len(header)}")
        timestamp, number, x, y, z, qx, qy, qz, qw = parse_floats(
            " ".join(row[i] for i in columns), where
        )
        if number != int(number) or number < 0 or (numbers and number <= numbers[-1]):
            raise SourceError(f"{where}: frame {row[columns[1]].strip()!r} is not the next frame")
        pose = np.eye(4)
        pose[:3, :3] = quaternion_to_matrix(qx, qy, qz, qw, where)
        pose[:3, 3] = (x, y, z)
        times_s.append(timestamp)
        numbers.append(int(number))
        poses.append(checked_pose(pose, where))
    return times_s, numbers, poses


def _read_confidence(path: Path) -> np.ndarray | None:
    """uint8 [h, w] ARKit confidence of confidence/<frame>.png, or None if the file is absent."""
    if not path.is_file():
        return None
    try:
        with Image.open(path) as image:
            if image.mode != "L":
                raise SourceError(
                    f"{path}: expected a grey confidence image, got mode {image.mode}"
                )
            return np.asarray(image).astype(np.uint8)
    except OSError as exc:
        raise SourceError(f"{path}: not a readable PNG ({exc})") from None
