"""Microsoft 7-Scenes sequences (e.g. as redistributed by tsdf-fusion-python).

Layout of a sequence folder (`root`, or `root/data` as in tsdf-fusion-python):

    frame-000000.color.jpg   RGB 640x480 (".color.png" in the original release)
    frame-000000.depth.png   uint16 millimetres, 65535 = invalid (and 0 = no reading)
    frame-000000.pose.txt    4x4 camera-to-world, 4 lines of 4 numbers
    camera-intrinsics.txt    optional 3x3 K (in the folder or its parent)

Caveats we accept: the Kinect's depth and RGB cameras are not registered in 7-Scenes; the
published depth is in the depth camera's frame and the usual practice (tsdf-fusion, most
relocalisation work) is to treat both as one pinhole camera with fx = fy = 585,
cx = 320, cy = 240, which is what we do. The colour therefore sits a few pixels off the
geometry at depth edges; geometry and poses are consistent with each other. There are no
timestamps: frames are taken to be 1 / `fps` s apart (the Kinect ran at 30 Hz).

Frame stems (for the labels folder) look like "frame-000123".
"""

from __future__ import annotations

import re
from pathlib import Path

from client_sim.sources.base import (
    Intrinsics,
    RecordedSource,
    SourceFrame,
    checked_pose,
    pinhole_intrinsics,
    read_matrix_file,
    read_rgb,
    read_uint16_png,
)

SEVEN_SCENES_INTRINSICS: Intrinsics = (585.0, 585.0, 320.0, 240.0)
"""The dataset's published pinhole model (fx, fy, cx, cy), used when no file overrides it."""
DEPTH_UNITS_PER_M = 1000.0
INVALID_DEPTH_RAW = 65535
INTRINSICS_FILE = "camera-intrinsics.txt"

_COLOR_NAME = re.compile(r"^frame-(\d+)\.color\.(jpg|png)$")


class SevenScenesSource(RecordedSource):
    """Frames of one 7-Scenes sequence folder, in frame-number order.

    root: the folder holding the frame-*.color.jpg files, or its parent if they are in
    `root/data`. intrinsics: (fx, fy, cx, cy) override; by default camera-intrinsics.txt
    (next to the frames or one level up) or else the published 585/320/240 model.
    labels_dir: optional detections folder (see `client_sim.sources.base`).
    fps: frame rate used to derive `SourceFrame.t` (7-Scenes has no timestamps).
    """

    def __init__(
        self,
        root: str | Path,
        *,
        intrinsics: Intrinsics | None = None,
        labels_dir: str | Path | None = None,
        fps: float = 30.0,
    ):
        root = Path(root)
        if not root.is_dir():
            raise FileNotFoundError(f"7-Scenes folder not found: {root}")
        if not _frame_files(root) and _frame_files(root / "data"):
            root = root / "data"
        color_paths = _frame_files(root)
        if not color_paths:
            raise FileNotFoundError(
                f"no 7-Scenes frames (frame-XXXXXX.color.jpg) in {root} or {root / 'data'}"
            )
        if not fps > 0:
            raise ValueError(f"fps must be positive, got {fps!r}")
        self.root = root
        self.name = f"7scenes:{(root.parent if root.name == 'data' else root).name}"
        self.fps = float(fps)
        self.labels_dir = Path(labels_dir) if labels_dir is not None else None
        self.intrinsics = intrinsics if intrinsics is not None else _find_intrinsics(root)

        self._numbers = sorted(color_paths)
        self._color_paths = color_paths
        # Fail at construction, not 200 frames into a run, if a frame lacks its depth or pose.
        for number in self._numbers:
            for path in (self._depth_path(number), self._pose_path(number)):
                if not path.is_file():
                    raise FileNotFoundError(f"missing 7-Scenes file: {path}")

    def __len__(self) -> int:
        return len(self._numbers)

    def stem(self, index: int) -> str:
        """The frame's file stem, e.g. "frame-000123"; also its name in the labels folder."""
        return f"frame-{self._numbers[self._check_index(index)]:06d}"

    def frame(self, index: int) -> SourceFrame:
        index = self._check_index(index)
        number = self._numbers[index]
        rgb = read_rgb(self._color_paths[number])
        raw = read_uint16_png(self._depth_path(number), "7-Scenes depth image")
        pose_path = self._pose_path(number)
        pose = checked_pose(read_matrix_file(pose_path, (4, 4), "7-Scenes pose"), str(pose_path))
        t = number / self.fps
        return self._recorded_frame(index, t, rgb, raw, DEPTH_UNITS_PER_M, pose, INVALID_DEPTH_RAW)

    def _depth_path(self, number: int) -> Path:
        return self.root / f"frame-{number:06d}.depth.png"

    def _pose_path(self, number: int) -> Path:
        return self.root / f"frame-{number:06d}.pose.txt"


def _frame_files(folder: Path) -> dict[int, Path]:
    """{frame number: colour image path} of a folder (empty if it does not exist)."""
    if not folder.is_dir():
        return {}
    found: dict[int, Path] = {}
    for path in folder.iterdir():
        match = _COLOR_NAME.match(path.name)
        if match:
            found[int(match.group(1))] = path
    return found


def _find_intrinsics(frames_dir: Path) -> Intrinsics:
    """(fx, fy, cx, cy) from camera-intrinsics.txt beside the frames or one level up."""
    for folder in (frames_dir, frames_dir.parent):
        path = folder / INTRINSICS_FILE
        if path.is_file():
            return pinhole_intrinsics(
                read_matrix_file(path, (3, 3), "camera intrinsics"), str(path)
            )
    return SEVEN_SCENES_INTRINSICS
