"""The two system organisations of the mapping engine (docs/architecture.md).

One algorithm, two organisations, one small class each, chosen once per map
(`organisation_for`):

- `semanticxr` (`SemanticXROrganisation`): per-object work batched across the objects of a
  frame (one lifting pass for all detections, one similarity matrix for association),
  per-object geometry capped at `max_object_points_server`, and the depth co-design:
  detections too small to map well at the uploaded depth resolution
  (`min_mapping_bbox_area`) are deferred until seen larger, or lifted from a full-resolution
  depth patch.
- `baseline` (`BaselineOrganisation`): frame-level, objects one at a time (a full-image mask
  and lift per detection, a pair-by-pair association loop), geometry at sensor resolution
  and uncapped, every detection integrated as it comes (the paper's ConceptGraphs-style
  baseline).

Both call the same geometry, similarity, denoising and merge functions, so they differ in
how the work is organised and scheduled and how much geometry is kept, never in how a
detection and an object are compared or fused.
"""

from __future__ import annotations

import abc
import math
from dataclasses import dataclass

import numpy as np

from app.config import MODES, Knobs, Mode
from app.mapping import geometry as geo
from app.mapping.object import MapObject
from app.mapping.stats import IntegrationStats
from app.perception.base import Detection, FrameDetections
from app.protocol import DepthPatch, FrameInput

BASELINE_RESOLUTION_M = 0.01
"""The baseline keeps geometry at sensor resolution: de-duplicated only at 1 cm, finer than
a depth pixel at mapping range, so repeated views do not stack identical points."""


def _patch_covering(
    patches: list[DepthPatch], box_px: tuple[int, int, int, int]
) -> DepthPatch | None:
    """The first depth patch whose box holds all of `box_px` (x0, y0, x1, y1), or None."""
    x0, y0, x1, y1 = box_px
    for patch in patches:
        px0, py0, px1, py1 = patch.box_px
        if px0 <= x0 and py0 <= y0 and x1 <= px1 and y1 <= py1:
            return patch
    return None


@dataclass
class Observation:
    """A lifted detection, ready to associate. points: float32 [N, 3] (de-duplicated)."""

    detection: Detection
    points: np.ndarray
    embedding: np.ndarray
    bbox: np.ndarray


def match_radius_m(obj: MapObject, knobs: Knobs) -> float:
    """One voxel, or the object's own sampling once a cap has coarsened it (a new view of
    a capped surface is then still found; the semantic floor keeps small things lying on
    it apart)."""
    return max(knobs.voxel_size_m, obj.resolution_m)


def combined_score(spatial, semantic, knobs: Knobs):
    """ConceptGraphs' match score (scalars or arrays): spatial + semantic, or -inf where
    the observation does not touch the object or the two disagree semantically."""
    ok = (semantic >= knobs.association_min_semantic) & (spatial > 0)
    return np.where(ok, spatial + semantic, -np.inf)


def similarity(obs: Observation, obj: MapObject, semantic: float, knobs: Knobs) -> float:
    """Spatial + semantic similarity of one observation and one object (ConceptGraphs).

    Spatial: the fraction of the observation's points within one voxel of the object's
    points, the voxel being the object's own sampling (coarser once capped).
    """
    if semantic < knobs.association_min_semantic:
        return -math.inf
    spatial = geo.overlap_fraction(obs.points, obj.tree, match_radius_m(obj, knobs))
    return float(combined_score(spatial, semantic, knobs))


class Organisation(abc.ABC):
    """How the engine organises, schedules and keeps its per-keyframe work: lifting,
    association, the geometry kept per object and the denoising schedule."""

    mode: Mode
    whole_map_downstream: bool
    """True: every update carries the whole confirmed map at full resolution (the baseline);
    False: the objects changed since the subscriber's seq, at client resolution."""

    @abc.abstractmethod
    def lift(
        self,
        frame: FrameInput,
        detections: FrameDetections,
        kept: list[Detection],
        knobs: Knobs,
        stats: IntegrationStats,
    ) -> tuple[list[Detection], list[np.ndarray]]:
        """The detections `kept` (not skipped) that map now, and the world points float32
        [N, 3] each lifts to (not yet de-duplicated)."""

    @abc.abstractmethod
    def associate(
        self, observations: list[Observation], objects: dict[int, MapObject], knobs: Knobs
    ) -> list[int | None]:
        """Object id per observation (None = new object)."""

    @abc.abstractmethod
    def resolution_m(self, knobs: Knobs) -> float:
        """Voxel at which object geometry is kept."""

    def cap(
        self, points: np.ndarray, knobs: Knobs, start_m: float | None = None
    ) -> tuple[np.ndarray, float]:
        """The object's geometry after a merge and its spacing in metres.

        start_m: the merged objects' current spacing (the cap never refines it)."""
        capped, spacing_m, _ = self.cap_supported(points, None, knobs, start_m)
        return capped, spacing_m

    @abc.abstractmethod
    def cap_supported(
        self,
        points: np.ndarray,
        support: np.ndarray | None,
        knobs: Knobs,
        start_m: float | None = None,
    ) -> tuple[np.ndarray, float, np.ndarray | None]:
        """`cap` carrying each point's support (float [N], the views it stands for; None:
        unknown): (points, spacing in metres, their support or None)."""

    @abc.abstractmethod
    def denoise_due(self, changed: set[int], keyframes: int, interval: int) -> list[int]:
        """The objects among `changed` (since last denoised) whose outliers keyframe number
        `keyframes` removes, in id order; `interval`: the clean-up interval in keyframes."""


class SemanticXROrganisation(Organisation):
    """Batched per keyframe, capped geometry, small detections deferred or lifted from a
    full-resolution depth patch."""

    mode: Mode = "semanticxr"
    whole_map_downstream: bool = False

    def lift(self, frame, detections, kept, knobs, stats):
        """semanticxr lifts a detection from the frame's full-resolution depth patch over
        its box when it is too small to map at the downsampled depth: its box is under
        `min_mapping_bbox_area` (deferred without a patch), or the downsampled depth lifts
        it to fewer than `min_detection_points` (a thin or partly visible thing: a picture
        frame at the image border)."""
        mapped: list[Detection] = []
        patch_of: dict[int, DepthPatch] = {}
        """Detections under the deferral area and the patch each is lifted from."""
        for det in kept:
            if det.bbox_area_px < knobs.min_mapping_bbox_area:
                patch = _patch_covering(frame.depth_patches, det.bbox_px)
                if patch is None:
                    stats.deferred += 1  # too small to map well at this depth resolution
                else:
                    patch_of[det.instance_id] = patch
                    mapped.append(det)
            else:
                mapped.append(det)
        if not mapped:
            return [], []
        pose = np.asarray(frame.pose, np.float64)
        args = (frame.depth_m, frame.intrinsics, pose, knobs.max_depth_m)
        ids = [d.instance_id for d in mapped if d.instance_id not in patch_of]
        lifted = geo.lift_instances_batched(detections.instance_image, ids, *args)
        for det in mapped:
            if len(lifted.get(det.instance_id, ())) < knobs.min_detection_points:
                patch = patch_of.get(det.instance_id) or _patch_covering(
                    frame.depth_patches, det.bbox_px
                )
                if patch is not None:
                    lifted[det.instance_id] = geo.lift_in_patch(
                        detections.instance_image,
                        det.instance_id,
                        patch.box_px,
                        patch.depth_m,
                        frame.intrinsics,
                        pose,
                        knobs.max_depth_m,
                    )
        return mapped, [lifted[d.instance_id] for d in mapped]

    def associate(self, observations, objects, knobs):
        """All observations at once: one box test and one semantic matrix for every pair,
        then one tree query per candidate object for all the observations that may match
        it."""
        if not observations or not objects:
            return [None] * len(observations)
        candidates_of = list(objects.values())
        obs_boxes = np.stack([o.bbox for o in observations])
        obj_boxes = np.stack([o.bbox for o in candidates_of])
        semantic = (
            np.stack([o.embedding for o in observations])
            @ np.stack([o.embedding for o in candidates_of]).T
        )
        candidates = geo.bbox_intersects_matrix(obs_boxes, obj_boxes, knobs.voxel_size_m)
        candidates &= semantic >= knobs.association_min_semantic
        scores = np.full(semantic.shape, -np.inf)
        for j in np.flatnonzero(candidates.any(axis=0)):
            rows = np.flatnonzero(candidates[:, j])
            spatial = geo.overlap_fractions(
                [observations[i].points for i in rows],
                candidates_of[j].tree,
                match_radius_m(candidates_of[j], knobs),
                candidates_of[j].bbox,
            )
            scores[rows, j] = combined_score(spatial, semantic[rows, j], knobs)
        matches: list[int | None] = []
        for row in scores:
            j = len(row) - 1 - int(np.argmax(row[::-1]))  # ties: the last, as pair by pair
            matches.append(candidates_of[j].id if row[j] >= knobs.association_threshold else None)
        return matches

    def resolution_m(self, knobs):
        return knobs.voxel_size_m

    def cap_supported(self, points, support, knobs, start_m=None):
        return geo.cap_points_supported(
            points,
            support,
            knobs.max_object_points_server,
            self.resolution_m(knobs),
            start_m,
            knobs.max_object_spacing_m,
        )

    def denoise_due(self, changed, keyframes, interval):
        """Spread over keyframes (denoising is the costly part of the clean-up): an object
        changed since it was last denoised is due on the keyframes where `keyframes %
        interval` equals `id % interval`, so each is denoised within `interval` keyframes of
        changing and each keyframe carries about 1/interval of the changed objects, never
        the whole map."""
        slot = keyframes % interval
        return sorted(oid for oid in changed if oid % interval == slot)


class BaselineOrganisation(Organisation):
    """Objects one at a time, geometry at sensor resolution and uncapped, every detection
    integrated as it comes."""

    mode: Mode = "baseline"
    whole_map_downstream: bool = True

    def lift(self, frame, detections, kept, knobs, stats):
        """A full-image mask and lift per detection; a small one that the edge test would
        leave under `min_detection_points` is lifted whole (this organisation has no depth
        patch to fall back on)."""
        pose = np.asarray(frame.pose, np.float64)
        args = (frame.depth_m, frame.intrinsics, pose, knobs.max_depth_m)
        lifted = []
        for d in kept:
            points = geo.lift_detection(detections.mask(d), *args)
            if len(points) < knobs.min_detection_points:
                points = geo.lift_detection(detections.mask(d), *args, edge_test=False)
            lifted.append(points)
        return kept, lifted

    def associate(self, observations, objects, knobs):
        """Pair by pair."""
        matches: list[int | None] = []
        margin = knobs.voxel_size_m
        for obs in observations:
            best, best_score = None, knobs.association_threshold
            for obj in objects.values():
                if not geo.bbox_intersects_matrix(obs.bbox[None], obj.bbox[None], margin)[0, 0]:
                    continue
                score = similarity(obs, obj, float(obs.embedding @ obj.embedding), knobs)
                if score >= best_score:
                    best, best_score = obj.id, score
            matches.append(best)
        return matches

    def resolution_m(self, knobs):
        return BASELINE_RESOLUTION_M

    def cap_supported(self, points, support, knobs, start_m=None):
        return geo.cap_points_supported(points, support, 1 << 62, self.resolution_m(knobs), start_m)

    def denoise_due(self, changed, keyframes, interval):
        """The per-scene organisation: every changed object every `interval` keyframes."""
        return sorted(changed) if keyframes % interval == 0 else []


ORGANISATIONS: dict[str, type[Organisation]] = {
    "semanticxr": SemanticXROrganisation,
    "baseline": BaselineOrganisation,
}
"""Mode -> its organisation (the modes of `app.config.MODES`)."""


def organisation_for(mode: str) -> Organisation:
    """The organisation of `mode`; ValueError for a mode that is not one of MODES."""
    if mode not in MODES or mode not in ORGANISATIONS:
        raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
    return ORGANISATIONS[mode]()
