"""The client representation of objects and the downstream delta message.

One function owns each representation: `client_points` is the only place that turns an
object's server geometry into what crosses the network, and `delta_message` the only place
that builds a v1 `delta` (with the protocol's `DeltaMessage`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from app.config import Knobs
from app.mapping.deltas import Delta
from app.mapping.engine import MappingEngine
from app.mapping.geometry import cap_points
from app.mapping.object import MapObject
from app.protocol import ChangeEntry, DeltaMessage, UpsertEntry
from app.protocol.limits import MAX_CHANGES_PER_DELTA

MIN_CAP_RESOLUTION_M = Knobs().voxel_size_m
"""Capping never thins an object finer than the default voxel size."""


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
        points, _ = cap_points(obj.points, max_points, max(obj.resolution_m, MIN_CAP_RESOLUTION_M))
    obj._client_cache = (key, points)
    return points


LabelTextsOf = Callable[[str], Sequence[str] | None]
"""label -> its texts to send with an upsert (the server's label knowledge), None: none."""


def object_upsert(
    obj: MapObject, max_points: int | None, label_texts: LabelTextsOf | None = None
) -> UpsertEntry:
    """The `upserts[]` entry of one object (with its label's texts when `label_texts`)."""
    return UpsertEntry(
        id=obj.id,
        version=obj.version,
        label=obj.label,
        embedding=obj.embedding,
        points=client_points(obj, max_points),
        bbox=tuple(float(v) for v in obj.bbox),  # type: ignore[arg-type]
        n_obs=obj.n_obs,
        first_seen_t=obj.first_seen_t,
        last_seen_t=obj.last_seen_t,
        label_texts=_texts(obj.label, label_texts),
    )


def _texts(label: str, label_texts: LabelTextsOf | None) -> tuple[str, ...] | None:
    texts = label_texts(label) if label_texts is not None else None
    return tuple(texts) if texts is not None else None


def delta_message(
    delta: Delta,
    objects: dict[int, MapObject],
    max_points: int | None,
    label_texts: LabelTextsOf | None = None,
) -> dict:
    """A v1 `delta` message for `delta`; ids no longer in `objects` are skipped."""
    return _delta(delta, objects, max_points, label_texts).pack()


def _delta(
    delta: Delta,
    objects: dict[int, MapObject],
    max_points: int | None,
    label_texts: LabelTextsOf | None = None,
) -> DeltaMessage:
    return DeltaMessage(
        seq=delta.seq,
        full=delta.full,
        upserts=[
            object_upsert(objects[i], max_points, label_texts)
            for i in delta.upserts
            if i in objects
        ],
        removed=list(delta.removed),
    )


def update_message(
    engine: MappingEngine, since: int | None, label_texts: LabelTextsOf | None = None
) -> dict:
    """The update a subscriber whose last applied seq is `since` receives.

    semanticxr: the objects changed since `since`, coalesced, at client resolution.
    baseline: the whole confirmed map at full resolution, every time (the organisation's
    `whole_map_downstream`; docs/architecture.md "Two system organisations").
    With the v1 extension "device_pose": the newest mapped keyframe's pose, so viewers can
    show where the device is. With `label_texts`, each upsert carries its label's texts
    (the label-texts extension: the match rule's input, docs/protocol.md).
    """
    if engine.organisation.whole_map_downstream:
        message = _delta(engine.delta_since(None), engine.objects, None, label_texts)
    else:
        max_points = engine.knobs.max_object_points_client
        message = _delta(engine.delta_since(since), engine.objects, max_points, label_texts)
    message.device_pose = engine.last_pose
    if not message.full and since is not None:
        message.changes = [
            ChangeEntry(c.id, c.kind, c.t, c.label, c.from_xyz, c.to_xyz)
            for c in engine.recent_changes
            if c.seq > since
        ][-MAX_CHANGES_PER_DELTA:]
    return message.pack()
