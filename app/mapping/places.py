"""Where a thing is, in words: "on the dining table", "near the sofa".

A place is described by the nearest large object it rests on or stands near (issue 24, "People
see it"). Pure geometry on the objects' boxes, no I/O: the server describes where a change
happened and where a query's hit is, against the present map, when it answers.

- **on**: an object whose top surface lies just below the point (at most ON_MAX_GAP_M below
  it along up, or ON_SLACK_M above it: a noisy top) with the point inside its footprint (its
  box seen from above, FOOTPRINT_MARGIN_M wider); the largest footprint wins (a mug on a
  book on a table is on the table).
- **near**: else the nearest large object (box volume >= LARGE_VOLUME_M3 or a side >=
  LARGE_SIDE_M) within NEAR_MAX_M of the point (distance to its box).

"Up" is one of the world axes (our synthetic world is Z-up, XR runtimes are Y-up):
`infer_up` takes it from camera poses.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Literal

import numpy as np

from app.mapping.object import MapObject

ON_MAX_GAP_M = 0.35
"""A point at most this far above a surface rests on it (a centroid sits half the thing's
height above what carries it)."""
ON_SLACK_M = 0.05
"""...or at most this far below its top (boxes of noisy points stick out a little)."""
FOOTPRINT_MARGIN_M = 0.05
"""A support's footprint is taken this much wider on every side."""
NEAR_MAX_M = 1.5
"""Farthest a landmark may be from the point (to its box) for "near"."""
LARGE_VOLUME_M3 = 0.03
"""An object is large (a landmark) with a box of at least this volume..."""
LARGE_SIDE_M = 0.5
"""...or a box side at least this long (a table top, a wall, a door)."""

Z_UP = np.array([0.0, 0.0, 1.0])
"""Our synthetic world's up, and the default when no pose is known."""


@dataclass(frozen=True)
class Place:
    """Where a point is: `relation` ("on" | "near") the object `id` labelled `label`."""

    relation: Literal["on", "near"]
    id: int
    label: str


@dataclass(frozen=True)
class Landmarks:
    """The objects a place is described against, as arrays (build once, describe many).

    ids:    int64 [n]
    labels: n labels
    boxes:  float64 [n, 6] (x0, y0, z0, x1, y1, z1) metres, world frame
    """

    ids: np.ndarray
    labels: tuple[str, ...]
    boxes: np.ndarray

    @classmethod
    def of(cls, objects: Iterable[MapObject]) -> Landmarks:
        """The objects' ids, labels and boxes."""
        objects = list(objects)
        boxes = np.stack([o.bbox for o in objects]) if objects else np.zeros((0, 6))
        return cls(
            ids=np.array([o.id for o in objects], np.int64),
            labels=tuple(o.label for o in objects),
            boxes=np.asarray(boxes, np.float64),
        )


def infer_up(pose: np.ndarray) -> np.ndarray:
    """The world axis (±x, ±y or ±z, float64 [3]) nearest to the camera's up.

    pose: camera-to-world float [4, 4] (OpenCV camera: y points down, so up is -y), or
    [n, 4, 4] for the mean of many cameras' up. One camera pitched over 45° (looking at the
    floor) points a horizontal axis: many poses say it better.
    """
    poses = np.asarray(pose, np.float64).reshape(-1, 4, 4)
    return snap_to_axis(-poses[:, :3, 1].mean(axis=0))


def snap_to_axis(vector: np.ndarray) -> np.ndarray:
    """The unit axis (±x, ±y or ±z, float64 [3]) nearest to `vector` (float [3], nonzero)."""
    vector = np.asarray(vector, np.float64)
    axis = int(np.argmax(np.abs(vector)))
    out = np.zeros(3)
    out[axis] = 1.0 if vector[axis] >= 0 else -1.0
    return out


def describe_place(
    xyz: np.ndarray,
    objects: Landmarks | Iterable[MapObject],
    up: np.ndarray = Z_UP,
    exclude: int | None = None,
) -> Place | None:
    """The object the point `xyz` (float [3], metres) rests on, else the large one it is
    near; None when neither. `up`: a world axis (a vector off the axes counts as the nearest
    one); `exclude`: an id never to answer (the thing whose place this is)."""
    landmarks = objects if isinstance(objects, Landmarks) else Landmarks.of(objects)
    if len(landmarks.ids) == 0:
        return None
    axis_up = snap_to_axis(up)
    a = int(np.argmax(np.abs(axis_up)))
    sign = axis_up[a]
    point = np.asarray(xyz, np.float64)
    lo, hi = landmarks.boxes[:, :3], landmarks.boxes[:, 3:]
    others = landmarks.ids != (exclude if exclude is not None else -1)

    # on: the point above the top surface, inside the footprint
    flat = [i for i in range(3) if i != a]
    inside = np.all(
        (lo[:, flat] - FOOTPRINT_MARGIN_M <= point[flat])
        & (point[flat] <= hi[:, flat] + FOOTPRINT_MARGIN_M),
        axis=1,
    )
    top = hi[:, a] if sign > 0 else -lo[:, a]  # along up
    gap = sign * point[a] - top
    supports = others & inside & (gap >= -ON_SLACK_M) & (gap <= ON_MAX_GAP_M)
    if supports.any():
        sides = hi[:, flat] - lo[:, flat]
        footprint = np.where(supports, sides[:, 0] * sides[:, 1], -1.0)
        return _place("on", landmarks, int(np.argmax(footprint)))

    # near: the nearest large object
    sides = hi - lo
    large = (np.prod(sides, axis=1) >= LARGE_VOLUME_M3) | (sides.max(axis=1) >= LARGE_SIDE_M)
    distance = np.linalg.norm(np.maximum(np.maximum(lo - point, point - hi), 0.0), axis=1)
    candidates = others & large & (distance <= NEAR_MAX_M)
    if not candidates.any():
        return None
    return _place("near", landmarks, int(np.argmin(np.where(candidates, distance, np.inf))))


def _place(relation: Literal["on", "near"], landmarks: Landmarks, i: int) -> Place:
    return Place(relation, int(landmarks.ids[i]), landmarks.labels[i])
