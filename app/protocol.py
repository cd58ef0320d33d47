"""Wire protocol v1 (DESIGN.md "Wire protocol v1"): build, parse and validate messages.

msgpack maps in binary WebSocket messages; binary fields are raw bytes. This module is the
one place that knows the field names; the server, the device and the viewer import it.
"""

from __future__ import annotations

import math
from typing import Any

import msgpack
import numpy as np

from app import codecs
from app.perception.base import FrameInput, InputError

PROTOCOL_VERSION = 1
MAX_IMAGE_SIDE_PX = 8192
MAX_INTRINSIC = 1e6


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


def decode_frame(message: Any, rgb_pixels: bool = True) -> FrameInput:
    """A v1 `frame` message (already unpacked from msgpack) -> FrameInput.

    Validates every field and raises InputError naming the first bad one; does not check
    what only the engine knows (depth/RGB size ratio, detections vs labels).
    rgb_pixels=False: the JPEG is fully validated but its pixels are not kept (`rgb` is None),
    for perception backends that do not look at the image (`PerceptionBackend.needs_rgb`).
    """
    if not isinstance(message, dict):
        raise InputError("message", f"must be a map, got {type(message).__name__}")
    if message.get("type") != "frame":
        raise InputError("type", f"must be 'frame', got {message.get('type')!r}")
    seq = _require(message, "seq", int)
    t = float(_require(message, "t", (int, float)))
    if not math.isfinite(t):
        raise InputError("t", "must be finite")

    pose = codecs.validate_rigid_pose(codecs.pose_from_bytes(_require(message, "pose", bytes)))

    intrinsics = _require(message, "intrinsics", list)
    if len(intrinsics) != 4 or not all(
        isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
        for v in intrinsics
    ):
        raise InputError("intrinsics", "must be 4 finite numbers [fx, fy, cx, cy]")
    fx, fy, cx, cy = (float(v) for v in intrinsics)
    if not (0 < fx < MAX_INTRINSIC and 0 < fy < MAX_INTRINSIC):
        raise InputError("intrinsics", "fx and fy must be positive")

    rgb_msg = _require(message, "rgb", dict)
    if rgb_msg.get("codec") != "jpeg":
        raise InputError("rgb.codec", f"must be 'jpeg', got {rgb_msg.get('codec')!r}")
    rgb_data = _require(rgb_msg, "data", bytes, "rgb.")
    if rgb_pixels:
        rgb = codecs.decode_jpeg(rgb_data, field="rgb")
        height, width = rgb.shape[:2]
    else:
        rgb = None
        width, height = codecs.validate_jpeg(rgb_data, field="rgb")

    depth_msg = _require(message, "depth", dict)
    dw, dh = _image_size(depth_msg, "depth.")
    scale = float(_require(depth_msg, "scale", (int, float), "depth."))
    if not (math.isfinite(scale) and 0 < scale <= 1):
        raise InputError("depth.scale", f"must be metres per unit in (0, 1], got {scale!r}")
    codec = _require(depth_msg, "codec", str, "depth.")
    raw_depth = codecs.decode_uint16_image(
        _require(depth_msg, "data", bytes, "depth."), codec, dw, dh, field="depth"
    )
    depth_m = raw_depth.astype(np.float32) * np.float32(scale)

    instance_ids, instances = None, []
    det_msg = message.get("detections")
    if det_msg is not None:
        if not isinstance(det_msg, dict):
            raise InputError("detections", "must be a map")
        iw, ih = _image_size(det_msg, "detections.")
        if (iw, ih) != (width, height):
            raise InputError(
                "detections",
                f"instance image is {iw}x{ih}, RGB is {width}x{height}; they must match",
            )
        instance_ids = codecs.decode_uint16_image(
            _require(det_msg, "data", bytes, "detections."),
            _require(det_msg, "codec", str, "detections."),
            iw,
            ih,
            field="detections",
        )
        instances = _require(det_msg, "instances", list, "detections.")

    return FrameInput(
        seq=seq,
        t=t,
        pose=pose,
        intrinsics=(fx, fy, cx, cy),
        rgb_size=(width, height),
        depth_m=depth_m,
        rgb=rgb,
        instance_ids=instance_ids,
        instances=instances,
    )


def unpack_update(raw: bytes | str) -> dict | str:
    """A message from the updates socket, unpacked; or what is wrong with it (a string).

    Only the framing is checked here (binary msgpack); the delta itself is validated by
    whoever applies it.
    """
    if not isinstance(raw, bytes):
        return "a text message; updates are binary msgpack"
    try:
        return msgpack.unpackb(raw, raw=False)
    except Exception as exc:  # msgpack raises many types for garbage
        return f"not msgpack ({type(exc).__name__})"
