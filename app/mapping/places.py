"""Where a thing is, in words: "on the dining table", "near the sofa".

A place is described by the nearest large object it rests on or stands near, as people see it
(docs/protocol.md, "The living map": places in words). Pure geometry on the objects' boxes, no
I/O: the server describes where a change happened and where a query's hit is, against the
present map, when it answers.

- **on**: an object whose top surface lies just below the point (at most ON_MAX_GAP_M below
  it along up, or ON_SLACK_M above it: a noisy top) with the point inside its footprint (its
  box seen from above, FOOTPRINT_MARGIN_M wider); the largest footprint wins (a mug on a
  book on a table is on the table).
- **near**: else the nearest large object (box volume >= LARGE_VOLUME_M3 or a side >=
  LARGE_SIDE_M) within NEAR_MAX_M of the point (distance to its box).

Map objects are described by their points, boxes only narrowing the search: a support must
hold points under the point (within ON_REACH_M of it across, in the gap along up), and
"near" is the distance to its nearest points (the ON_MIN_POINTS-th nearest). A few stray points blow a box up (a table's
box reaching the floor, a floor-level thing's box reaching a table top) and would swallow
everything; they are few where a surface is many. Landmarks given as boxes alone (no
points) are described by their boxes.

"Up" is one of the world axes (our synthetic world is Z-up, XR runtimes are Y-up), named
"+x", "-x", "+y", "-y", "+z" or "-z" (`up_vector`, `up_name`). A session may set it; else
`UpInference` takes it from its keyframes' camera poses once they agree (`infer_up`: at once,
from the poses given).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from app.mapping.object import MapObject
from app.relations.bodies import Z_UP, snap_to_axis

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
ON_REACH_M = 0.25
"""A support holds a point this close across (perpendicular to up) to the thing's point: the
surface right under a thing is hidden by it, the surface round it is seen."""
ON_MIN_POINTS = 3
"""...and at least this many such points (a stray or two is not a surface)."""


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
    labels: n labels (any sequence)
    boxes:  float64 [n, 6] (x0, y0, z0, x1, y1, z1) metres, world frame
    points: n float [k, 3] clouds (world metres) the places are read from, or None: the
            boxes alone
    """

    ids: np.ndarray
    labels: Sequence[str]
    boxes: np.ndarray
    points: Sequence[np.ndarray] | None = None

    @classmethod
    def of(cls, objects: Iterable[MapObject]) -> Landmarks:
        """The objects' ids, labels and boxes (a label is read only when answered: counting
        50k objects' labels would cost more than the rest)."""
        objects = list(objects)
        boxes = np.concatenate([o.bbox for o in objects]) if objects else np.zeros(0)
        return cls(
            ids=np.array([o.id for o in objects], np.int64),
            labels=_LabelsOf(objects),
            boxes=np.asarray(boxes, np.float64).reshape(-1, 6),
            points=[o.points for o in objects],
        )


class _LabelsOf(Sequence[str]):
    """The objects' labels, each read when asked for."""

    def __init__(self, objects: list[MapObject]):
        self._objects = objects

    def __len__(self) -> int:
        return len(self._objects)

    def __getitem__(self, i):  # type: ignore[override]
        if isinstance(i, slice):
            return [o.label for o in self._objects[i]]
        return self._objects[i].label


def camera_up(pose: np.ndarray) -> np.ndarray:
    """The camera's up in the world, float64 [3] (or [n, 3] for [n, 4, 4] poses): -y of the
    OpenCV camera (y points down), the negated second column of the camera-to-world pose."""
    return -np.asarray(pose, np.float64)[..., :3, 1]


def infer_up(pose: np.ndarray) -> np.ndarray:
    """The world axis (±x, ±y or ±z, float64 [3]) nearest to the camera's up.

    pose: camera-to-world float [4, 4] (OpenCV camera: y points down, so up is -y), or
    [n, 4, 4] for the mean of many cameras' up. One camera pitched over 45° (looking at the
    floor) points a horizontal axis: many poses say it better (`UpInference`).
    """
    poses = np.asarray(pose, np.float64).reshape(-1, 4, 4)
    return snap_to_axis(camera_up(poses).mean(axis=0))


_AXIS_LETTERS = "xyz"
DEFAULT_UP = "+z"
"""Up until a session sets one or its poses settle one (our synthetic world is Z-up)."""


def up_vector(name: str) -> np.ndarray:
    """The unit axis (float64 [3]) named "+x", "-x", "+y", "-y", "+z" or "-z"; ValueError
    for any other name."""
    if not (isinstance(name, str) and len(name) == 2 and name[0] in "+-" and name[1] in "xyz"):
        raise ValueError(f"up must be one of +x, -x, +y, -y, +z, -z; got {name!r}")
    axis = np.zeros(3)
    axis[_AXIS_LETTERS.index(name[1])] = 1.0 if name[0] == "+" else -1.0
    return axis


def up_name(vector: np.ndarray) -> str:
    """The name ("+z", ...) of the world axis nearest to `vector` (float [3], nonzero)."""
    axis = snap_to_axis(vector)
    i = int(np.argmax(np.abs(axis)))
    return ("+" if axis[i] > 0 else "-") + _AXIS_LETTERS[i]


UP_STABLE_KEYFRAMES = 8
"""An inferred up is settled once the mean camera up has snapped to the same axis, with
UP_MIN_MEAN_COSINE along it, this many keyframes in a row (~1.3 s of a device at 30 fps
sending every 5th frame as a keyframe): a device that starts by looking at the floor has
not settled it yet."""
UP_MIN_MEAN_COSINE = 0.7
"""...and the mean of the cameras' unit up vectors has at least this component along the
axis: the cameras agree, tilted from it by about 45° or less on average (a mean of cameras
that disagree is short and settles nothing)."""


@dataclass
class UpInference:
    """Which way is up, from the poses of a session's keyframes, one at a time (no I/O).

    A running mean of the cameras' up vectors (`camera_up`, unit vectors in the world
    frame), snapped to the nearest axis; `observe` answers that axis once it is stable
    (UP_STABLE_KEYFRAMES, UP_MIN_MEAN_COSINE), else None, and the same axis ever after:
    settled, it never flips (the server persists it, so a reload does not flip it either).
    A few tilted poses move a mean of many little, so they neither settle an axis nor undo
    a streak on their own (while the mean holds only a few poses, one can reset the
    streak: settling then takes a few keyframes more)."""

    total: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """Sum of the cameras' up vectors seen, float64 [3]."""
    count: int = 0
    """Poses seen."""
    candidate: str | None = None
    """The axis the mean has snapped to, agreeing, over the last `streak` keyframes."""
    streak: int = 0
    settled: str | None = None
    """The stable axis, once the poses have settled one; None until then."""

    def observe(self, pose: np.ndarray) -> str | None:
        """Count one keyframe's camera-to-world pose (float [4, 4], OpenCV camera); the up
        axis ("+y", ...) once stable, else None."""
        up = camera_up(pose)
        norm = float(np.linalg.norm(up))
        if self.settled is not None or not np.isfinite(norm) or norm == 0.0:
            return self.settled
        self.total += up / norm
        self.count += 1
        mean = self.total / self.count
        name = up_name(mean)
        if float(mean @ up_vector(name)) < UP_MIN_MEAN_COSINE:
            self.candidate, self.streak = None, 0
        elif name == self.candidate:
            self.streak += 1
        else:
            self.candidate, self.streak = name, 1
        if self.streak >= UP_STABLE_KEYFRAMES:
            self.settled = self.candidate
        return self.settled


def describe_place(
    xyz: np.ndarray,
    objects: Landmarks | Iterable[MapObject],
    up: np.ndarray = Z_UP,
    exclude: int | None = None,
) -> Place | None:
    """The object the point `xyz` (float [3], metres) rests on, else the large one it is
    near; None when neither. `up`: a world axis (a vector off the axes counts as the nearest
    one); `exclude`: an id never to answer (the thing whose place this is)."""
    excluded = None if exclude is None else [exclude]
    return describe_places(np.asarray(xyz, np.float64)[None], objects, up, excluded)[0]


BATCH_ELEMENTS = 1 << 20
"""Points x landmarks compared at once by `describe_places` (memory stays ~100 MB)."""


def describe_places(
    points: np.ndarray,
    objects: Landmarks | Iterable[MapObject],
    up: np.ndarray = Z_UP,
    exclude: Sequence[int] | None = None,
) -> list[Place | None]:
    """`describe_place` of each point, float [m, 3] metres, at once; `exclude`: m ids (the
    thing whose place each point is), or None."""
    landmarks = objects if isinstance(objects, Landmarks) else Landmarks.of(objects)
    points = np.asarray(points, np.float64).reshape(-1, 3)
    n, m = len(landmarks.ids), len(points)
    if n == 0 or m == 0:
        return [None] * m
    excluded = np.full(m, -1, np.int64) if exclude is None else np.asarray(exclude, np.int64)
    axis_up = snap_to_axis(up)
    a = int(np.argmax(np.abs(axis_up)))
    sign = axis_up[a]
    f0, f1 = (i for i in range(3) if i != a)  # the footprint's axes
    # axis by axis, contiguous: [3, n] (a [c, n, 3] array is several times slower)
    lo = np.ascontiguousarray(landmarks.boxes[:, :3].T)
    hi = np.ascontiguousarray(landmarks.boxes[:, 3:].T)
    sides = hi - lo
    footprint = sides[f0] * sides[f1]
    top = hi[a] if sign > 0 else -lo[a]  # along up
    large = (np.prod(sides, axis=0) >= LARGE_VOLUME_M3) | (sides.max(axis=0) >= LARGE_SIDE_M)

    places: list[Place | None] = []
    step = max(1, BATCH_ELEMENTS // n)
    for start in range(0, m, step):
        p = points[start : start + step].T[:, :, None]  # [3, c, 1] against [3, n]
        others = landmarks.ids != excluded[start : start + step, None]  # [c, n]
        # on: the point above the top surface, inside the footprint; the largest wins
        gap = sign * p[a] - top
        if landmarks.points is None:
            supports = others & (gap >= -ON_SLACK_M) & (gap <= ON_MAX_GAP_M)
        else:  # anywhere from the box's bottom up: its points tell where its top is
            supports = others & (gap >= -ON_SLACK_M - sides[a]) & (gap <= ON_MAX_GAP_M)
        for f in (f0, f1):
            supports &= (lo[f] - FOOTPRINT_MARGIN_M <= p[f]) & (p[f] <= hi[f] + FOOTPRINT_MARGIN_M)
        # near: the nearest large object (distance to its box, 0 inside)
        squared = np.zeros(others.shape)
        for i in range(3):
            outside = np.maximum(np.maximum(lo[i] - p[i], p[i] - hi[i]), 0.0)
            squared += outside * outside
        candidates = others & large & (squared <= NEAR_MAX_M**2)
        if landmarks.points is not None:
            chunk = points[start : start + step]
            _by_points(chunk, landmarks.points, supports, squared, candidates, a, sign)
        support = np.argmax(np.where(supports, footprint, -1.0), axis=1)
        nearest = np.argmin(np.where(candidates, squared, np.inf), axis=1)
        for row in range(len(supports)):
            if supports[row, support[row]]:
                places.append(_place("on", landmarks, int(support[row])))
            elif candidates[row, nearest[row]]:
                places.append(_place("near", landmarks, int(nearest[row])))
            else:
                places.append(None)
    return places


def _by_points(
    points: np.ndarray,
    clouds: Sequence[np.ndarray],
    supports: np.ndarray,
    squared: np.ndarray,
    candidates: np.ndarray,
    a: int,
    sign: float,
) -> None:
    """Narrow the box answers [c, n] of points float64 [c, 3] to what the landmarks' clouds
    say, in place: a support keeps ON_MIN_POINTS points within ON_REACH_M across of the
    point and in its gap along up (axis `a`, `sign`); `squared` becomes the squared
    distance to the ON_MIN_POINTS-th nearest point of each candidate landmark (a farther
    one drops out)."""
    across = [i for i in range(3) if i != a]
    for row, col in zip(*np.nonzero(supports | candidates), strict=True):
        cloud = np.asarray(clouds[col], np.float64)
        if len(cloud) == 0:
            supports[row, col] = candidates[row, col] = False
            continue
        offset = points[row] - cloud
        if supports[row, col]:
            gap = sign * offset[:, a]
            reach = np.hypot(offset[:, across[0]], offset[:, across[1]])
            under = (reach <= ON_REACH_M) & (gap >= -ON_SLACK_M) & (gap <= ON_MAX_GAP_M)
            supports[row, col] = int(under.sum()) >= ON_MIN_POINTS
        if candidates[row, col]:
            distances = np.einsum("ij,ij->i", offset, offset)
            k = min(ON_MIN_POINTS, len(distances)) - 1  # a stray or two is not the thing
            squared[row, col] = float(np.partition(distances, k)[k])
            candidates[row, col] = squared[row, col] <= NEAR_MAX_M**2


def _place(relation: Literal["on", "near"], landmarks: Landmarks, i: int) -> Place:
    return Place(relation, int(landmarks.ids[i]), landmarks.labels[i])
