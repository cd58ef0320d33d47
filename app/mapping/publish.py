"""The client representation of objects and the downstream delta message.

One function owns each representation: `client_points` is the only place that turns an
object's server geometry into what crosses the network, and `delta_message` the only place
that builds a v1 `delta`.
"""

from __future__ import annotations

import numpy as np

from app.codecs import float16_points_to_bytes, float16_vector_to_bytes, pose_to_bytes
from app.mapping.deltas import Delta
from app.mapping.engine import MappingEngine
from app.mapping.geometry import cap_points
from app.mapping.object import MapObject


def client_points(obj: MapObject, max_points: int | None) -> np.ndarray:
    """float32 [<= max_points, 3] of the object as a device holds it (None: full resolution).

    Deterministic, and cached on the object until it changes.
    """
    key = (obj.version, max_points)
    cached = obj._client_cache
    if cached is not None and cached[0] == key:
        return cached[1]
    if max_points is None or len(obj.points) <= max_points:
        points = obj.points
    else:
        points, _ = cap_points(obj.points, max_points, max(obj.resolution_m, 0.025))
    obj._client_cache = (key, points)
    return points


def object_upsert(obj: MapObject, max_points: int | None) -> dict:
    """The `upserts[]` entry of one object (embedding and points as float16 bytes)."""
    points = client_points(obj, max_points)
    return {
        "id": obj.id,
        "version": obj.version,
        "label": obj.label,
        "embedding": float16_vector_to_bytes(obj.embedding),
        "points": float16_points_to_bytes(points),
        "bbox": [float(v) for v in obj.bbox],
        "n_obs": obj.n_obs,
    }


def delta_message(delta: Delta, objects: dict[int, MapObject], max_points: int | None) -> dict:
    """A v1 `delta` message for `delta`; ids no longer in `objects` are skipped."""
    return {
        "type": "delta",
        "seq": delta.seq,
        "full": delta.full,
        "upserts": [object_upsert(objects[i], max_points) for i in delta.upserts if i in objects],
        "removed": list(delta.removed),
    }


def update_message(engine: MappingEngine, since: int | None) -> dict:
    """The update a subscriber whose last applied seq is `since` receives.

    semanticxr: the objects changed since `since`, coalesced, at client resolution.
    baseline: the whole confirmed map at full resolution, every time (DESIGN.md's table).
    Extension of v1 (an optional field): "device_pose", the newest mapped keyframe's
    camera-to-world pose in the frame's own encoding (16 float32 LE, row-major), so viewers
    can show where the device is.
    """
    if engine.mode == "baseline":
        message = delta_message(engine.delta_since(None), engine.objects, None)
    else:
        max_points = engine.knobs.max_object_points_client
        message = delta_message(engine.delta_since(since), engine.objects, max_points)
    if engine.last_pose is not None:
        message["device_pose"] = pose_to_bytes(engine.last_pose)
    return message
