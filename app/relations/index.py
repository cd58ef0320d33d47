"""The pairwise relations of a map's objects, kept as objects change (`RelationIndex`).

`sync(objects, up, geometry)` brings the index up to a map's objects by their versions (the
one versioned update: the server on a query, the relations eval after each keyframe);
`update` applies one delta. Pairs are computed when first read.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Protocol, TypeVar

import numpy as np

from app.relations.bodies import Z_UP, Body, snap_to_axis
from app.relations.pairwise import (
    PAIR_SLOTS,
    PAIRWISE_KINDS,
    PairwiseKind,
    pair_degrees,
    within_reach,
)


class Identified(Protocol):
    """What `RelationIndex.sync` reads of a map object itself: its id."""

    @property
    def id(self) -> int: ...


Object = TypeVar("Object", bound=Identified)


@dataclass(frozen=True)
class ObjectGeometry:
    """What a delta carries about one object's shape."""

    label: str
    points: np.ndarray
    """float [N >= 1, 3] metres, world frame (the client-capped points)."""


@dataclass(frozen=True)
class Relation:
    """`subject` stands in `kind` to `anchor` with `degree` in (0, 1]."""

    kind: str
    subject: int
    anchor: int
    degree: float


class RelationIndex:
    """The pairwise relations of a map's objects, kept as objects change.

    Holds each object's `Body` and label, the pairs within reach of each other (boxes within
    near_max_m, or over one another within vertical_max_gap_m: the only pairs with a degree
    above 0), and their degrees of on, in, under, above, below, near and next_to.

    `update` prepares the changed objects' bodies and marks the pairs within reach of them
    stale; a stale pair's degrees are computed when first read (`degree`, `pairs`,
    `relations_of`) or by `settle`. Only pairs touching a changed object are ever recomputed,
    and keyframes come far more often than questions: a pair re-observed for a minute is
    computed once, when asked about. No I/O, no clock: the server and the device's local map
    each keep one.
    """

    def __init__(self, up: np.ndarray = Z_UP):
        self._start(up)

    def _start(self, up: np.ndarray) -> None:
        """Empty, along `up`."""
        self.up = snap_to_axis(up)
        self._bodies: dict[int, Body] = {}
        self._labels: dict[int, str] = {}
        self._reach: dict[int, set[int]] = {}
        """id -> the ids within reach of it (settled or stale)."""
        self._degrees: dict[tuple[int, int], np.ndarray] = {}
        """(smaller id, larger id) -> `pair_degrees` of the settled pairs with any above 0."""
        self._stale: set[tuple[int, int]] = set()
        # the boxes (up frame) as rows for the prefilter; a free row has id -1
        self._row_of: dict[int, int] = {}
        self._row_ids = np.full(16, -1, np.int64)
        self._lo = np.full((16, 3), np.inf)
        self._hi = np.full((16, 3), -np.inf)
        self._free: list[int] = list(range(15, -1, -1))
        self._versions: dict[int, int] = {}
        """id -> the version of the object whose points the index holds (`sync`)."""

    def __len__(self) -> int:
        return len(self._bodies)

    def __contains__(self, object_id: int) -> bool:
        return object_id in self._bodies

    def body(self, object_id: int) -> Body:
        return self._bodies[object_id]

    def label(self, object_id: int) -> str:
        return self._labels[object_id]

    def ids(self) -> list[int]:
        return list(self._bodies)

    @property
    def stale_pairs(self) -> int:
        """Pairs whose degrees will be computed when next read."""
        return len(self._stale)

    def update(
        self, upserts: Mapping[int, ObjectGeometry], removed: Iterable[int] = ()
    ) -> list[int]:
        """Apply one delta: objects created or changed, objects gone. Returns the ids whose
        geometry changed (their pairs are now stale); a new label alone is just replaced."""
        for object_id in removed:
            if object_id in self._bodies:
                self._forget(object_id)
        changed: list[int] = []
        for object_id, geometry in upserts.items():
            self._labels[object_id] = geometry.label
            body = Body(geometry.points, self.up)
            held = self._bodies.get(object_id)
            if held is not None:
                if np.array_equal(held.local, body.local):
                    continue
                self._forget(object_id, keep_label=True)
            self._remember(object_id, body)
            changed.append(object_id)
        for object_id in changed:
            reach = self._reach[object_id]
            for other in self._candidates(self._bodies[object_id]).tolist():
                if other != object_id:
                    reach.add(other)
                    self._reach[other].add(object_id)
                    self._stale.add((object_id, other) if object_id < other else (other, object_id))
        return changed

    def sync(
        self,
        objects: Iterable[tuple[Object, int]],
        up: np.ndarray,
        geometry: Callable[[Object], ObjectGeometry],
    ) -> int:
        """Bring the index up to a map's objects, (object, version) each: the objects whose
        version the index does not hold get their `geometry(object)` (only those: the rest
        cost a look-up), the ids no longer among them are dropped, and a new up axis starts
        the index afresh. Returns how many objects changed or went (their pairs are stale)."""
        objects = list(objects)
        if not np.array_equal(self.up, up):
            self._start(up)
        versions = self._versions
        upserts = {o.id: geometry(o) for o, version in objects if versions.get(o.id) != version}
        present = {o.id for o, _ in objects}
        removed = [i for i in versions if i not in present]
        self.update(upserts, removed)
        for i in removed:
            del versions[i]
        versions.update({o.id: version for o, version in objects if o.id in upserts})
        return len(upserts) + len(removed)

    def settle(self) -> int:
        """Compute every stale pair now; returns how many were."""
        stale = len(self._stale)
        while self._stale:
            self._settle(self._stale.pop())
        return stale

    def _settle(self, key: tuple[int, int]) -> None:
        degrees = pair_degrees(self._bodies[key[0]], self._bodies[key[1]])
        if degrees.any():
            self._degrees[key] = degrees
        else:
            self._degrees.pop(key, None)

    def _row(self, subject: int, anchor: int) -> np.ndarray | None:
        key = (subject, anchor) if subject < anchor else (anchor, subject)
        if key in self._stale:
            self._stale.discard(key)
            self._settle(key)
        return self._degrees.get(key)

    def _candidates(self, body: Body) -> np.ndarray:
        """Ids of the objects whose boxes pass `pair_degrees`'s prefilters with `body`."""
        return self._row_ids[
            within_reach(self._lo, self._hi, body.lo, body.hi) & (self._row_ids >= 0)
        ]

    def _remember(self, object_id: int, body: Body) -> None:
        self._bodies[object_id] = body
        self._reach[object_id] = set()
        if not self._free:
            grown = len(self._row_ids)
            self._row_ids = np.concatenate([self._row_ids, np.full(grown, -1, np.int64)])
            self._lo = np.concatenate([self._lo, np.full((grown, 3), np.inf)])
            self._hi = np.concatenate([self._hi, np.full((grown, 3), -np.inf)])
            self._free = list(range(2 * grown - 1, grown - 1, -1))
        row = self._free.pop()
        self._row_of[object_id] = row
        self._row_ids[row] = object_id
        self._lo[row], self._hi[row] = body.lo, body.hi

    def _forget(self, object_id: int, keep_label: bool = False) -> None:
        del self._bodies[object_id]
        if not keep_label:
            del self._labels[object_id]
        for other in self._reach.pop(object_id):
            self._reach[other].discard(object_id)
            key = (object_id, other) if object_id < other else (other, object_id)
            self._degrees.pop(key, None)
            self._stale.discard(key)
        row = self._row_of.pop(object_id)
        self._row_ids[row] = -1
        self._lo[row], self._hi[row] = np.inf, -np.inf
        self._free.append(row)

    def degree(self, kind: PairwiseKind, subject: int, anchor: int) -> float:
        """How much `subject` stands in `kind` to `anchor` (0 for a pair out of reach or an
        unknown id)."""
        if kind == "below":
            kind, subject, anchor = "above", anchor, subject  # type: ignore[assignment]
        slot = PAIR_SLOTS.get(kind)
        if slot is None:
            raise ValueError(f"unknown relation {kind!r}; one of {PAIRWISE_KINDS}")
        if anchor not in self._reach.get(subject, ()):
            return 0.0
        row = self._row(subject, anchor)
        if row is None:
            return 0.0
        directed = kind not in ("near", "next_to")
        return float(row[slot + 1 if directed and subject > anchor else slot])

    def degrees(self, kind: str, anchor: int, subjects: np.ndarray) -> np.ndarray:
        """float64 [m]: how much each of `subjects` (ids int [m]) stands in `kind` to `anchor`
        (0 out of reach, for the anchor itself and for unknown ids); only the pairs within
        reach of the anchor are computed."""
        if kind != "below" and kind not in PAIR_SLOTS:
            raise ValueError(f"unknown relation {kind!r}; one of {PAIRWISE_KINDS}")
        subjects = np.asarray(subjects, np.int64)
        out = np.zeros(len(subjects))
        reach = self._reach.get(anchor)
        if reach:
            within = np.isin(subjects, np.fromiter(reach, np.int64, len(reach)))
            for i in np.flatnonzero(within).tolist():
                out[i] = self.degree(kind, int(subjects[i]), anchor)  # type: ignore[arg-type]
        return out

    def bodies(self, ids: np.ndarray) -> list[Body]:
        return [self._bodies[int(i)] for i in ids]

    def centroids(self, ids: np.ndarray) -> np.ndarray:
        """float64 [m, 3]: the bodies' centroids, world frame."""
        return np.array([self._bodies[int(i)].centroid for i in ids], np.float64).reshape(-1, 3)

    def boxes(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) float64 [m, 3]: the bodies' boxes in the up frame."""
        rows = [self._row_of[int(i)] for i in ids]
        return self._lo[rows].reshape(-1, 3), self._hi[rows].reshape(-1, 3)

    def relations_of(self, object_id: int) -> list[Relation]:
        """Every relation with a degree above 0 that `object_id` takes part in, as subject or
        as anchor (near and next_to listed once, with `object_id` as subject)."""
        out: list[Relation] = []
        for other in sorted(self._reach.get(object_id, ())):
            if self._row(object_id, other) is None:
                continue
            for kind in PAIRWISE_KINDS:
                pairs = [(object_id, other)]
                if kind not in ("near", "next_to"):
                    pairs.append((other, object_id))
                for subject, anchor in pairs:
                    value = self.degree(kind, subject, anchor)  # type: ignore[arg-type]
                    if value > 0.0:
                        out.append(Relation(kind, subject, anchor, value))
        return out

    def pairs(
        self,
        kind: PairwiseKind,
        subject: int | None = None,
        anchor: int | None = None,
        min_degree: float = 0.0,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(subjects int64 [m], anchors int64 [m], degrees float64 [m]): every pair standing
        in `kind` with degree above min_degree, only those with this subject and / or this
        anchor when given. Symmetric kinds (near, next_to) list each pair both ways. With a
        subject or an anchor only that object's stale pairs are computed; without, all of the
        map's (the first such read after building a large map computes every pair)."""
        if kind not in PAIRWISE_KINDS:
            raise ValueError(f"unknown relation {kind!r}; one of {PAIRWISE_KINDS}")
        if subject is not None:
            others = self._reach.get(subject, set())
            candidates = [(subject, o) for o in others if anchor is None or o == anchor]
        elif anchor is not None:
            candidates = [(o, anchor) for o in self._reach.get(anchor, ())]
        else:
            self.settle()
            candidates = [(x, y) for x, y in self._degrees] + [(y, x) for x, y in self._degrees]
        found = [(s, t, self.degree(kind, s, t)) for s, t in candidates]
        found = [(s, t, d) for s, t, d in found if d > min_degree]
        found.sort()
        return (
            np.array([s for s, _, _ in found], np.int64),
            np.array([t for _, t, _ in found], np.int64),
            np.array([d for _, _, d in found], np.float64),
        )
