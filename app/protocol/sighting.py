"""The `sighting` (device -> server on the stream socket): an optional, negotiated v1 extension.

"Send what the server maps." A device that opens the stream socket offering the WebSocket
subprotocol `SIGHTINGS_SUBPROTOCOL`, and sees the server select it, picks the keyframes
itself with the selector the server uses for whole-frame streams (`app.keyframes`). It sends
each keyframe whole, as a `frame` (which the server then always maps), and between keyframes
only what confirmation needs: a `sighting`, the frame's detections and a coarse depth for
visibility, without the RGB image. A server that does not know the subprotocol does not
select it, and the device sends every frame whole, as any v1 client does.

    sighting = {"type": "sighting", "seq": int, "t": float,
                "pose": bin, "intrinsics": [fx, fy, cx, cy],       # as in a frame
                "size": [W, H],                                   # of the RGB image
                "depth": {"codec", "w", "h", "scale", "data"},    # W x H / an integer ratio
                "detections": {"codec", "w", "h", "data",         # W x H / an integer ratio
                               "instances": [{"id", "label", "score"}]}}

It gets exactly one ack (`keyframe: false`) or one error, as a frame does, and is bounded by
the same limits (`FRAME_LIMITS` when unpacked, the server's `FrameBudget` for each image,
the declared RGB size and the instances).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from app.errors import InputError
from app.protocol.frame import (
    FrameInput,
    Uint16Image,
    _image_size,
    _require,
    pack_depth_part,
    pack_detections_part,
    parse_depth,
    parse_detections,
    parse_stamp_and_camera,
)
from app.protocol.limits import FrameBudget

SIGHTINGS_SUBPROTOCOL = "semanticxr.sightings.v1"
"""The WebSocket subprotocol a device offers on the stream socket to send sightings between
the keyframes it picks; a server that supports the extension selects it."""


def is_sighting(message: Any) -> bool:
    """Whether an unpacked stream message says it is a `sighting` (not a `frame`)."""
    return isinstance(message, dict) and message.get("type") == "sighting"


def pack_sighting(
    seq: int,
    t: float,
    pose: bytes,
    intrinsics: Sequence[float],
    rgb_size: tuple[int, int],
    depth: Uint16Image,
    depth_scale_m: float,
    detections: Uint16Image,
    instances: Sequence[dict],
) -> dict:
    """A `sighting` message, ready for `msgpack.packb`, from its already-encoded parts.

    pose: 64 bytes (`codecs.pose_to_bytes`); intrinsics (fx, fy, cx, cy) and rgb_size (W, H)
    of the RGB image the device saw (not sent); depth: a coarse depth image in units of
    `depth_scale_m` metres; detections: a coarse instance-id image, with `instances`
    [{"id", "label", "score"}] describing it. Both images are the RGB size divided by an
    integer ratio (each its own)."""
    return {
        "type": "sighting",
        "seq": int(seq),
        "t": float(t),
        "pose": pose,
        "intrinsics": [float(value) for value in intrinsics],
        "size": [int(rgb_size[0]), int(rgb_size[1])],
        "depth": pack_depth_part(depth, depth_scale_m),
        "detections": pack_detections_part(detections, instances),
    }


_NO_BUDGET = FrameBudget()


def parse_sighting(message: Any, budget: FrameBudget = _NO_BUDGET) -> FrameInput:
    """A `sighting` message (already unpacked) -> FrameInput with no RGB pixels, the coarse
    depth and the coarse instance image; InputError naming the first bad field (LimitError
    for a part over `budget`, checked before it is decoded). What only the engine knows is
    checked there (`MappingEngine.validate_sighting`: the size ratios, the instances)."""
    if not isinstance(message, dict):
        raise InputError("message", f"must be a map, got {type(message).__name__}")
    if message.get("type") != "sighting":
        raise InputError("type", f"must be 'sighting', got {message.get('type')!r}")
    seq, t, pose, intrinsics = parse_stamp_and_camera(message)
    size = _require(message, "size", list)
    if len(size) != 2 or not all(isinstance(v, int) and not isinstance(v, bool) for v in size):
        raise InputError("size", "must be the RGB image's [width, height] in pixels")
    width, height = _image_size({"w": size[0], "h": size[1]}, "size.")
    budget.check_pixels("size", width, height)
    depth_m = parse_depth(message, budget)
    instance_ids, instances = parse_detections(_require(message, "detections", dict), budget)
    return FrameInput(
        seq=seq,
        t=t,
        pose=pose,
        intrinsics=intrinsics,
        rgb_size=(width, height),
        depth_m=depth_m,
        instance_ids=instance_ids,
        instances=instances,
    )
