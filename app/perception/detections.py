"""The `detections` backend: the device sends its detections with the frame.

Real devices can (ARKit / Quest scene understanding, an on-device detector); the device
emulator renders ground truth through a noise model. The engine validates and indexes them with every frame (`detections_from_instance_image`);
this backend passes a keyframe's on to mapping.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from app.perception.base import (
    Detection,
    FrameDetections,
    InputError,
    PerceptionBackend,
)
from app.protocol import FrameInput
from app.protocol.limits import MAX_INSTANCES_PER_FRAME as MAX_INSTANCES
from app.protocol.limits import MAX_LABEL_CHARS


def detections_from_instance_image(
    instance_image: np.ndarray, instances: list[dict], rgb_size: tuple[int, int]
) -> FrameDetections:
    """Validate a device's instance image + instance list and index it as detections.

    instance_image: uint16 [H, W] at RGB size; every non-zero id must have an entry.
    Instances listed but absent from the image are dropped (nothing to map).
    """
    width, height = rgb_size
    if not isinstance(instance_image, np.ndarray) or instance_image.ndim != 2:
        raise InputError("detections", "instance image must be a 2-D array")
    if instance_image.shape != (height, width):
        raise InputError(
            "detections",
            f"instance image is {instance_image.shape[1]}x{instance_image.shape[0]}, "
            f"RGB is {width}x{height}; they must match",
        )
    if instance_image.dtype != np.uint16:
        raise InputError("detections", f"instance image must be uint16, got {instance_image.dtype}")
    if not isinstance(instances, list) or len(instances) > MAX_INSTANCES:
        raise InputError("detections.instances", f"must be a list of at most {MAX_INSTANCES}")

    by_id: dict[int, dict] = {}
    for i, inst in enumerate(instances):
        where = f"detections.instances[{i}]"
        if not isinstance(inst, dict):
            raise InputError(where, "must be an object with id, label, score")
        iid, label, score = inst.get("id"), inst.get("label"), inst.get("score", 1.0)
        if isinstance(iid, bool) or not isinstance(iid, int) or not 1 <= iid <= 65535:
            raise InputError(f"{where}.id", f"must be an integer in [1, 65535], got {iid!r}")
        if iid in by_id:
            raise InputError(f"{where}.id", f"duplicate instance id {iid}")
        if not isinstance(label, str) or not label.strip() or len(label) > MAX_LABEL_CHARS:
            raise InputError(
                f"{where}.label",
                f"must be a non-empty string of at most {MAX_LABEL_CHARS} characters",
            )
        if (
            isinstance(score, bool)
            or not isinstance(score, int | float)
            or not math.isfinite(score)
            or not 0 <= score <= 1
        ):
            raise InputError(f"{where}.score", f"must be a number in [0, 1], got {score!r}")
        by_id[iid] = {"label": label.strip(), "score": float(score)}

    # Every frame: the ids present, by one bincount of the labelled pixels (a third of the
    # cost of counting every pixel). Boxes only when a stage reads them.
    counts = np.bincount(instance_image[instance_image != 0])
    present = np.flatnonzero(counts).tolist()
    unlabelled = [iid for iid in present if iid not in by_id]
    if unlabelled:
        raise InputError(
            "detections.instances",
            f"instance ids {unlabelled[:10]} appear in the instance image but have no label",
        )
    return DeviceDetections(instance_image, {iid: by_id[iid] for iid in present})


class DeviceDetections(FrameDetections):
    """Detections a device sent, validated with every frame; their boxes are found (one
    pass over the image) when a stage first reads `detections`: a keyframe's mapping, not
    a sighting, which reads labels at a few pixels only."""

    def __init__(self, instance_image: np.ndarray, present: dict[int, dict]):
        self.instance_image = instance_image
        self._present = present
        """id -> {"label", "score"} of the ids in the image, in id order."""
        self._detections: list[Detection] | None = None

    @property
    def detections(self) -> list[Detection]:  # type: ignore[override]
        if self._detections is None:
            slices = ndimage.find_objects(self.instance_image)
            self._detections = []
            for iid, meta in self._present.items():
                ys, xs = slices[iid - 1]
                box = (xs.start, ys.start, xs.stop, ys.stop)
                self._detections.append(Detection(iid, meta["label"], meta["score"], box))
        return self._detections

    def labels(self) -> dict[int, str]:
        return {iid: meta["label"] for iid, meta in self._present.items()}


class DetectionsBackend(PerceptionBackend):
    """Client-supplied detections (the embedded default): the device's own, as validated."""

    name = "detections"
    needs_rgb = False

    def detect(self, frame: FrameInput, sent: FrameDetections | None) -> FrameDetections:
        if sent is None:
            width, height = frame.rgb_size
            return FrameDetections(np.zeros((height, width), np.uint16), [])
        return sent
