"""The living map's evidence: does a keyframe show an object's place without the object?

Pure functions and small records, no I/O (the engine calls them; tests call them directly).

A keyframe gives **evidence of absence** for a confirmed object when its place is in view at
`absence_min_depth_m`..`absence_max_depth_m` and the keyframe sees through it. Each of a
sample of the object's points is projected into the keyframe's depth and is

- *matching* when the sensed depth lies within tau of it (tau = `absence_depth_tolerance_m`
  + `absence_depth_tolerance_rel` x depth), anywhere in its 3 x 3 depth neighbourhood (an
  edge or a thin part at the uploaded resolution is not seen through);
- *seen through* when even the nearest depth of that neighbourhood lies beyond it by more
  than tau;
- *occluded* otherwise: something lies in front, or there is no depth. **Occlusion is never
  evidence**: a thing hidden behind or inside something new stays.

Two kinds of evidence (docs/architecture.md "The living map"):

- `depth`: at least `absence_min_visible` of the in-view points are visible (matching or
  seen through), at least `absence_min_seen_through` of those are seen through, and no
  detection carrying one of the object's labels lies under its matching points (a
  detection where the keyframe sees through the place is of what lies beyond).
- `thin`: things lying on a surface barely change depth (a laptop on a table), so: at least
  THIN_MIN_VISIBLE of the in-view points visible, projected at least `min_absence_area_px`,
  and no detection of any label the object has carried nor any detection covering at least
  THIN_MAX_COVER of its visible points (only detections small enough to be the object:
  the table under a laptop taken away covers its place either way, while a chair covers a
  reading of its back as a stool). Weaker: a removal
  that uses it needs two viewpoints.

An object is removed (`removal_due`) after `removal_min_evidence` keyframes of evidence that
span `removal_min_span_s` of device time or two viewpoints (`removal_min_baseline_m` or
`removal_min_angle_deg` apart); evidence that is mostly thin (fewer than two depth keyframes)
always needs the two viewpoints.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from app.config import Knobs
from app.mapping import geometry as geo

EvidenceKind = Literal["depth", "thin"]

ABSENCE_SAMPLE_POINTS = 100
"""Points of each object projected into a keyframe (a regular subsample)."""
MIN_IN_VIEW = 0.25
"""An object is in view when at least this fraction of its sample projects into the image
within the depth range..."""
MIN_VISIBLE_POINTS = 8
"""...and a keyframe tells about it only with at least this many of them visible."""
THIN_MIN_VISIBLE = 0.8
"""Thin evidence: at least this fraction of the in-view points visible (not occluded)."""
THIN_MAX_COVER = 0.5
"""Thin evidence: no detection of any label may cover this fraction of the in-view points..."""
COVER_MAX_AREA_RATIO = 8.0
"""...counting only detections whose box is at most this many times the object's projected
area: a detection that size may be the object under another label; a larger one is the
surface it lay on (the table under a laptop taken away), which covers its place either way."""
SUSPICION_MAX_KEYFRAMES = 20
"""Evidence older than this many keyframes is forgotten: a removal needs its evidence close
together, not sporadic doubts gathered over a long session."""


@dataclass
class EvidenceView:
    """What one keyframe shows, as the evidence test reads it.

    pose:        float64 [4, 4] camera-to-world (OpenCV camera frame)
    intrinsics:  (fx, fy, cx, cy) of the RGB image; rgb_size (W, H)
    depth_m:     float32 [h, w] metres, 0 = no depth, the RGB size divided by an integer ratio
    label_image: integer [h', w'] detection ids (0 = none), the RGB size divided by an integer
                 ratio; labels: detection id -> its label
    neighbourhood: look at each point's 3 x 3 depth neighbourhood (a keyframe's own depth);
                 False for a coarse remembered view, whose pixels are already block minima
    """

    pose: np.ndarray
    intrinsics: tuple[float, float, float, float]
    rgb_size: tuple[int, int]
    depth_m: np.ndarray
    label_image: np.ndarray
    labels: dict[int, str]
    areas: dict[int, float] | None = None
    """Detection id -> its box area (px at RGB size); None: every detection may cover."""
    t: float = 0.0
    keyframe: int = 0
    neighbourhood: bool = True

    _stacked: np.ndarray | None = field(default=None, init=False, repr=False, compare=False)

    @property
    def position(self) -> np.ndarray:
        return np.asarray(self.pose, np.float64)[:3, 3]

    def depth_neighbourhoods(self) -> np.ndarray:
        """float32 [h * w, k]: each depth pixel's 3 x 3 neighbourhood (edges repeated), the
        centre first; k = 1 without `neighbourhood`. Built once per view: every point read
        from it is one gather, however many objects the view is asked about."""
        if self._stacked is None:
            depth = self.depth_m
            if not self.neighbourhood:
                self._stacked = depth.reshape(-1, 1)
            else:
                padded = np.pad(depth, 1, mode="edge")
                h, w = depth.shape
                shifts = [(0, 0)] + [(r, c) for r in (-1, 0, 1) for c in (-1, 0, 1) if r or c]
                self._stacked = np.stack(
                    [padded[1 + r : 1 + r + h, 1 + c : 1 + c + w] for r, c in shifts], axis=-1
                ).reshape(h * w, len(shifts))
        return self._stacked

    @property
    def direction(self) -> np.ndarray:
        """Unit viewing direction (the camera's +z) in the world."""
        return np.asarray(self.pose, np.float64)[:3, 2]


@dataclass
class Evidence:
    """One keyframe's evidence of an object's absence."""

    kind: EvidenceKind
    t: float
    keyframe: int
    position: np.ndarray
    direction: np.ndarray


@dataclass
class PointVerdicts:
    """How a keyframe sees a set of points. Bool arrays [N]: in view (in the image, within
    the depth range), matching, seen through (subsets of in view); (u, v) pixel of each."""

    in_view: np.ndarray
    matching: np.ndarray
    seen_through: np.ndarray
    u: np.ndarray
    v: np.ndarray


def object_sample(points: np.ndarray, n: int = ABSENCE_SAMPLE_POINTS) -> np.ndarray:
    """A regular subsample of about `n` of an object's points float32 [N, 3]."""
    return points[:: max(1, len(points) // n)]


def classify_points(points: np.ndarray, view: EvidenceView, knobs: Knobs) -> PointVerdicts:
    """Project world points float32 [N, 3] into the view and classify each (module doc)."""
    u, v, z = geo.project_to_pixels(points, view.pose, view.intrinsics)
    width, height = view.rgb_size
    in_view = (
        (z >= knobs.absence_min_depth_m)
        & (z <= knobs.absence_max_depth_m)
        & (u >= 0)
        & (u < width)
        & (v >= 0)
        & (v < height)
    )
    n = len(points)
    matching = np.zeros(n, bool)
    seen_through = np.zeros(n, bool)
    ui = np.where(in_view, u, 0).astype(np.int64)
    vi = np.where(in_view, v, 0).astype(np.int64)
    idx = np.flatnonzero(in_view)
    if len(idx):
        zi = z[idx]
        tau = knobs.absence_depth_tolerance_m + knobs.absence_depth_tolerance_rel * zi
        depth = view.depth_m
        ratio = max(1, round(width / depth.shape[1]))
        rows = np.minimum(vi[idx] // ratio, depth.shape[0] - 1)
        cols = np.minimum(ui[idx] // ratio, depth.shape[1] - 1)
        sensed = view.depth_neighbourhoods()[rows * depth.shape[1] + cols].astype(np.float64)
        valid = sensed > 0
        match = (valid & (np.abs(sensed - zi[:, None]) <= tau[:, None])).any(axis=1)
        nearest = np.where(valid, sensed, np.inf).min(axis=1)
        through = ~match & valid[:, 0] & np.isfinite(nearest) & (nearest - zi > tau)
        matching[idx] = match
        seen_through[idx] = through
    return PointVerdicts(in_view, matching, seen_through, ui, vi)


def absence_evidence(
    sample: np.ndarray, labels: Sequence[str], view: EvidenceView, knobs: Knobs
) -> EvidenceKind | None:
    """The evidence of absence one view gives for one object: "depth", "thin" or None.

    sample: float32 [N, 3] of the object's points (`object_sample`); labels: every label the
    object has carried."""
    return absence_evidence_batched([sample], [labels], view, knobs)[0]


def absence_evidence_batched(
    samples: Sequence[np.ndarray],
    labels: Sequence[Sequence[str]],
    view: EvidenceView,
    knobs: Knobs,
) -> list[EvidenceKind | None]:
    """`absence_evidence` for many objects at once: one projection for all samples, the
    per-object counts by bincount, Python only over the (object, detection) pairs seen."""
    n = len(samples)
    if not n:
        return []
    sizes = np.array([len(s) for s in samples])
    owner = np.repeat(np.arange(n), sizes)
    verdicts = classify_points(np.concatenate(samples).astype(np.float32), view, knobs)
    seen = verdicts.in_view
    in_view = np.bincount(owner[seen], minlength=n)
    matching = np.bincount(owner[verdicts.matching], minlength=n)
    through = np.bincount(owner[verdicts.seen_through], minlength=n)
    visible = matching + through
    out: list[EvidenceKind | None] = [None] * n
    # occlusion is never evidence: only objects in view with enough of it visible go on
    candidates = (sizes > 0) & (in_view >= MIN_IN_VIEW * sizes) & (in_view > 0)
    candidates &= visible >= knobs.absence_min_visible * in_view
    candidates &= visible >= MIN_VISIBLE_POINTS
    if not candidates.any():
        return out
    # projected extent (px) of each candidate's visible points: owner_v is sorted
    keep = (verdicts.matching | verdicts.seen_through) & candidates[owner]
    owner_v, u, v = owner[keep], verdicts.u[keep], verdicts.v[keep]
    starts = np.flatnonzero(np.r_[True, owner_v[1:] != owner_v[:-1]])
    who = owner_v[starts]
    area = np.zeros(n, np.int64)
    area[who] = (np.maximum.reduceat(u, starts) - np.minimum.reduceat(u, starts) + 1) * (
        np.maximum.reduceat(v, starts) - np.minimum.reduceat(v, starts) + 1
    )
    # A detection tells about the surface its pixel senses: where that is the object's own
    # depth (matching points) it may be the object; where the keyframe sees through the
    # object's place, it is whatever lies beyond (another mug behind where this one was).
    at = verdicts.matching & candidates[owner]
    owner_m = owner[at]
    det = geo.pixels_of(view.label_image, verdicts.u[at], verdicts.v[at], view.rgb_size[0])
    det = det.astype(np.int64)
    base = int(det.max(initial=0)) + 1
    pairs, counts = np.unique(owner_m * base + det, return_counts=True)
    pair_owner, pair_det = np.divmod(pairs, base)
    own_label_seen = np.zeros(n, bool)
    largest_cover = np.zeros(n, np.int64)
    areas = view.areas
    for i, d, c in zip(pair_owner.tolist(), pair_det.tolist(), counts.tolist(), strict=True):
        if d == 0:
            continue
        if view.labels.get(d) in labels[i]:
            own_label_seen[i] = True
        if areas is None or areas.get(d, 0.0) <= COVER_MAX_AREA_RATIO * area[i]:
            largest_cover[i] = max(largest_cover[i], c)
    for i in np.flatnonzero(candidates & ~own_label_seen).tolist():
        if through[i] >= knobs.absence_min_seen_through * visible[i]:
            out[i] = "depth"
        elif (
            largest_cover[i] < THIN_MAX_COVER * visible[i]
            and visible[i] >= THIN_MIN_VISIBLE * in_view[i]
            and area[i] >= knobs.min_absence_area_px
        ):
            out[i] = "thin"
    return out


def seen_through_any_batched(
    samples: Sequence[np.ndarray], view: EvidenceView, knobs: Knobs
) -> np.ndarray:
    """bool [len(samples)]: whether the view sees through any point of each sample (one
    projection for all): the objects whose whole clouds are worth classifying."""
    if not samples:
        return np.zeros(0, bool)
    owner = np.repeat(np.arange(len(samples)), [len(s) for s in samples])
    through = classify_points(np.concatenate(samples).astype(np.float32), view, knobs)
    return np.bincount(owner[through.seen_through], minlength=len(samples)) > 0


def viewpoints_apart(evidence: Sequence[Evidence], knobs: Knobs) -> bool:
    """Whether two of the evidence keyframes saw from viewpoints `removal_min_baseline_m` or
    `removal_min_angle_deg` apart."""
    cos_limit = math.cos(math.radians(knobs.removal_min_angle_deg))
    for i, a in enumerate(evidence):
        for b in evidence[i + 1 :]:
            if float(np.linalg.norm(a.position - b.position)) >= knobs.removal_min_baseline_m:
                return True
            if float(a.direction @ b.direction) <= cos_limit:
                return True
    return False


def removal_due(evidence: Sequence[Evidence], knobs: Knobs) -> bool:
    """Whether the evidence gathered removes the object (module doc)."""
    if len(evidence) < knobs.removal_min_evidence:
        return False
    if viewpoints_apart(evidence, knobs):
        return True
    if sum(e.kind == "depth" for e in evidence) < 2:
        return False  # mostly thin evidence: two viewpoints, whatever the time
    times = [e.t for e in evidence]
    return max(times) - min(times) >= knobs.removal_min_span_s


def coarse_view(view: EvidenceView, factor: int) -> EvidenceView:
    """A small copy of a keyframe's view to remember (for telling later whether a place was
    seen empty): depth as block minima (nearest surface, float16), detections sampled at
    block centres. factor: blocks of factor x factor depth pixels."""
    depth = view.depth_m
    h, w = depth.shape[0] // factor, depth.shape[1] // factor
    if h == 0 or w == 0:
        factor, h, w = 1, depth.shape[0], depth.shape[1]
    blocks = depth[: h * factor, : w * factor].reshape(h, factor, w, factor)
    blocks = np.where(blocks > 0, blocks, np.inf).min(axis=(1, 3))
    small_depth = np.where(np.isfinite(blocks), blocks, 0).astype(np.float16)
    width, height = view.rgb_size
    ratio = max(1, round(width / w))
    us = np.arange(w) * ratio + ratio // 2
    vs = np.arange(h) * ratio + ratio // 2
    label_ratio = max(1, round(width / view.label_image.shape[1]))
    ids = view.label_image[
        np.minimum(vs // label_ratio, view.label_image.shape[0] - 1)[:, None],
        np.minimum(us // label_ratio, view.label_image.shape[1] - 1)[None, :],
    ]
    present = [int(d) for d in np.unique(ids) if int(d) in view.labels]
    labels = {d: view.labels[d] for d in present}
    areas = None if view.areas is None else {d: view.areas.get(d, 0.0) for d in present}
    return EvidenceView(
        pose=np.asarray(view.pose, np.float64).copy(),
        intrinsics=view.intrinsics,
        rgb_size=view.rgb_size,
        depth_m=small_depth,
        label_image=ids.astype(np.uint16),
        labels=labels,
        areas=areas,
        t=view.t,
        keyframe=view.keyframe,
        neighbourhood=False,
    )


def place_seen_empty(
    sample: np.ndarray,
    labels: Sequence[str],
    views: Sequence[EvidenceView],
    knobs: Knobs,
) -> bool:
    """Whether remembered views (from before an object was first seen) showed its place
    without it: two views with depth evidence, or three with any evidence from two
    viewpoints apart. What makes a new object `added` rather than found on a first look."""
    evidence = []
    for view in views:
        kind = absence_evidence(sample, labels, view, knobs)
        if kind is not None:
            evidence.append(Evidence(kind, view.t, view.keyframe, view.position, view.direction))
    if sum(e.kind == "depth" for e in evidence) >= 2:
        return True
    return len(evidence) >= 3 and viewpoints_apart(evidence, knobs)


def views_seeing(point: np.ndarray, views: Sequence[EvidenceView], knobs: Knobs) -> list[int]:
    """Indices of the views whose image holds `point` [3] within the depth range (a cheap
    prefilter before `place_seen_empty`)."""
    if not views:
        return []
    poses = np.stack([np.asarray(v.pose, np.float64) for v in views])
    cam = np.einsum("kji,kj->ki", poses[:, :3, :3], point[None, :] - poses[:, :3, 3])
    intr = np.array([v.intrinsics for v in views], np.float64)
    size = np.array([v.rgb_size for v in views], np.float64)
    z = cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = intr[:, 0] * cam[:, 0] / z + intr[:, 2]
        v = intr[:, 1] * cam[:, 1] / z + intr[:, 3]
    ok = (
        (z >= knobs.absence_min_depth_m)
        & (z <= knobs.absence_max_depth_m)
        & (u >= 0)
        & (u < size[:, 0])
        & (v >= 0)
        & (v < size[:, 1])
    )
    return [int(i) for i in np.flatnonzero(ok)]
