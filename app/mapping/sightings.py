"""Sightings: a non-keyframe's detections counted towards confirming candidate objects.

A device with the sightings extension sends detections with frames it does not pick as
keyframes (docs/protocol.md); nothing is lifted from them and no geometry changes, but a
candidate seen on enough of the frames it was in view is confirmed by the next keyframe.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from app.config import Knobs
from app.mapping import geometry as geo
from app.mapping.object import MapObject
from app.perception.base import FrameDetections
from app.protocol import FrameInput

SIGHTING_MIN_POINTS = 5
"""A candidate object is sighted on a non-keyframe only if at least this many of its points
are visible there (in the image, in front of the camera, not hidden behind nearer depth)..."""
SIGHTING_COVER = 0.5
"""...and at least this fraction of those fall in one detection carrying one of its labels."""
SIGHTING_AGREEMENT = 0.5
"""A candidate is confirmed by sightings only if it was seen on at least this fraction of
the frames it was in view: a detection with a confused label (the detector calls a window a
door one frame in twenty) builds a candidate that its frames rarely agree with."""
SIGHTING_SAMPLE_POINTS = 200
"""Points of each object projected into a non-keyframe (a regular subsample)."""
SIGHTING_DEPTH_TOLERANCE_M = 0.1
"""A projected point is visible when its depth is within this (plus 5 %) of the sensed depth."""


@dataclass
class Glimpses:
    """What the frames said about one candidate object (frame seqs)."""

    seen: set[int] = field(default_factory=set)
    """Keyframes where it was observed and non-keyframes where it was sighted."""
    missed: set[int] = field(default_factory=set)
    """Non-keyframes where it was in view but no detection of its own sighted it."""

    def update(self, other: Glimpses) -> None:
        self.seen |= other.seen
        self.missed |= other.missed - self.seen


class _SightSamples(NamedTuple):
    """What sightings project between two keyframes."""

    keyframe: int
    """The map's keyframe count they were drawn at."""
    objects: list[MapObject]
    """The objects with points."""
    points: np.ndarray
    """float32 [N, 3]: about SIGHTING_SAMPLE_POINTS of each object's points, concatenated."""
    owner: np.ndarray
    """int [N]: the index in `objects` of each point."""
    sizes: np.ndarray
    """int64 [len(objects)]: each sample's size."""


def _project(
    points: np.ndarray, frame: FrameInput
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """World points float32 [N, 3] into the frame's RGB image: (u, v) int pixel, z metres
    (in front of the camera, inside the image) and the bool [N] mask of those points."""
    u, v, z = geo.project_to_pixels(points, frame.pose, frame.intrinsics)
    width, height = frame.rgb_size
    kept = (z > 1e-3) & (u >= 0) & (u < width) & (v >= 0) & (v < height)
    return u[kept].astype(np.int64), v[kept].astype(np.int64), z[kept], kept


class Sightings:
    """What the frames said about the candidate objects: the keyframes that observed them
    and the non-keyframes that sighted or missed them (in memory: sightings start over after
    a restart)."""

    def __init__(self) -> None:
        self.glimpses: dict[int, Glimpses] = {}
        """Candidate (unconfirmed) object id -> the frames it was seen on, keyframes
        (observations) and non-keyframes (`sight`) alike, and the non-keyframes where it was
        in view but not sighted."""
        self.sighted: set[int] = set()
        """Candidates sighted since the last keyframe: the next keyframe considers them for
        confirmation."""
        self._samples: _SightSamples | None = None
        """What every sighting projects, the same from one keyframe to the next."""

    def clear(self) -> None:
        """Forget everything (a map restored from the store)."""
        self.glimpses.clear()
        self.sighted.clear()
        self._samples = None

    def observed(self, oid: int, seq: int) -> None:
        """Candidate `oid` was observed on keyframe `seq`."""
        self.glimpses.setdefault(oid, Glimpses()).seen.add(seq)

    def forget(self, oid: int) -> Glimpses | None:
        """Drop what was seen of `oid` (confirmed, merged or gone); returns it."""
        return self.glimpses.pop(oid, None)

    def merge(self, keep: MapObject, gone: MapObject) -> None:
        """`gone` merged into `keep`: a candidate `keep` inherits `gone`'s glimpses."""
        gone_seen = self.forget(gone.id)
        if not keep.confirmed and gone_seen is not None:
            self.glimpses.setdefault(keep.id, Glimpses()).update(gone_seen)

    def take_sighted(self) -> set[int]:
        """The candidates sighted since the last keyframe, forgotten as such."""
        sighted, self.sighted = self.sighted, set()
        return sighted

    def qualifies(self, oid: int, min_observations: int) -> bool:
        """Whether candidate `oid` was seen on `min_observations` frames (keyframes and
        non-keyframe sightings) whose seqs span more than `min_observations` frames (first
        and last at least that far apart) and that are at least SIGHTING_AGREEMENT of the
        frames it was in view: a detection that lives for `min_observations` frames or
        fewer (a transient), and one whose label the other frames mostly contradict (a
        label confusion), do not."""
        glimpses = self.glimpses.get(oid)
        if glimpses is None:
            return False
        seqs = glimpses.seen
        return (
            len(seqs) >= min_observations
            and max(seqs) - min(seqs) >= min_observations
            and len(seqs) >= SIGHTING_AGREEMENT * (len(seqs) + len(glimpses.missed))
        )

    def sight(
        self,
        objects_by_id: dict[int, MapObject],
        keyframes: int,
        frame: FrameInput,
        sent: FrameDetections,
        knobs: Knobs,
    ) -> list[int]:
        """Count a non-keyframe's detections as sightings of the map's candidate objects
        (docs/protocol.md, the sightings extension: a detection sent with a non-keyframe may
        count towards confirmation).

        objects_by_id: the map's objects, at its `keyframes` count. frame: validated, with
        its detections `sent` (its instance image and depth may be at the RGB size divided
        by any integer ratio). Every object is projected into the frame (a sample of
        SIGHTING_SAMPLE_POINTS points); a candidate (unconfirmed object) is in view when at
        least SIGHTING_MIN_POINTS of them are visible (in the image, in front of the camera,
        not hidden behind nearer depth). It is sighted when at least SIGHTING_COVER of its
        visible points fall in one detection that is its own: the detection carries one of
        its labels, no confirmed object carrying that label is visible in it (the candidate
        would be a fragment or a duplicate of that object), and no other candidate carrying
        the label has more points in it. A candidate in view but not sighted is missed there
        (`qualifies` weighs sightings against misses).

        Nothing is lifted and no geometry changes. Returns the sighted ids."""
        if not any(not o.confirmed for o in objects_by_id.values()):
            return []
        _, objects, points, owner, sample_sizes = self._samples_to_sight(objects_by_id, keyframes)
        if not objects:
            return []
        u, v, z, kept = _project(points, frame)
        owner = owner[kept]
        width, height = frame.rgb_size
        sensed = geo.pixels_of(frame.depth_m, u, v, width)
        visible = (sensed > 0) & (np.abs(z - sensed) <= SIGHTING_DEPTH_TOLERANCE_M + 0.05 * z)
        owner, u, v = owner[visible], u[visible], v[visible]
        det_ids, column = np.unique(
            geo.pixels_of(sent.instance_image, u, v, width), return_inverse=True
        )
        # counts[i, k]: visible sample points of objects[i] in detection det_ids[k] (0: none)
        counts = np.bincount(
            owner * len(det_ids) + column, minlength=len(objects) * len(det_ids)
        ).reshape(len(objects), len(det_ids))
        n_visible = counts.sum(axis=1)
        in_view = np.flatnonzero(n_visible >= np.minimum(SIGHTING_MIN_POINTS, sample_sizes))

        skip = {label.lower() for label in knobs.skip_mapping_set}
        label_of = {i: label for i, label in sent.labels().items() if label.lower() not in skip}
        labels = [label_of.get(int(d)) for d in det_ids]
        taken: set[int] = set()  # columns a confirmed object carrying their label is seen in
        best_candidate: dict[int, tuple[int, int]] = {}  # column -> (points, object index)
        claim_of: dict[int, int] = {}  # candidate index -> the column it would be sighted by
        for i in in_view:
            obj = objects[i]
            row = counts[i]
            for k in np.flatnonzero(row):
                if labels[k] is None or labels[k] not in obj.label_counts:
                    continue
                if obj.confirmed:
                    if row[k] >= SIGHTING_MIN_POINTS:
                        taken.add(int(k))
                elif (int(row[k]), int(i)) > best_candidate.get(int(k), (0, -1)):
                    best_candidate[int(k)] = (int(row[k]), int(i))
            if not obj.confirmed:
                k = int(np.argmax(row * (det_ids > 0)))
                if det_ids[k] and row[k] >= SIGHTING_COVER * n_visible[i]:
                    claim_of[int(i)] = k
        sighted = []
        seq = int(frame.seq)
        for i in in_view:
            obj = objects[i]
            if obj.confirmed:
                continue
            k = claim_of.get(int(i))
            glimpses = self.glimpses.setdefault(obj.id, Glimpses())
            if k is None or k in taken or best_candidate.get(k, (0, -1))[1] != i:
                glimpses.missed.add(seq)
                continue
            glimpses.seen.add(seq)
            self.sighted.add(obj.id)
            sighted.append(obj.id)
        return sorted(sighted)

    def _samples_to_sight(
        self, objects_by_id: dict[int, MapObject], keyframes: int
    ) -> _SightSamples:
        """The objects' samples, drawn once per keyframe: the geometry only changes when a
        keyframe is mapped."""
        cached = self._samples
        if cached is None or cached.keyframe != keyframes:
            objects = [o for o in objects_by_id.values() if len(o.points)]
            samples = [
                o.points[:: max(1, len(o.points) // SIGHTING_SAMPLE_POINTS)] for o in objects
            ]
            sizes = np.array([len(p) for p in samples], np.int64)
            points = np.concatenate(samples) if samples else np.zeros((0, 3), np.float32)
            owner = np.repeat(np.arange(len(objects)), sizes)
            cached = self._samples = _SightSamples(keyframes, objects, points, owner, sizes)
        return cached
