"""The v1 `frame` (device -> server on the stream socket): pack, unpack, parse, validate.

The device packs the parts it has already encoded (`pack_frame`); the server unpacks the
socket's bytes within the frame limits (`unpack_frame_message`) and parses the message into
the `FrameInput` the engine consumes (`parse_frame`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from app import codecs
from app.errors import InputError
from app.protocol.limits import (
    FRAME_LIMITS,
    MAX_IMAGE_SIDE_PX,
    MAX_INTRINSIC_PX,
    FrameBudget,
    unpack_limited,
)

TYPE_FIELD = "type"
"""The field in which every stream message names its kind ("frame" or "sighting")."""
POSE_FIELD = "pose"
"""The camera-to-world pose of a frame or a sighting (16 float32, little-endian, row-major)."""
INTRINSICS_FIELD = "intrinsics"
"""[fx, fy, cx, cy] of the RGB image, in its pixels."""
RGB_FIELD = "rgb"
"""The RGB image part (JPEG); its size is the frame's RGB size."""
DEPTH_FIELD = "depth"
"""The depth part: a uint16 image, the RGB size divided by an integer ratio."""
DETECTIONS_FIELD = "detections"
"""The device's detections: an instance-id image and its instances."""
FRAME_PARTS = (RGB_FIELD, DEPTH_FIELD, DETECTIONS_FIELD)
"""The binary parts a stream message may carry, each a map holding its bytes in `data`: the
kinds of a session's `bytes_in`."""


def stream_message_seq(message: Any) -> int | None:
    """The integer `seq` of an unpacked stream message, else None: what the reply to a
    message refused before it is parsed carries."""
    seq = message.get("seq") if isinstance(message, dict) else None
    return seq if isinstance(seq, int) and not isinstance(seq, bool) else None


def part_sizes(message: Any) -> dict[str, int]:
    """The bytes of each binary part (`FRAME_PARTS`) an unpacked stream message carries, by
    kind; a part missing or of another shape is left out (parsing refuses it)."""
    sizes = {}
    if not isinstance(message, dict):
        return sizes
    for kind in FRAME_PARTS:
        part = message.get(kind)
        if isinstance(part, dict) and isinstance(part.get("data"), bytes):
            sizes[kind] = len(part["data"])
    return sizes


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
    depth_patches: full-resolution depth of a few boxes of the RGB image (the depth
                  co-design for small things: `DepthPatch`), optional
    pose_skew_s:  the RGB image's capture time minus the pose's (seconds), where the device
                  paired an image with the nearest pose of another clock (a headset's camera
                  read through getUserMedia); None where image and pose are one sample
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
    depth_patches: list[DepthPatch] = field(default_factory=list)
    pose_skew_s: float | None = None


MAX_POSE_SKEW_S = 10.0
"""Largest |pose_skew_s| a frame may declare: an image seconds away from its pose is a bug."""

POSE_FIELD = "pose"
"""The camera-to-world pose of a frame or a sighting (16 float32, little-endian, row-major)."""
INTRINSICS_FIELD = "intrinsics"
"""[fx, fy, cx, cy] of the RGB image, in its pixels."""
RGB_FIELD = "rgb"
"""The RGB image part (JPEG); its size is the frame's RGB size."""
DEPTH_FIELD = "depth"
"""The depth part: a uint16 image, the RGB size divided by an integer ratio."""
DETECTIONS_FIELD = "detections"
"""The device's detections: an instance-id image and its instances."""


@dataclass(frozen=True)
class DepthPatch:
    """Depth at RGB resolution over one box of the RGB image.

    box_px:  (x0, y0, x1, y1) in RGB pixels, half-open
    depth_m: float32 [y1 - y0, x1 - x0] metres, 0 = invalid
    """

    box_px: tuple[int, int, int, int]
    depth_m: np.ndarray


@dataclass(frozen=True)
class EncodedDepthPatches:
    """The encoded `depth_patches` part of a frame: the boxes' depth pixels, box after box,
    each row-major, zero-padded to whole rows of the RGB width, as one uint16 image."""

    codec: str
    """One of `app.codecs.DEPTH_CODECS`."""
    boxes: list[tuple[int, int, int, int]]
    """(x0, y0, x1, y1) per patch, RGB pixels, half-open."""
    data: bytes


def patch_rows(boxes: Sequence[Sequence[int]], width: int) -> int:
    """Rows of RGB width that hold the boxes' pixels one after another (the last row padded)."""
    pixels = sum((x1 - x0) * (y1 - y0) for x0, y0, x1, y1 in boxes)
    return max(1, -(-pixels // max(width, 1)))


def pack_depth_patches(
    depth_units: np.ndarray,
    boxes: Sequence[tuple[int, int, int, int]],
    codec: str = "zstd",
    level: int | None = None,
) -> EncodedDepthPatches:
    """The `depth_patches` part of a frame: `depth_units` (uint16 [H, W] at RGB size, in the
    frame's depth units) over each box (x0, y0, x1, y1), half-open, inside the image."""
    height, width = depth_units.shape
    pixels = np.concatenate(
        [np.asarray(depth_units[y0:y1, x0:x1], np.uint16).ravel() for x0, y0, x1, y1 in boxes]
        or [np.zeros(0, np.uint16)]
    )
    rows = patch_rows(boxes, width)
    padded = np.zeros(rows * width, np.uint16)
    padded[: len(pixels)] = pixels
    data = codecs.encode_uint16_image(padded.reshape(rows, width), codec, level)
    return EncodedDepthPatches(codec, [tuple(int(v) for v in b) for b in boxes], data)


@dataclass(frozen=True)
class Uint16Image:
    """An encoded uint16 image part of a frame (depth or detection instance ids)."""

    codec: str
    """One of `app.codecs.DEPTH_CODECS`."""
    w: int
    h: int
    data: bytes


def pack_depth_part(depth: Uint16Image, depth_scale_m: float) -> dict:
    """The "depth" part of a stream message: a uint16 image in units of `depth_scale_m` metres."""
    return {
        "codec": depth.codec,
        "w": int(depth.w),
        "h": int(depth.h),
        "scale": float(depth_scale_m),
        "data": depth.data,
    }


DEPTH_PATCHES_FIELD = "depth_patches"
"""Full-resolution depth of some boxes of the detections (optional)."""
INSTANCES_FIELD = "instances"
"""The instances of a detections part: [{"id", "label", "score"}] for the ids in its image."""
LABEL_FIELD = "label"
"""An instance's label (its detector's category text)."""


def pack_detections_part(detections: Uint16Image, instances: Sequence[dict]) -> dict:
    """The "detections" part of a stream message: an instance-id image and its instances
    [{"id", "label", "score"}]."""
    return {
        "codec": detections.codec,
        "w": int(detections.w),
        "h": int(detections.h),
        "data": detections.data,
        "instances": [
            {"id": int(inst["id"]), "label": str(inst["label"]), "score": float(inst["score"])}
            for inst in instances
        ],
    }


def pack_frame(
    seq: int,
    t: float,
    pose: bytes,
    intrinsics: Sequence[float],
    rgb_jpeg: bytes,
    depth: Uint16Image,
    depth_scale_m: float,
    detections: Uint16Image | None = None,
    instances: Sequence[dict] = (),
    depth_patches: EncodedDepthPatches | None = None,
) -> dict:
    """A v1 `frame` message, ready for `msgpack.packb`, from its already-encoded parts.

    pose: 64 bytes (`codecs.pose_to_bytes`); intrinsics (fx, fy, cx, cy) of the RGB image;
    depth: the (downsampled) depth image in units of `depth_scale_m` metres; detections: the
    instance-id image at RGB size, with `instances` [{"id", "label", "score"}] describing it;
    depth_patches: full-resolution depth of some boxes, in units of `depth_scale_m` too.
    """
    if instances and detections is None:
        raise ValueError("instances given without a detections image")
    message: dict = {
        "type": "frame",
        "seq": int(seq),
        "t": float(t),
        POSE_FIELD: pose,
        INTRINSICS_FIELD: [float(value) for value in intrinsics],
        RGB_FIELD: {"codec": "jpeg", "data": rgb_jpeg},
        DEPTH_FIELD: pack_depth_part(depth, depth_scale_m),
    }
    if detections is not None:
        message[DETECTIONS_FIELD] = pack_detections_part(detections, instances)
    if depth_patches is not None and depth_patches.boxes:
        message["depth_patches"] = {
            "codec": depth_patches.codec,
            "boxes": [[int(v) for v in box] for box in depth_patches.boxes],
            "data": depth_patches.data,
        }
    return message


def unpack_frame_message(raw: bytes) -> Any:
    """A message from the stream socket (device -> server), unpacked within `FRAME_LIMITS`;
    InputError("message", ...) if it is not msgpack or is over a limit. The message itself
    is validated by `parse_frame`."""
    return unpack_limited(raw, FRAME_LIMITS)


def _require(message: dict, key: str, kind: type | tuple[type, ...], where: str = "") -> Any:
    name = f"{where}{key}"
    if key not in message:
        raise InputError(name, "is missing")
    value = message[key]
    if isinstance(value, bool) and bool not in (kind if isinstance(kind, tuple) else (kind,)):
        raise InputError(name, f"must be {_kind_name(kind)}, got a boolean")
    if not isinstance(value, kind):
        raise InputError(name, f"must be {_kind_name(kind)}, got {type(value).__name__}")
    return value


def _kind_name(kind: type | tuple[type, ...]) -> str:
    kinds = kind if isinstance(kind, tuple) else (kind,)
    names = {
        int: "an integer",
        float: "a number",
        str: "a string",
        bytes: "binary",
        dict: "a map",
        list: "a list",
    }
    return " or ".join(names.get(k, k.__name__) for k in kinds)


def _image_size(message: dict, where: str) -> tuple[int, int]:
    w = _require(message, "w", int, where)
    h = _require(message, "h", int, where)
    if not (1 <= w <= MAX_IMAGE_SIDE_PX and 1 <= h <= MAX_IMAGE_SIDE_PX):
        raise InputError(f"{where}w", f"image size {w}x{h} must be within 1..{MAX_IMAGE_SIDE_PX}")
    return w, h


_NO_BUDGET = FrameBudget()


def parse_frame(
    message: Any, rgb_pixels: bool = True, budget: FrameBudget = _NO_BUDGET, mapped: bool = True
) -> FrameInput:
    """A v1 `frame` message (already unpacked from msgpack) -> FrameInput.

    Validates every field and raises InputError naming the first bad one; does not check
    what only the engine knows (depth/RGB size ratio, detections vs labels).
    rgb_pixels=False: the JPEG is fully validated but its pixels are not kept (`rgb` is None),
    for perception backends that do not look at the image (`PerceptionBackend.needs_rgb`).
    budget: the server's; each image's declared size (the JPEG's from its header) and the
    instance count are checked against it before that part is decoded (`LimitError`).
    Keys the protocol does not know are ignored (v1 extensions); what they may hold is
    bounded by `FRAME_LIMITS` when the message is unpacked.
    mapped=False: a frame no stage maps (not a keyframe), so only what every frame needs is
    decoded: the JPEG and the depth patches are checked as far as their headers and boxes
    (`rgb` and `depth_patches` are left empty); pose, depth and detections in full.
    """
    if not isinstance(message, dict):
        raise InputError("message", f"must be a map, got {type(message).__name__}")
    if message.get("type") != "frame":
        raise InputError("type", f"must be 'frame', got {message.get('type')!r}")
    seq, t, pose, intrinsics = parse_stamp_and_camera(message)

    rgb_msg = _require(message, RGB_FIELD, dict)
    if rgb_msg.get("codec") != "jpeg":
        raise InputError("rgb.codec", f"must be 'jpeg', got {rgb_msg.get('codec')!r}")
    rgb_data = _require(rgb_msg, "data", bytes, "rgb.")
    declared = codecs.jpeg_size(rgb_data, field=RGB_FIELD)
    budget.check_pixels(RGB_FIELD, *declared)
    rgb = None
    if not mapped:
        width, height = declared
    elif rgb_pixels:
        rgb = codecs.decode_jpeg(rgb_data, field=RGB_FIELD)
        height, width = rgb.shape[:2]
    else:
        width, height = codecs.validate_jpeg(rgb_data, field=RGB_FIELD)

    depth_m = parse_depth(message, budget)

    instance_ids, instances = None, []
    det_msg = message.get(DETECTIONS_FIELD)
    if det_msg is not None:
        instance_ids, instances = parse_detections(det_msg, budget, rgb_size=(width, height))
    scale = float(message[DEPTH_FIELD]["scale"])  # validated by parse_depth
    patches = _parse_depth_patches(
        message.get("depth_patches"), width, height, scale, budget, decode=mapped
    )
    pose_skew_s = _parse_pose_skew(message.get("pose_skew_s"))

    return FrameInput(
        seq=seq,
        t=t,
        pose=pose,
        intrinsics=intrinsics,
        rgb_size=(width, height),
        depth_m=depth_m,
        rgb=rgb,
        instance_ids=instance_ids,
        instances=instances,
        depth_patches=patches,
        pose_skew_s=pose_skew_s,
    )


def _parse_pose_skew(value: Any) -> float | None:
    """The optional `pose_skew_s` (v1 extension): a finite number of seconds within
    MAX_POSE_SKEW_S, or absent."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise InputError("pose_skew_s", f"must be a finite number of seconds, got {value!r}")
    if abs(value) > MAX_POSE_SKEW_S:
        raise InputError("pose_skew_s", f"must be within ±{MAX_POSE_SKEW_S:g} s, got {value!r}")
    return float(value)


# --- parts shared by the stream socket's messages (frame, and the sighting extension) ---------


def parse_stamp_and_camera(
    message: dict,
) -> tuple[int, float, np.ndarray, tuple[float, float, float, float]]:
    """(seq, t, pose [4, 4] camera-to-world, intrinsics (fx, fy, cx, cy)) of a message;
    InputError naming the first bad field."""
    seq = _require(message, "seq", int)
    t = float(_require(message, "t", (int, float)))
    if not math.isfinite(t):
        raise InputError("t", "must be finite")

    pose = codecs.validate_rigid_pose(codecs.pose_from_bytes(_require(message, POSE_FIELD, bytes)))

    intrinsics = _require(message, INTRINSICS_FIELD, list)
    if len(intrinsics) != 4 or not all(
        isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
        for v in intrinsics
    ):
        raise InputError(INTRINSICS_FIELD, "must be 4 finite numbers [fx, fy, cx, cy]")
    fx, fy, cx, cy = (float(v) for v in intrinsics)
    if not (0 < fx < MAX_INTRINSIC_PX and 0 < fy < MAX_INTRINSIC_PX):
        raise InputError(INTRINSICS_FIELD, "fx and fy must be positive")
    return seq, t, pose, (fx, fy, cx, cy)


def parse_depth(message: dict, budget: FrameBudget) -> np.ndarray:
    """The message's "depth" part -> float32 [h, w] metres (0 = no depth); its declared size
    is checked against `budget` before it is decoded."""
    depth_msg = _require(message, DEPTH_FIELD, dict)
    dw, dh = _image_size(depth_msg, "depth.")
    budget.check_pixels(DEPTH_FIELD, dw, dh)
    scale = float(_require(depth_msg, "scale", (int, float), "depth."))
    if not (math.isfinite(scale) and 0 < scale <= 1):
        raise InputError("depth.scale", f"must be metres per unit in (0, 1], got {scale!r}")
    codec = _require(depth_msg, "codec", str, "depth.")
    raw_depth = codecs.decode_uint16_image(
        _require(depth_msg, "data", bytes, "depth."), codec, dw, dh, field=DEPTH_FIELD
    )
    return raw_depth.astype(np.float32) * np.float32(scale)


def parse_detections(
    det_msg: Any, budget: FrameBudget, rgb_size: tuple[int, int] | None = None
) -> tuple[np.ndarray, list]:
    """A "detections" part -> (uint16 [h, w] instance ids, the instances list as sent, for
    the engine to validate). Before the image is decoded: its declared size must be
    `rgb_size` (W, H) where given, and it and the instance count are checked against
    `budget`."""
    if not isinstance(det_msg, dict):
        raise InputError(DETECTIONS_FIELD, "must be a map")
    iw, ih = _image_size(det_msg, "detections.")
    if rgb_size is not None and (iw, ih) != tuple(rgb_size):
        raise InputError(
            DETECTIONS_FIELD,
            f"instance image is {iw}x{ih}, RGB is {rgb_size[0]}x{rgb_size[1]}; they must match",
        )
    budget.check_pixels(DETECTIONS_FIELD, iw, ih)
    instances = _require(det_msg, "instances", list, "detections.")
    budget.check_instances("detections.instances", len(instances))
    instance_ids = codecs.decode_uint16_image(
        _require(det_msg, "data", bytes, "detections."),
        _require(det_msg, "codec", str, "detections."),
        iw,
        ih,
        field=DETECTIONS_FIELD,
    )
    return instance_ids, instances


def _parse_depth_patches(
    part: Any, width: int, height: int, scale: float, budget: FrameBudget, decode: bool = True
) -> list[DepthPatch]:
    """The optional `depth_patches` part (v1 extension): boxes inside the RGB image, their
    pixels at most the RGB image's, in the depth's units (`depth.scale`). decode=False:
    the boxes and the declared size are checked, the data is not decoded (no patches)."""
    if part is None:
        return []
    if not isinstance(part, dict):
        raise InputError("depth_patches", "must be a map")
    boxes = _require(part, "boxes", list, "depth_patches.")
    budget.check_instances("depth_patches.boxes", len(boxes))
    checked = []
    for k, box in enumerate(boxes):
        if not (
            isinstance(box, list)
            and len(box) == 4
            and all(isinstance(v, int) and not isinstance(v, bool) for v in box)
        ):
            raise InputError(f"depth_patches.boxes[{k}]", "must be 4 integers [x0, y0, x1, y1]")
        x0, y0, x1, y1 = box
        if not (0 <= x0 < x1 <= width and 0 <= y0 < y1 <= height):
            raise InputError(
                f"depth_patches.boxes[{k}]",
                f"{box} must be a non-empty box inside the {width}x{height} RGB image",
            )
        checked.append((x0, y0, x1, y1))
    if not checked:
        return []
    rows = patch_rows(checked, width)
    if rows > height:
        raise InputError("depth_patches", "the boxes hold more pixels than the RGB image")
    budget.check_pixels("depth_patches", width, rows)
    if not decode:
        _require(part, "data", bytes, "depth_patches.")
        _require(part, "codec", str, "depth_patches.")
        return []
    units = codecs.decode_uint16_image(
        _require(part, "data", bytes, "depth_patches."),
        _require(part, "codec", str, "depth_patches."),
        width,
        rows,
        field="depth_patches",
    ).reshape(-1)
    patches, start = [], 0
    for x0, y0, x1, y1 in checked:
        n = (x1 - x0) * (y1 - y0)
        depth_m = units[start : start + n].reshape(y1 - y0, x1 - x0).astype(np.float32)
        patches.append(DepthPatch((x0, y0, x1, y1), depth_m * np.float32(scale)))
        start += n
    return patches
