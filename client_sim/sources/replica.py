"""Replica scenes as rendered by NICE-SLAM (the layout ConceptGraphs and nvblox read).

Layout:

    <scene>/results/frame000000.jpg   RGB (1200x680 in the NICE-SLAM renders)
    <scene>/results/depth000000.png   uint16, depth in metres = value / scale (6553.5)
    <scene>/traj.txt                  line n: 4x4 camera-to-world of frame n, 16 numbers
                                      row-major (OpenCV camera: x right, y down, z forward)
    cam_params.json                   {"camera": {"w", "h", "fx", "fy", "cx", "cy", "scale"}},
                                      in <scene> or, as NICE-SLAM ships it, its parent

The renders are synthetic, so depth and RGB share one pinhole camera exactly. There are no
timestamps: frames are taken to be 1 / `fps` s apart. A folder may hold a subset of the
frames (e.g. the first few): the source has one frame per RGB image present, and frame n's
pose is traj.txt line n.

Frame stems (for the labels folder) look like "frame000123".
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from client_sim.sources.base import (
    Intrinsics,
    RecordedSource,
    SourceFrame,
    checked_pose,
    parse_floats,
    read_rgb,
    read_uint16_png,
    require_file,
)

CAM_PARAMS_FILE = "cam_params.json"
TRAJECTORY_FILE = "traj.txt"
DEFAULT_DEPTH_SCALE = 6553.5
"""Depth PNG units per metre when cam_params.json has no "scale"."""

_RGB_NAME = re.compile(r"^frame(\d+)\.jpg$")


class ReplicaSource(RecordedSource):
    """Frames of one Replica scene folder in the NICE-SLAM layout, in frame-number order.

    root: the scene folder (holding results/ and traj.txt). cam_params: path of
    cam_params.json if it is neither in `root` nor in its parent. labels_dir: optional
    detections folder (see `client_sim.sources.base`). fps: frame rate for `SourceFrame.t`.
    """

    def __init__(
        self,
        root: str | Path,
        *,
        cam_params: str | Path | None = None,
        labels_dir: str | Path | None = None,
        fps: float = 30.0,
    ):
        root = Path(root)
        if not root.is_dir():
            raise FileNotFoundError(f"Replica scene folder not found: {root}")
        if not fps > 0:
            raise ValueError(f"fps must be positive, got {fps!r}")
        self.root = root
        self.name = f"replica:{root.name}"
        self.fps = float(fps)
        self.labels_dir = Path(labels_dir) if labels_dir is not None else None

        self.cam_params_path = _find_cam_params(root, cam_params)
        self.intrinsics, self.image_size_px, self.depth_scale = _read_cam_params(
            self.cam_params_path
        )
        self.trajectory_path = require_file(root / TRAJECTORY_FILE, "Replica trajectory")
        self._trajectory = _read_trajectory(self.trajectory_path)

        results = root / "results"
        if not results.is_dir():
            raise FileNotFoundError(f"missing Replica results folder: {results}")
        numbers = sorted(
            int(m.group(1)) for p in results.iterdir() if (m := _RGB_NAME.match(p.name))
        )
        if not numbers:
            raise FileNotFoundError(f"no Replica frames (frameXXXXXX.jpg) in {results}")
        self._numbers = numbers
        for number in numbers:
            if not self._depth_path(number).is_file():
                raise FileNotFoundError(f"missing Replica depth image: {self._depth_path(number)}")
        if numbers[-1] >= len(self._trajectory):
            raise ValueError(
                f"{self.trajectory_path}: has {len(self._trajectory)} poses, but frame "
                f"{numbers[-1]} needs line {numbers[-1] + 1}"
            )

    def __len__(self) -> int:
        return len(self._numbers)

    def stem(self, index: int) -> str:
        """The frame's file stem, e.g. "frame000123"; also its name in the labels folder."""
        return f"frame{self._numbers[self._check_index(index)]:06d}"

    def frame(self, index: int) -> SourceFrame:
        index = self._check_index(index)
        number = self._numbers[index]
        rgb_path = self.root / "results" / f"{self.stem(index)}.jpg"
        rgb = read_rgb(rgb_path)
        if (rgb.shape[1], rgb.shape[0]) != self.image_size_px:
            raise ValueError(
                f"{rgb_path}: image is {rgb.shape[1]}x{rgb.shape[0]}, but "
                f"{self.cam_params_path} says {self.image_size_px[0]}x{self.image_size_px[1]}"
            )
        raw = read_uint16_png(self._depth_path(number), "Replica depth image")
        pose = checked_pose(self._trajectory[number], f"{self.trajectory_path}:{number + 1}")
        return self._recorded_frame(index, number / self.fps, rgb, raw, self.depth_scale, pose)

    def _depth_path(self, number: int) -> Path:
        return self.root / "results" / f"depth{number:06d}.png"


def _find_cam_params(root: Path, explicit: str | Path | None) -> Path:
    """cam_params.json: the explicit path, else in the scene folder, else in its parent."""
    if explicit is not None:
        return require_file(Path(explicit), "Replica camera parameters")
    candidates = (root / CAM_PARAMS_FILE, root.parent / CAM_PARAMS_FILE)
    for path in candidates:
        if path.is_file():
            return path
    raise FileNotFoundError(
        f"missing Replica camera parameters: {candidates[0]} (nor {candidates[1]})"
    )


def _read_cam_params(path: Path) -> tuple[Intrinsics, tuple[int, int], float]:
    """((fx, fy, cx, cy), (w, h) in pixels, depth units per metre) of cam_params.json."""
    try:
        document = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from None
    camera = document.get("camera", document) if isinstance(document, dict) else None
    if not isinstance(camera, dict):
        raise ValueError(f"{path}: expected an object with a 'camera' object")
    missing = [key for key in ("w", "h", "fx", "fy", "cx", "cy") if key not in camera]
    if missing:
        raise ValueError(f"{path}: camera parameters lack {', '.join(missing)}")
    try:
        fx, fy, cx, cy = (float(camera[key]) for key in ("fx", "fy", "cx", "cy"))
        size_px = (int(camera["w"]), int(camera["h"]))
        scale = float(camera.get("scale", DEFAULT_DEPTH_SCALE))
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{path}: camera parameters are not numbers ({exc})") from None
    if fx <= 0 or fy <= 0 or scale <= 0 or min(size_px) <= 0:
        raise ValueError(f"{path}: fx, fy, w, h and scale must be positive")
    return (fx, fy, cx, cy), size_px, scale


def _read_trajectory(path: Path) -> np.ndarray:
    """float64 [N, 4, 4] camera-to-world poses, one per line of 16 numbers (row-major)."""
    lines = path.read_text().rstrip().splitlines()
    poses = np.empty((len(lines), 4, 4), np.float64)
    for line_number, line in enumerate(lines, start=1):
        where = f"{path}:{line_number}"
        values = parse_floats(line, where)
        if len(values) != 16:
            raise ValueError(f"{where}: expected 16 numbers (a row-major 4x4), got {len(values)}")
        poses[line_number - 1] = np.reshape(values, (4, 4))
    return poses
