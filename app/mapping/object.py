"""MapObject: one object of the map, the unit of memory, execution and communication."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy.spatial import cKDTree

from app.mapping.geometry import EMPTY_POINTS, bbox_of

ObjectState = Literal["present", "removed"]
OBJECT_STATES: tuple[str, ...] = ("present", "removed")
MAX_STAYS = 32
"""Stays kept per object; beyond it the two oldest are merged into one (at most 32
binary stays, <= 2 KB; docs/architecture.md "The store")."""


KEYFRAMES_SEEN_KEPT = 64
"""Keyframe numbers an object keeps in `MapObject.keyframes_seen` (the newest)."""


@dataclass
class Stay:
    """One place an object stayed at, on the device clock (frame `t`, seconds).

    t_from, t_to: the first and last keyframe that observed it there
    centroid:     (x, y, z) metres; bbox: (x0, y0, z0, x1, y1, z1) metres
    """

    t_from: float
    t_to: float
    centroid: tuple[float, float, float]
    bbox: tuple[float, float, float, float, float, float]

    def to_json(self) -> dict:
        return {
            "t_from": self.t_from,
            "t_to": self.t_to,
            "centroid": list(self.centroid),
            "bbox": list(self.bbox),
        }


def merged_stays(older: Stay, newer: Stay) -> Stay:
    """Two consecutive stays as one: the whole time span, the newer place."""
    return Stay(older.t_from, newer.t_to, newer.centroid, newer.bbox)


@dataclass
class Change:
    """Something the map concluded about the world at one keyframe.

    kind:    "added" (appeared where the map had seen nothing), "moved" or "removed"
    t:       frame time of the keyframe at which the map concluded it (device clock)
    from_xyz / to_xyz: the old / new place (centroids), where the kind has one
    seq:     the delta log seq of the commit that published it (0 until committed)
    """

    id: int
    kind: Literal["added", "moved", "removed"]
    t: float
    label: str
    from_xyz: tuple[float, float, float] | None = None
    to_xyz: tuple[float, float, float] | None = None
    seq: int = 0

    def to_json(self) -> dict:
        """The wire / REST form: {"id", "kind", "t", "label", "from"?, "to"?}."""
        out: dict = {"id": self.id, "kind": self.kind, "t": self.t, "label": self.label}
        if self.from_xyz is not None:
            out["from"] = [float(v) for v in self.from_xyz]
        if self.to_xyz is not None:
            out["to"] = [float(v) for v in self.to_xyz]
        return out


@dataclass(eq=False)
class MapObject:
    """A persistent object of the map.

    points:           float32 [N, 3] world metres, capped per the session's mode
    embedding_sum:    float32 [d], observation-weighted sum of unit embeddings (all labels)
    label_embeddings: label -> float32 [d], the sum of that label's detection embeddings
                      (per-label evidence: the object's embedding is its dominant label's)
    label_counts:     label -> times observed (the label histogram)
    frames_seen:      keyframes in which the object was observed
    first_seen_t, last_seen_t: device-clock times (frame `t`) of the first and the newest
                      keyframe that observed it (arrival order; None: from an older store)
    state:            "present" (in the map) or "removed" (kept in the store as history)
    stays:            where it has been, oldest first, at most MAX_STAYS
    """

    id: int
    points: np.ndarray = field(default_factory=lambda: EMPTY_POINTS)
    embedding_sum: np.ndarray | None = None
    label_counts: Counter = field(default_factory=Counter)
    n_obs: int = 0
    frames_seen: int = 0
    first_seen: int = 0
    last_seen: int = 0
    version: int = 0
    confirmed: bool = False
    resolution_m: float = 0.0
    """Spacing the points sample the surface at (grows when the cap coarsens them)."""
    label_embeddings: dict[str, np.ndarray] = field(default_factory=dict)
    first_seen_t: float | None = None
    last_seen_t: float | None = None
    state: ObjectState = "present"
    stays: list[Stay] = field(default_factory=list)
    support: np.ndarray | None = None
    """float32 [N]: how many keyframes' views each point stands for (the views whose points
    fell in its voxel); None where unknown (a stored, imported or re-placed object)."""
    keyframes_seen: set[int] = field(default_factory=set, repr=False)
    """The numbers of the newest keyframes (at most KEYFRAMES_SEEN_KEPT) whose detections mapped
    to it, in this process (not stored): two objects one keyframe saw as two detections are
    two things."""
    _tree: cKDTree | None = field(default=None, repr=False)
    _bbox: np.ndarray | None = field(default=None, repr=False)
    _client_cache: tuple | None = field(default=None, repr=False)
    _unit: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False)
    """(the sum the embedding was normalised from, the embedding): sums are replaced, never
    changed in place, so the same sum object means the same embedding."""

    @property
    def embedding(self) -> np.ndarray:
        """float32 [d] unit vector: the mean embedding of the dominant label's detections
        (per-label evidence), or of all observations where the object has no per-label
        sums (an object from an older store or an import)."""
        vector = self.label_embeddings.get(self.label) if self.label_embeddings else None
        if vector is None:
            vector = self.embedding_sum
        assert vector is not None
        if self._unit is None or self._unit[0] is not vector:
            norm = float(np.linalg.norm(vector))
            self._unit = (vector, vector / max(norm, 1e-12))
        return self._unit[1]

    def observe_label(self, label: str, embedding: np.ndarray) -> None:
        """Count one detection of `label` with its embedding float32 [d]."""
        self.label_counts[label] += 1
        self.embedding_sum = (
            embedding.copy() if self.embedding_sum is None else self.embedding_sum + embedding
        )
        held = self.label_embeddings.get(label)
        self.label_embeddings[label] = embedding.copy() if held is None else held + embedding

    def absorb_labels(self, other: MapObject) -> None:
        """Add another object's label histogram and embedding sums to this one's."""
        self.label_counts.update(other.label_counts)
        if other.embedding_sum is not None:
            self.embedding_sum = (
                other.embedding_sum.copy()
                if self.embedding_sum is None
                else self.embedding_sum + other.embedding_sum
            )
        for label, vector in other.label_embeddings.items():
            held = self.label_embeddings.get(label)
            self.label_embeddings[label] = vector.copy() if held is None else held + vector

    def seen_at(self, keyframes: set[int] | int) -> None:
        """Note keyframe number(s) whose detections mapped to it (the newest
        KEYFRAMES_SEEN_KEPT are kept)."""
        self.keyframes_seen |= {keyframes} if isinstance(keyframes, int) else keyframes
        if len(self.keyframes_seen) > KEYFRAMES_SEEN_KEPT:
            self.keyframes_seen = set(sorted(self.keyframes_seen)[-KEYFRAMES_SEEN_KEPT:])

    def place(self) -> tuple[tuple[float, float, float], tuple[float, ...]]:
        """(centroid, bbox) as plain floats: where the object is now."""
        return (
            tuple(float(v) for v in self.centroid),  # type: ignore[return-value]
            tuple(float(v) for v in self.bbox),
        )

    def refresh_stay(self) -> None:
        """Bring the current stay up to date (place, last seen); start one if none."""
        if self.last_seen_t is None:
            return
        centroid, bbox = self.place()
        if not self.stays:
            t_from = self.first_seen_t if self.first_seen_t is not None else self.last_seen_t
            self.stays.append(Stay(t_from, self.last_seen_t, centroid, bbox))  # type: ignore[arg-type]
            return
        stay = self.stays[-1]
        stay.t_to, stay.centroid, stay.bbox = self.last_seen_t, centroid, bbox  # type: ignore[assignment]

    def start_stay(self, t_from: float) -> None:
        """A new stay from `t_from` at the object's current place (it was re-placed); the
        oldest two merge when over MAX_STAYS."""
        centroid, bbox = self.place()
        t_to = self.last_seen_t if self.last_seen_t is not None else t_from
        self.stays.append(Stay(t_from, t_to, centroid, bbox))  # type: ignore[arg-type]
        if len(self.stays) > MAX_STAYS:
            self.stays[:2] = [merged_stays(self.stays[0], self.stays[1])]

    @property
    def label(self) -> str:
        """The most observed label (ties: the first one seen)."""
        return self.label_counts.most_common(1)[0][0] if self.label_counts else ""

    @property
    def bbox(self) -> np.ndarray:
        """[x0, y0, z0, x1, y1, z1] float64."""
        if self._bbox is None:
            self._bbox = bbox_of(self.points) if len(self.points) else np.zeros(6)
        return self._bbox

    @property
    def centroid(self) -> np.ndarray:
        return self.points.mean(axis=0) if len(self.points) else np.zeros(3)

    @property
    def tree(self) -> cKDTree:
        """KD-tree of the points, rebuilt only after they change.

        Built with sliding-midpoint splits instead of medians: half the build time, the same
        query time on these small clouds, and most trees serve one or two queries before
        the object changes again."""
        if self._tree is None:
            self._tree = cKDTree(self.points, balanced_tree=False)
        return self._tree

    def set_points(
        self, points: np.ndarray, resolution_m: float, support: np.ndarray | None = None
    ) -> None:
        """Replace the geometry; drops the cached tree and box.

        support: float [N] of the new points (`support`); without it, points kept from the
        current geometry keep theirs, and any new point makes the support unknown."""
        if support is None and self.support is not None:
            support = _carried_support(self.points, self.support, points)
        self.points = points
        self.support = None if support is None else np.asarray(support, np.float32)
        self.resolution_m = resolution_m
        self._tree = None
        self._bbox = None


def _carried_support(
    old: np.ndarray, old_support: np.ndarray, points: np.ndarray
) -> np.ndarray | None:
    """The support of `points` [M, 3] that are all rows of `old` [N, 3] (a subset kept,
    such as the points a view did not see through), None if any is not."""
    if len(points) == 0:
        return np.zeros(0, np.float32)
    rows = np.ascontiguousarray(old, np.float32).view(np.dtype((np.void, 12))).ravel()
    wanted = np.ascontiguousarray(points, np.float32).view(np.dtype((np.void, 12))).ravel()
    order = np.argsort(rows)
    at = np.searchsorted(rows[order], wanted).clip(0, len(rows) - 1)
    found = order[at]
    if len(rows) == 0 or not np.array_equal(rows[found], wanted):
        return None
    return old_support[found]


_STAY_DTYPE = np.dtype(
    [("t_from", "<f8"), ("t_to", "<f8"), ("centroid", "<f4", 3), ("bbox", "<f4", 6)]
)
STAY_BYTES = _STAY_DTYPE.itemsize
"""52 bytes a stay: MAX_STAYS of them fit in 2 KB."""


def stays_to_bytes(stays: list[Stay]) -> bytes:
    """The binary form of stays (for stores): little-endian records of STAY_BYTES each."""
    records = np.zeros(len(stays), _STAY_DTYPE)
    for i, stay in enumerate(stays):
        records[i] = (stay.t_from, stay.t_to, stay.centroid, stay.bbox)
    return records.tobytes()


def stays_from_bytes(blob: bytes) -> list[Stay]:
    """The stays of `stays_to_bytes`; ValueError if the bytes are not whole records."""
    if len(blob) % STAY_BYTES:
        raise ValueError(f"{len(blob)} bytes is not a whole number of {STAY_BYTES}-byte stays")
    records = np.frombuffer(blob, _STAY_DTYPE)
    return [
        Stay(
            float(r["t_from"]),
            float(r["t_to"]),
            tuple(float(v) for v in r["centroid"]),  # type: ignore[arg-type]
            tuple(float(v) for v in r["bbox"]),  # type: ignore[arg-type]
        )
        for r in records
    ]
