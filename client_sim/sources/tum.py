"""TUM RGB-D benchmark sequences (Sturm et al., IROS 2012).

Layout of a sequence folder:

    rgb.txt           "timestamp path" per line (path relative to the folder), '#' comments
    depth.txt         same, for the depth PNGs: uint16, depth in metres = value / 5000
    groundtruth.txt   "timestamp tx ty tz qx qy qz qw": the colour camera's optical centre,
                      camera-to-world (OpenCV camera axes: x right, y down, z forward)

Association follows the benchmark's own tool (associate.py): RGB and depth images are
paired one-to-one, closest timestamps first, and only if they are within `max_dt_s`; each
pair takes the ground-truth pose nearest its RGB timestamp, again within `max_dt_s`.
RGB images left without a depth image or a pose are dropped. The published depth is
already registered to the RGB camera, so one set of intrinsics serves both.
`SourceFrame.t` counts seconds from the first kept frame; the absolute timestamps are in
`timestamps_s`.

Frame stems (for the labels folder) are the RGB file's stem, e.g. "1305031102.175304".
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from client_sim.sources.base import (
    Intrinsics,
    RecordedSource,
    SourceFrame,
    checked_pose,
    parse_floats,
    quaternion_to_matrix,
    read_rgb,
    read_uint16_png,
    require_file,
)

FREIBURG1_INTRINSICS: Intrinsics = (517.3, 516.5, 318.6, 255.3)
"""The fr1 Kinect's calibrated colour camera (fx, fy, cx, cy); fr2/fr3 need an override."""
DEPTH_UNITS_PER_M = 5000.0
MAX_ASSOCIATION_DT_S = 0.02


class TumSource(RecordedSource):
    """Associated (RGB, depth, pose) triples of one TUM RGB-D sequence, in time order.

    root: the sequence folder. intrinsics: (fx, fy, cx, cy) of the RGB image (default
    Freiburg1). max_dt_s: the largest timestamp difference an association may bridge.
    depth_units_per_m: depth PNG scale. labels_dir: optional detections folder (see
    `client_sim.sources.base`).
    """

    def __init__(
        self,
        root: str | Path,
        *,
        intrinsics: Intrinsics = FREIBURG1_INTRINSICS,
        max_dt_s: float = MAX_ASSOCIATION_DT_S,
        depth_units_per_m: float = DEPTH_UNITS_PER_M,
        labels_dir: str | Path | None = None,
    ):
        root = Path(root)
        if not root.is_dir():
            raise FileNotFoundError(f"TUM sequence folder not found: {root}")
        if not max_dt_s >= 0:
            raise ValueError(f"max_dt_s must be non-negative, got {max_dt_s!r}")
        if not depth_units_per_m > 0:
            raise ValueError(f"depth_units_per_m must be positive, got {depth_units_per_m!r}")
        self.root = root
        self.name = f"tum:{root.name}"
        self.intrinsics = intrinsics
        self.depth_units_per_m = float(depth_units_per_m)
        self.labels_dir = Path(labels_dir) if labels_dir is not None else None

        rgb_times, rgb_paths = _read_file_list(root, "rgb.txt")
        depth_times, depth_paths = _read_file_list(root, "depth.txt")
        pose_times, poses = _read_groundtruth(root / "groundtruth.txt")

        pairs = associate(rgb_times, depth_times, max_dt_s)
        pose_of_pair = nearest_within(rgb_times[pairs[:, 0]], pose_times, max_dt_s)
        kept = pose_of_pair >= 0
        pairs, pose_of_pair = pairs[kept], pose_of_pair[kept]
        if len(pairs) == 0:
            raise ValueError(
                f"{root}: no RGB image has both a depth image and a ground-truth pose "
                f"within {max_dt_s} s"
            )

        self.timestamps_s: np.ndarray = rgb_times[pairs[:, 0]]
        """float64 [N] absolute RGB timestamps (seconds) of the kept frames."""
        self.depth_timestamps_s: np.ndarray = depth_times[pairs[:, 1]]
        """float64 [N] absolute timestamps of the depth images paired with them."""
        self._rgb_paths = [rgb_paths[i] for i in pairs[:, 0]]
        self._depth_paths = [depth_paths[i] for i in pairs[:, 1]]
        self._poses = poses[pose_of_pair]
        self._pose_lines = [
            f"{root / 'groundtruth.txt'} (t={pose_times[i]:.6f})" for i in pose_of_pair
        ]

    def __len__(self) -> int:
        return len(self._rgb_paths)

    def stem(self, index: int) -> str:
        """The RGB file's stem, e.g. "1305031102.175304"; also its name in the labels folder."""
        return self._rgb_paths[self._check_index(index)].stem

    def frame(self, index: int) -> SourceFrame:
        index = self._check_index(index)
        rgb = read_rgb(self._rgb_paths[index])
        raw = read_uint16_png(self._depth_paths[index], "TUM depth image")
        t = float(self.timestamps_s[index] - self.timestamps_s[0])
        pose = checked_pose(self._poses[index], self._pose_lines[index])
        return self._recorded_frame(index, t, rgb, raw, self.depth_units_per_m, pose)


def associate(times_a: np.ndarray, times_b: np.ndarray, max_dt_s: float) -> np.ndarray:
    """int [K, 2] one-to-one (i, j) pairs with |a_i - b_j| <= max_dt_s, sorted by i.

    Greedy on the smallest difference first, as TUM's associate.py does, so a B stamp
    between two A stamps goes to the closer one and neither is used twice.
    `times_b` must be sorted ascending.
    """
    candidates = []
    for i, t in enumerate(times_a):
        lo = np.searchsorted(times_b, t - max_dt_s, side="left")
        hi = np.searchsorted(times_b, t + max_dt_s, side="right")
        candidates.extend((abs(times_b[j] - t), i, j) for j in range(lo, hi))
    candidates.sort()
    used_a, used_b, pairs = set(), set(), []
    for _, i, j in candidates:
        if i not in used_a and j not in used_b:
            used_a.add(i)
            used_b.add(j)
            pairs.append((i, j))
    pairs.sort()
    return np.array(pairs, dtype=np.intp).reshape(-1, 2)


def nearest_within(times: np.ndarray, reference_times: np.ndarray, max_dt_s: float) -> np.ndarray:
    """int [N]: index of the nearest reference stamp to each time, or -1 if > max_dt_s away.

    `reference_times` must be sorted ascending.
    """
    if len(reference_times) == 0:
        return np.full(len(times), -1, np.intp)
    last = len(reference_times) - 1
    right = np.searchsorted(reference_times, times).clip(0, last)
    left = (right - 1).clip(0, last)
    take_left = np.abs(times - reference_times[left]) <= np.abs(reference_times[right] - times)
    nearest = np.where(take_left, left, right)
    too_far = np.abs(reference_times[nearest] - times) > max_dt_s
    return np.where(too_far, -1, nearest).astype(np.intp)


def _data_lines(path: Path) -> list[tuple[int, str]]:
    """(line number, text) of the non-blank, non-comment lines of a TUM list file."""
    return [
        (number, line.strip())
        for number, line in enumerate(path.read_text().splitlines(), start=1)
        if line.strip() and not line.lstrip().startswith("#")
    ]


def _read_file_list(root: Path, list_name: str) -> tuple[np.ndarray, list[Path]]:
    """(timestamps float64 [N] ascending, image paths) of rgb.txt / depth.txt."""
    list_path = require_file(root / list_name, f"TUM list {list_name}")
    entries = []
    for number, line in _data_lines(list_path):
        fields = line.split()
        where = f"{list_path}:{number}"
        if len(fields) != 2:
            raise ValueError(f"{where}: expected 'timestamp path', got {line!r}")
        (timestamp,) = parse_floats(fields[0], where)
        entries.append((timestamp, root / fields[1]))
    entries.sort(key=lambda entry: entry[0])
    for _, image_path in entries:
        require_file(image_path, f"image listed in {list_path}")
    return np.array([t for t, _ in entries], np.float64), [p for _, p in entries]


def _read_groundtruth(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(timestamps float64 [M] ascending, camera-to-world poses float64 [M, 4, 4])."""
    require_file(path, "TUM ground truth")
    times, poses = [], []
    for number, line in _data_lines(path):
        where = f"{path}:{number}"
        values = parse_floats(line, where)
        if len(values) != 8:
            raise ValueError(f"{where}: expected 'timestamp tx ty tz qx qy qz qw', got {line!r}")
        timestamp, tx, ty, tz, qx, qy, qz, qw = values
        pose = np.eye(4)
        pose[:3, :3] = quaternion_to_matrix(qx, qy, qz, qw, where)
        pose[:3, 3] = (tx, ty, tz)
        times.append(timestamp)
        poses.append(pose)
    order = np.argsort(times, kind="stable")
    return np.array(times, np.float64)[order], np.array(poses, np.float64).reshape(-1, 4, 4)[order]
