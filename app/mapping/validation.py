"""Checks on a frame or a sighting before the mapping engine uses it: what a device sends
that cannot be mapped is refused with an InputError naming the wire field."""

from __future__ import annotations

import math

import numpy as np

from app.codecs import validate_rigid_pose
from app.perception.base import FrameDetections, InputError
from app.perception.detections import detections_from_instance_image
from app.protocol import MAX_INTRINSIC_PX, FrameInput
from app.protocol.frame import (
    DEPTH_FIELD,
    DETECTIONS_FIELD,
    INTRINSICS_FIELD,
    POSE_FIELD,
    RGB_FIELD,
)

MAX_WORLD_M = 10_000.0
"""A camera farther than this from the map's origin (per axis) is refused: no XR map is that
big, and it keeps lifted points finite whatever the pose bytes say."""


def check_size_ratio(field_name: str, image: np.ndarray, rgb_size: tuple[int, int]) -> None:
    """InputError unless `image` [h, w] is the RGB size (W, H) divided by an integer ratio."""
    width, height = rgb_size
    h, w = image.shape[:2]
    ratio = max(1, round(width / max(w, 1)))
    if w == 0 or h == 0 or width // ratio != w or height // ratio != h:
        raise InputError(
            field_name,
            f"is {w}x{h}, which is not the RGB size {width}x{height} divided by an integer ratio",
        )


def validate_frame(frame: FrameInput) -> FrameDetections | None:
    """Every check the engine makes on a frame, run once per frame (keyframe or not).

    Raises InputError naming the field if the frame cannot be mapped: pose (rigid,
    within MAX_WORLD_M), intrinsics, RGB size, depth (float32, the RGB size divided by an
    integer ratio), and the detections the device sent (instance image vs labels).
    Returns those detections indexed (None when the frame carries none): what a
    keyframe's perception gets as `sent`. Nothing after this re-validates the frame.
    """
    validate_view(frame)
    if frame.instance_ids is None:
        return None
    return detections_from_instance_image(frame.instance_ids, frame.instances, frame.rgb_size)


def validate_sighting(frame: FrameInput) -> FrameDetections:
    """The checks of `validate_frame` for a sighting (`app.protocol.parse_sighting`),
    whose instance image, which it must carry, may be the RGB size divided by an
    integer ratio, as its depth is. Returns the detections for `sight` (their boxes in
    the instance image's pixels)."""
    validate_view(frame)
    if frame.instance_ids is None:
        raise InputError(DETECTIONS_FIELD, "a sighting must carry detections")
    check_size_ratio(DETECTIONS_FIELD, frame.instance_ids, frame.rgb_size)
    h, w = frame.instance_ids.shape
    return detections_from_instance_image(frame.instance_ids, frame.instances, (w, h))


def validate_view(frame: FrameInput) -> None:
    """Pose, intrinsics, RGB size and depth of a frame or a sighting."""
    pose = validate_rigid_pose(np.asarray(frame.pose, np.float64))
    if np.abs(pose[:3, 3]).max() > MAX_WORLD_M:
        raise InputError(
            POSE_FIELD,
            f"translation {pose[:3, 3].tolist()} is over {MAX_WORLD_M:g} m from the origin",
        )
    intr = frame.intrinsics
    if len(intr) != 4 or not all(isinstance(v, int | float) and math.isfinite(v) for v in intr):
        raise InputError(INTRINSICS_FIELD, "must be 4 finite numbers [fx, fy, cx, cy]")
    if intr[0] <= 0 or intr[1] <= 0:
        raise InputError(INTRINSICS_FIELD, "fx and fy must be positive")
    if max(abs(v) for v in intr) > MAX_INTRINSIC_PX:
        raise InputError(INTRINSICS_FIELD, f"values must be within ±{MAX_INTRINSIC_PX:g} pixels")
    width, height = frame.rgb_size
    if width <= 0 or height <= 0:
        raise InputError(RGB_FIELD, f"image size must be positive, got {width}x{height}")
    if frame.rgb is not None and frame.rgb.shape[:2] != (height, width):
        raise InputError(
            RGB_FIELD,
            f"is {frame.rgb.shape[1]}x{frame.rgb.shape[0]}, expected {width}x{height}",
        )
    depth = frame.depth_m
    if not isinstance(depth, np.ndarray) or depth.ndim != 2:
        raise InputError(DEPTH_FIELD, "must be a 2-D array")
    if depth.dtype != np.float32:
        raise InputError(DEPTH_FIELD, f"must be float32 metres, got {depth.dtype}")
    check_size_ratio(DEPTH_FIELD, depth, frame.rgb_size)
