"""The frame-source interface, and the file readers the recorded-dataset loaders share.

A `FrameSource` is an indexed, finite sequence of `SourceFrame`s: RGB, metric depth at RGB
size, a camera-to-world pose in the OpenCV camera convention (x right, y down, z forward)
and the RGB intrinsics, optionally with detections (an instance-id image and its labels).

Optional detections for recorded datasets come from a labels folder: for a frame whose
stem is `S` (each loader says what its stems look like), `<labels_dir>/S.png` is a uint16
instance-id image at RGB size (0 = no instance) and `<labels_dir>/S.json` is
`[{"id": int, "label": str, "score": float}, ...]`. Frames without both files carry no
detections (geometry only).
"""

from __future__ import annotations

import abc
import json
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from app.codecs import validate_rigid_pose

Intrinsics = tuple[float, float, float, float]
"""(fx, fy, cx, cy) in pixels, pixel centres at integer coordinates."""


class SourceError(ValueError):
    """A recording that cannot be read: a corrupt, truncated or inconsistent file. The message
    names the file and what is wrong; `semanticxr device` prints it and stops (also when it
    happens mid-stream, where a reader finds it)."""


@dataclass
class SourceFrame:
    """One RGB-D frame with its pose, as a device would capture it."""

    index: int
    """Position in the source, 0 .. len(source) - 1."""
    t: float
    """Capture time in seconds (each loader documents its clock; none is wall-clock)."""
    rgb: np.ndarray
    """uint8 [H, W, 3]."""
    depth_m: np.ndarray
    """float32 [H, W] z-depth in metres, 0 = invalid. Always at RGB size: a loader whose depth
    sensor has another resolution resizes it with nearest neighbour (never interpolating
    across surfaces), because the frame encoder requires depth at RGB size."""
    pose: np.ndarray
    """float64 [4, 4] camera-to-world, OpenCV camera convention (x right, y down, z forward)."""
    intrinsics: Intrinsics
    """(fx, fy, cx, cy) of the RGB image in pixels."""
    instance_ids: np.ndarray | None = None
    """uint16 [H, W] instance id per pixel (0 = none), if detections are available."""
    instances: list[dict] | None = None
    """[{"id": int, "label": str, "score": float}] describing `instance_ids`."""


class FrameSource(abc.ABC):
    """An indexed, finite sequence of frames. Subclasses define `__len__` and `frame`."""

    name: str = "source"
    """Short human-readable name, e.g. "7scenes:redkitchen"."""

    def __len__(self) -> int:
        raise NotImplementedError(f"{type(self).__name__} does not define __len__")

    @abc.abstractmethod
    def frame(self, index: int) -> SourceFrame:
        """Frame `index` (0 <= index < len(self)); IndexError outside that range."""

    def frames(self, every: int = 1, limit: int | None = None) -> Iterator[SourceFrame]:
        """Frames 0, every, 2 * every, ... in order, at most `limit` of them (None = all)."""
        if isinstance(every, bool) or not isinstance(every, int) or every < 1:
            raise ValueError(f"every must be a positive integer, got {every!r}")
        if limit is not None and (
            isinstance(limit, bool) or not isinstance(limit, int) or limit < 0
        ):
            raise ValueError(f"limit must be a non-negative integer or None, got {limit!r}")
        indices = range(0, len(self), every)
        if limit is not None:
            indices = indices[:limit]
        for index in indices:
            yield self.frame(index)

    def _check_index(self, index: int) -> int:
        """`index` as int if it names a frame of this source, else IndexError."""
        n_frames = len(self)
        if isinstance(index, bool) or not isinstance(index, int | np.integer):
            raise TypeError(f"frame index must be an integer, got {index!r}")
        if not 0 <= index < n_frames:
            raise IndexError(
                f"frame index {index} out of range for {self.name} ({n_frames} frames)"
            )
        return int(index)

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name!r}: {len(self)} frames>"


class RecordedSource(FrameSource):
    """A recorded dataset: frames read from files, detections from an optional labels folder.

    Subclasses set `intrinsics` and `labels_dir` and define `stem` (a frame's file stem, also
    its name in the labels folder); `_recorded_frame` assembles what they read.
    """

    intrinsics: Intrinsics
    labels_dir: Path | None = None

    @abc.abstractmethod
    def stem(self, index: int) -> str:
        """Frame `index`'s file stem, also its name in the labels folder."""

    def _recorded_frame(
        self,
        index: int,
        t: float,
        rgb: np.ndarray,
        depth_raw: np.ndarray,
        depth_units_per_m: float,
        pose: np.ndarray,
        invalid_depth_raw: int | None = None,
    ) -> SourceFrame:
        """The frame of RGB, raw uint16 depth and a checked pose, with its labels if any."""
        depth_m = depth_png_to_m(depth_raw, depth_units_per_m, invalid_depth_raw)
        instance_ids, instances = load_labels(self.labels_dir, self.stem(index), rgb.shape)
        return SourceFrame(
            index=index,
            t=t,
            rgb=rgb,
            depth_m=depth_at_rgb_size(depth_m, rgb.shape),
            pose=pose,
            intrinsics=self.intrinsics,
            instance_ids=instance_ids,
            instances=instances,
        )


# --------------------------------------------------------------------------------------
# Readers shared by the dataset loaders. Every error names the file (and line) at fault.
# --------------------------------------------------------------------------------------


def require_file(path: Path, what: str) -> Path:
    """`path` if it is an existing file, else FileNotFoundError naming it and what it is."""
    if not path.is_file():
        raise FileNotFoundError(f"missing {what}: {path}")
    return path


def read_rgb(path: Path) -> np.ndarray:
    """uint8 [H, W, 3] RGB of an image file (grey or RGBA are converted)."""
    require_file(path, "RGB image")
    with Image.open(path) as image:
        return np.asarray(image.convert("RGB"), dtype=np.uint8)


def read_uint16_png(path: Path, what: str) -> np.ndarray:
    """uint16 [h, w] of a 16-bit single-channel PNG; ValueError if it is anything else."""
    require_file(path, what)
    with Image.open(path) as image:
        # Pillow opens 16-bit PNGs as "I;16" (or "I" for some writers); 8-bit would mean
        # the file lost its precision somewhere upstream, so refuse it instead of guessing.
        if image.mode not in ("I;16", "I;16B", "I;16L", "I"):
            raise ValueError(f"{path}: expected a 16-bit single-channel PNG, got mode {image.mode}")
        values = np.asarray(image)
    if values.ndim != 2:
        raise ValueError(f"{path}: expected a single-channel image, got shape {list(values.shape)}")
    if values.dtype != np.uint16:
        if values.size and (values.min() < 0 or values.max() > 65535):
            raise ValueError(f"{path}: values outside the uint16 range")
        values = values.astype(np.uint16)
    return values


def depth_png_to_m(
    raw: np.ndarray, units_per_m: float, invalid_raw: int | None = None
) -> np.ndarray:
    """float32 [h, w] metres of raw uint16 depth [h, w]; 0 (and `invalid_raw`) become 0."""
    depth_m = raw.astype(np.float32) / np.float32(units_per_m)
    if invalid_raw is not None:
        depth_m[raw == invalid_raw] = 0.0
    return depth_m


def depth_at_rgb_size(depth_m: np.ndarray, rgb_shape: tuple[int, ...]) -> np.ndarray:
    """Depth [h, w] resized to the RGB image's [H, W] with nearest neighbour (if it differs).

    Nearest neighbour, never bilinear: averaging across a depth edge would invent points
    floating between foreground and background.
    """
    height_px, width_px = rgb_shape[:2]
    if depth_m.shape == (height_px, width_px):
        return depth_m
    resized = Image.fromarray(np.ascontiguousarray(depth_m, dtype=np.float32)).resize(
        (width_px, height_px), Image.Resampling.NEAREST
    )
    return np.asarray(resized, dtype=np.float32)


def checked_pose(matrix: np.ndarray, where: str) -> np.ndarray:
    """float64 [4, 4] camera-to-world if `matrix` is rigid, else ValueError naming `where`."""
    # One definition of "rigid" for the whole project: the wire codec's.
    return validate_rigid_pose(np.asarray(matrix, dtype=np.float64), field=where)


def parse_floats(text: str, where: str) -> list[float]:
    """The whitespace-separated numbers of `text`; ValueError naming `where` if one is not."""
    try:
        values = [float(token) for token in text.split()]
    except ValueError as exc:
        raise ValueError(f"{where}: not a list of numbers ({exc})") from None
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"{where}: contains NaN or inf")
    return values


def read_matrix_file(path: Path, shape: tuple[int, int], what: str) -> np.ndarray:
    """float64 array of `shape` from a text file of whitespace-separated numbers."""
    require_file(path, what)
    values = parse_floats(path.read_text(), str(path))
    if len(values) != shape[0] * shape[1]:
        raise ValueError(
            f"{path}: expected {shape[0]}x{shape[1]} = {shape[0] * shape[1]} numbers "
            f"for the {what}, got {len(values)}"
        )
    return np.array(values, dtype=np.float64).reshape(shape)


def quaternion_to_matrix(qx: float, qy: float, qz: float, qw: float, where: str) -> np.ndarray:
    """float64 [3, 3] rotation of a (near-)unit quaternion; ValueError naming `where` if not."""
    q = np.array([qw, qx, qy, qz], np.float64)
    norm = float(np.linalg.norm(q))
    # Text files print a few decimals (TUM: 4), so unit quaternions come out within ~1e-4 of
    # norm 1; anything further off is a corrupt line, not rounding.
    if not abs(norm - 1.0) <= 1e-2:  # also refuses NaN
        raise ValueError(f"{where}: quaternion norm is {norm:.4f}, expected 1")
    w, x, y, z = q / norm
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def pinhole_intrinsics(k: np.ndarray, where: str) -> Intrinsics:
    """(fx, fy, cx, cy) of a 3x3 pinhole matrix [[fx, s, cx], [0, fy, cy], [0, 0, 1]] (the skew s
    is ignored); ValueError naming `where` if `k` is not one."""
    k = np.asarray(k, dtype=np.float64)
    if (
        k.shape != (3, 3)
        or not np.all(np.isfinite(k))
        or k[0, 0] <= 0
        or k[1, 1] <= 0
        or not np.allclose(k[1:, 0], 0.0)
        or not np.allclose(k[2], [0.0, 0.0, 1.0])
    ):
        raise ValueError(f"{where}: not a pinhole intrinsics matrix: {k.tolist()}")
    return (float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2]))


def load_labels(
    labels_dir: Path | None, stem: str, rgb_shape: tuple[int, ...]
) -> tuple[np.ndarray | None, list[dict] | None]:
    """(instance_ids uint16 [H, W], instances) for frame `stem`, or (None, None) if absent.

    A frame with only one of `<stem>.png` / `<stem>.json` is a broken labels folder, not a
    frame without detections, so it raises FileNotFoundError naming the missing half.
    """
    if labels_dir is None:
        return None, None
    image_path, table_path = labels_dir / f"{stem}.png", labels_dir / f"{stem}.json"
    has_image, has_table = image_path.is_file(), table_path.is_file()
    if not has_image and not has_table:
        return None, None
    if not has_table:
        raise FileNotFoundError(
            f"missing instance table {table_path} (its image {image_path} exists)"
        )
    if not has_image:
        raise FileNotFoundError(
            f"missing instance image {image_path} (its table {table_path} exists)"
        )

    instance_ids = read_uint16_png(image_path, "instance-id image")
    if instance_ids.shape != tuple(rgb_shape[:2]):
        raise ValueError(
            f"{image_path}: instance-id image is {list(instance_ids.shape)}, "
            f"expected the RGB size {list(rgb_shape[:2])}"
        )
    try:
        table = json.loads(table_path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{table_path}: not valid JSON ({exc})") from None
    if not isinstance(table, list):
        raise ValueError(f"{table_path}: expected a JSON list of instances")
    instances = [_parse_instance(entry, f"{table_path}[{i}]") for i, entry in enumerate(table)]
    return instance_ids, instances


def _parse_instance(entry: object, where: str) -> dict:
    """{"id": int 1..65535, "label": str, "score": float} checked, extra keys dropped."""
    if not isinstance(entry, dict) or not {"id", "label", "score"} <= entry.keys():
        raise ValueError(f"{where}: expected an object with id, label and score")
    instance_id, label, score = entry["id"], entry["label"], entry["score"]
    if (
        isinstance(instance_id, bool)
        or not isinstance(instance_id, int)
        or not 0 < instance_id <= 65535
    ):
        raise ValueError(f"{where}: id must be an integer in 1..65535, got {instance_id!r}")
    if not isinstance(label, str) or not label:
        raise ValueError(f"{where}: label must be a non-empty string, got {label!r}")
    if isinstance(score, bool) or not isinstance(score, int | float) or not math.isfinite(score):
        raise ValueError(f"{where}: score must be a number, got {score!r}")
    return {"id": instance_id, "label": label, "score": float(score)}
