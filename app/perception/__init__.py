"""Perception: frame -> per-object detections, behind one interface."""

from app.perception.base import (
    Detection,
    FrameDetections,
    FrameInput,
    InputError,
    PerceptionBackend,
)
from app.perception.detections import DetectionsBackend, detections_from_instance_image

__all__ = [
    "Detection",
    "DetectionsBackend",
    "FrameDetections",
    "FrameInput",
    "InputError",
    "PerceptionBackend",
    "detections_from_instance_image",
    "make_backend",
]


def make_backend(name: str = "detections") -> PerceptionBackend:
    """The perception backend called `name`."""
    if name == "detections":
        return DetectionsBackend()
    raise ValueError(f"unknown perception backend {name!r}; available: detections")
