"""One frame's detections and the backend interface (the decoded frame, `FrameInput`, is
the protocol's: `app.protocol.frame`)."""

from __future__ import annotations

import abc
from dataclasses import dataclass

import numpy as np

from app.config import Mode
from app.errors import InputError
from app.protocol.frame import FrameInput
from app.semantics import TextEncoder

__all__ = ["Detection", "FrameDetections", "FrameInput", "InputError", "PerceptionBackend"]


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

    def labels(self) -> dict[int, str]:
        """instance id -> label of every detection."""
        return {d.instance_id: d.label for d in self.detections}


class PerceptionBackend(abc.ABC):
    """keyframe -> the keyframe's detections.

    One instance serves every session of a server that chose it, so `detect` may run in
    several worker threads at once. It runs on keyframes only, in the mapping worker, on a
    frame the engine has already validated (`MappingEngine.validate_frame`).
    """

    name: str = "abstract"
    needs_rgb: bool = True
    """Whether `detect` reads `FrameInput.rgb`; if not, frames skip decoding the pixels."""
    text_encoder: TextEncoder | None = None
    """The encoder whose space this backend's embeddings live in (sessions then embed labels
    and queries with it), or None for the server's default text encoder."""

    def for_mode(self, mode: Mode) -> PerceptionBackend:
        """This backend as a session of organisation `mode` uses it. A backend whose work is
        organised differently per mode (batched per keyframe or object by object) returns a
        view sharing its models; the default is the backend itself."""
        return self

    @abc.abstractmethod
    def detect(self, frame: FrameInput, sent: FrameDetections | None) -> FrameDetections:
        """Detect the objects of one validated keyframe.

        sent: the detections the device sent with the frame, validated and indexed (None
              when it sent none); a backend may use them, refine them or ignore them.
        """
