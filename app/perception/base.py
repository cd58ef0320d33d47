"""The decoded frame the engine consumes, one frame's detections, and the backend interface."""

from __future__ import annotations

import abc
from dataclasses import dataclass, field

import numpy as np

from app.errors import InputError

__all__ = ["Detection", "FrameDetections", "FrameInput", "InputError", "PerceptionBackend"]


@dataclass
class FrameInput:
    """One decoded RGB-D frame, as the mapping engine sees it.

    depth_m:      float32 [h, w] metres, possibly downsampled from the RGB size; 0 = invalid
    pose:         float64 [4, 4] camera-to-world (OpenCV camera: x right, y down, z forward)
    intrinsics:   (fx, fy, cx, cy) of the RGB image, in RGB pixels
    rgb_size:     (W, H) of the RGB image (the resolution masks and intrinsics refer to)
    rgb:          uint8 [H, W, 3], or None where a backend does not need it
    instance_ids: uint16 [H, W] instance image sent by the device (0 = none), optional
    instances:    [{"id": int, "label": str, "score": float}] for the ids in instance_ids
    """

    seq: int
    t: float
    pose: np.ndarray
    intrinsics: tuple[float, float, float, float]
    rgb_size: tuple[int, int]
    depth_m: np.ndarray
    rgb: np.ndarray | None = None
    instance_ids: np.ndarray | None = None
    instances: list[dict] = field(default_factory=list)


@dataclass
class Detection:
    """One object seen in one frame; its mask is pixels == instance_id of the frame's image.

    bbox_px:   (x0, y0, x1, y1) of the mask at RGB resolution, half-open
    embedding: float32 [d] unit image embedding, or None to embed the label text
    """

    instance_id: int
    label: str
    score: float
    bbox_px: tuple[int, int, int, int]
    embedding: np.ndarray | None = None

    @property
    def bbox_area_px(self) -> int:
        x0, y0, x1, y1 = self.bbox_px
        return max(0, x1 - x0) * max(0, y1 - y0)


@dataclass
class FrameDetections:
    """All detections of one frame: an instance image at RGB size plus one entry per id.

    instance_image: uint16 [H, W], the detection's instance_id per pixel, 0 = none
    """

    instance_image: np.ndarray
    detections: list[Detection]

    def mask(self, detection: Detection) -> np.ndarray:
        """bool [H, W] mask of one detection (a full-image pass)."""
        return self.instance_image == detection.instance_id


class PerceptionBackend(abc.ABC):
    """keyframe -> the keyframe's detections.

    One instance serves every session of a server that chose it, so `detect` may run in
    several worker threads at once. It runs on keyframes only, in the mapping worker, on a
    frame the engine has already validated (`MappingEngine.validate_frame`).
    """

    name: str = "abstract"
    needs_rgb: bool = True
    """Whether `detect` reads `FrameInput.rgb`; if not, frames skip decoding the pixels."""

    @abc.abstractmethod
    def detect(self, frame: FrameInput, sent: FrameDetections | None) -> FrameDetections:
        """Detect the objects of one validated keyframe.

        sent: the detections the device sent with the frame, validated and indexed (None
              when it sent none); a backend may use them, refine them or ignore them.
        """
