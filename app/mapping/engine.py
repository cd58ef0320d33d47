"""The mapping engine: per-frame detections -> a persistent, versioned map of objects.

`MappingEngine` orchestrates one keyframe: validate, perceive (the perception backend it is
given), lift and associate (its organisation, `app.mapping.organisation`: `semanticxr` or
`baseline`), merge and clean up, detect changes (`app.mapping.changes`), count sightings
towards confirmation (`app.mapping.sightings`), confirm and publish to the delta log.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from dataclasses import dataclass

import numpy as np

from app.config import Knobs, Mode
from app.mapping import geometry as geo
from app.mapping import validation
from app.mapping.changes import ChangeDetector
from app.mapping.deltas import Delta, DeltaLog
from app.mapping.object import Change, MapObject
from app.mapping.organisation import Observation, Organisation, organisation_for
from app.mapping.sightings import Sightings
from app.mapping.stats import IntegrationStats
from app.perception import DEFAULT_BACKEND, BackendOptions, make_backend
from app.perception.base import (
    Detection,
    FrameDetections,
    PerceptionBackend,
)
from app.protocol import FrameInput
from app.semantics import TextEncoder

log = logging.getLogger(__name__)

MERGE_OVERLAP = 0.7
"""Clean-up merges two objects when this fraction of the smaller one lies on the larger..."""
MERGE_SEMANTIC = 0.8
"""...and their embeddings agree at least this much (ConceptGraphs' defaults)."""
SAME_SPACE_BOX_IOU = 0.5
"""Two objects whose boxes overlap this much are also compared whatever their labels say..."""
SAME_SPACE_OVERLAP = 0.8
"""...and merged as two readings of one thing when this fraction of each lies on the other
(a sofa read as a loveseat in some views: the map said "the sofa, on the loveseat"). A
blanket on a bed stays apart: most of the bed does not lie on the blanket."""
FRAGMENT_REACH_VOXELS = 2
"""A piece of a thing: an object alike another (MERGE_SEMANTIC) that lies within this many
voxels of the other's points..."""
FRAGMENT_ON = 0.8
"""...for this fraction of its points..."""
FRAGMENT_GROWTH = 1.25
"""...and that widens the other's box (both grown by a voxel) at most this many times in
volume, is a piece of it: the part of a sofa or a fridge a view showed alone, not found on
the rest, whose surface it continues more than it overlaps. A like thing beside it (the next
book on a shelf, a mug by a mug, a book lying on a book) widens the box by its own size."""
OUTLIER_EPS_M = 0.1
"""DBSCAN radius for outlier removal on changed objects."""
RECENT_CHANGES = 256
"""Changes kept in memory for deltas (older ones are read from the store: GET .../changes)."""


def _denoise(obj: MapObject, settling: bool = False) -> bool:
    """Clean one object's geometry; returns whether its points changed.

    Always: outliers dropped (`geo.outlier_free`; given the support, a smaller part many
    views saw is kept). When `settling` (its stream has closed),
    first the points few of its views agree on are dropped where the support is known
    (against their neighbours', `geo.locally_supported`, and the whole object's,
    `geo.well_supported`), and last what is left is moved onto its local surface
    (`geo.onto_local_surface`, each point weighted by its support where known). During the
    walk both would cost F-mIoU: a part few views have shown yet is still gathering them,
    and rims and edges would be pulled in."""
    points, support = obj.points, obj.support
    if support is not None and settling:
        agreed = geo.locally_supported(points, support) & geo.well_supported(support)
        if not agreed.all():
            points, support = points[agreed], support[agreed]
    kept = geo.outlier_free(points, OUTLIER_EPS_M, support=support)
    if not kept.all():
        points, support = points[kept], None if support is None else support[kept]
    if settling:
        points = geo.onto_local_surface(points, support=support)
    if len(points) == len(obj.points) and np.abs(points - obj.points).max(initial=0) < 1e-3:
        return False  # under a millimetre: a clean object stays as it is
    obj.set_points(points, obj.resolution_m, support)
    return True


def _joined_support(obj: MapObject, added: np.ndarray) -> np.ndarray | None:
    """The support of obj's points followed by points of support `added` [M] (None while
    obj's own is unknown)."""
    return None if obj.support is None else np.concatenate([obj.support, added])


@dataclass
class QueryHit:
    object: MapObject
    score: float


def limit_numpy_threads() -> None:
    """Numpy's BLAS to one thread, process-wide (torch's own threads are left alone).

    The engine multiplies small matrices (tens of objects by 384 dimensions); OpenBLAS's
    threads spin between such products, which cost 40 % of the mapping CPU on 2 cores (a
    400-frame walk at 10.1 ms CPU a frame, 6.0 with one thread). A server's parallelism is
    its worker threads; an eval's, its organisations mapped one after the other."""
    from threadpoolctl import ThreadpoolController

    ThreadpoolController().select(internal_api="openblas").limit(limits=1)


def make_perception(
    name: str = DEFAULT_BACKEND, mode: Mode = "semanticxr", options: BackendOptions | None = None
) -> PerceptionBackend:
    """The perception backend called `name` (`app.perception.BACKENDS`), as organisation
    `mode` uses it: what a caller passes to `MappingEngine`. A server loads each backend
    once and passes every session its `for_mode` view instead."""
    return make_backend(name, options).for_mode(mode)


class MappingEngine:
    """Fuses frames into a map of objects. Not thread-safe: one frame at a time per map."""

    def __init__(
        self,
        encoder: TextEncoder,
        knobs: Knobs | None = None,
        mode: Mode = "semanticxr",
        *,
        backend: PerceptionBackend,
        max_objects: int | None = None,
    ):
        """backend: the perception backend, as organisation `mode` uses it (the caller builds
        it, `make_perception`).

        max_objects: most objects (candidates and confirmed) the map holds; at the cap a
        keyframe's observations that match an object still map, new ones are not created
        (refusing whole keyframes instead would also stop the pruning of transients that
        frees room, so a full map could never change again). None: no cap."""
        self.organisation: Organisation = organisation_for(mode)
        """How the work is organised: lifting, association, geometry kept, denoising."""
        self.encoder = encoder
        self.knobs = knobs or Knobs()
        self.mode = mode
        self.backend = backend
        """The perception backend that detects a keyframe's objects (`perceive`)."""
        self.objects: dict[int, MapObject] = {}
        self.log = DeltaLog()
        self.keyframes = 0
        self.last_pose: np.ndarray | None = None
        """Camera-to-world [4, 4] of the newest mapped keyframe (where the device is)."""
        self.last_t: float | None = None
        """Device-clock time (frame `t`) of the newest mapped keyframe: what "ago" counts from."""
        self.recent_changes: deque[Change] = deque(maxlen=RECENT_CHANGES)
        """The newest changes, with the seq that published them (for deltas)."""
        self.changes = ChangeDetector(self)
        """Suspicion, removals, moves and appearances (`app.mapping.changes`)."""
        self.next_object_id = 1
        self.max_objects = max_objects
        self._at_cap = False
        self._changed_since_cleanup: set[int] = set()
        """Objects changed since they were last denoised."""
        self._changed_since_merge_check: set[int] = set()
        """Objects changed since they were last compared with their neighbours for a merge."""
        self._changed_since_settle: set[int] = set()
        """Objects changed since the map last settled (`settle`)."""
        self.sightings = Sightings()
        """What the frames said about the candidates (keyframes and sightings alike)."""
        self._confirmed_matrix: tuple[list[MapObject], np.ndarray] | None = None

    def restore(
        self,
        objects: list[MapObject],
        log: DeltaLog,
        keyframes: int,
        next_object_id: int,
        last_t: float | None = None,
        recent_changes: list[Change] | None = None,
    ) -> None:
        """Resume from persisted state (confirmed objects and the delta log, the newest
        keyframe's time and the newest changes)."""
        self.objects = {o.id: o for o in objects}
        self.last_t = last_t
        self.changes.clear()
        self.recent_changes.clear()
        self.recent_changes.extend(recent_changes or [])
        self.log = log
        self.keyframes = keyframes
        self.next_object_id = max([next_object_id, *(o.id + 1 for o in objects)])
        self._changed_since_cleanup = set(self.objects)  # cleaned again once
        self._changed_since_merge_check = set(self.objects)
        self._changed_since_settle = set(self.objects)
        self.sightings.clear()
        self._confirmed_matrix = None

    # ------------------------------------------------------------------ validation
    def validate_frame(self, frame: FrameInput) -> FrameDetections | None:
        """Every check the engine makes on a frame, run once per frame (keyframe or not):
        `app.mapping.validation.validate_frame`. Returns the detections the device sent,
        indexed (None when the frame carries none): what a keyframe's perception gets as
        `sent`."""
        return validation.validate_frame(frame)

    def validate_sighting(self, frame: FrameInput) -> FrameDetections:
        """The checks of `validate_frame` for a sighting, which must carry detections:
        `app.mapping.validation.validate_sighting`. Returns the detections for `sight`."""
        return validation.validate_sighting(frame)

    # ------------------------------------------------------------------ integration
    def integrate(self, frame: FrameInput) -> IntegrationStats:
        """Validate, perceive and map one keyframe, for in-process callers (the evaluation
        driver, tests). Raises InputError (map unchanged) on bad input."""
        t0 = time.perf_counter()
        detections = self.perceive(frame, self.validate_frame(frame))
        perception_ms = (time.perf_counter() - t0) * 1e3
        stats = self.map_keyframe(frame, detections)
        stats.timings_ms = {
            "perception": perception_ms,
            **stats.timings_ms,
            "total": perception_ms + stats.timings_ms["total"],
        }
        return stats

    def perceive(self, frame: FrameInput, sent: FrameDetections | None) -> FrameDetections:
        """The keyframe's detections from the session's backend (keyframes only).

        frame: validated by `validate_frame`, which returned `sent`."""
        return self.backend.detect(frame, sent)

    def map_keyframe(self, frame: FrameInput, detections: FrameDetections) -> IntegrationStats:
        """Map one keyframe validated by `validate_frame`, with its perceived detections.

        timings_ms: lift, associate, merge, publish (the delta log commit) and their total.
        """
        t1 = time.perf_counter()
        self.keyframes += 1
        self.last_pose = np.asarray(frame.pose, np.float64)
        self.last_t = float(frame.t)
        stats = IntegrationStats(seq=self.log.seq, keyframe=self.keyframes)
        stats.detections = len(detections.detections)
        observations = self._observe(frame, detections, stats)
        t2 = time.perf_counter()

        matches = self.organisation.associate(observations, self.objects, self.knobs)
        t3 = time.perf_counter()

        touched = self._apply(observations, matches, stats)
        for oid in touched:
            if not self.objects[oid].confirmed:
                self.sightings.observed(oid, int(frame.seq))
        removed: set[int] = set()
        view = None
        if self.knobs.negative_evidence:
            view = self.changes.evidence_view(frame, detections)
            removed |= self.changes.gather_evidence(view, touched, stats)
        due = self._denoise_due()
        if due or self.keyframes % self.knobs.cleanup_interval == 0:
            merged_away = self._cleanup(touched, due)
            stats.retracted_added.extend(sorted(merged_away))
            removed |= merged_away
            stats.cleanup = True
        t4 = time.perf_counter()

        moved = {c.id for c in stats.changes if c.kind == "moved"}  # found from the old side
        sighted = self.sightings.take_sighted()
        published = self._confirm((touched | sighted | moved) - removed, stats)
        removed |= set(stats.dropped_ids)
        removed -= set(stats.unremoved_ids)
        published -= removed
        for oid in published:
            self.objects[oid].refresh_stay()
        if view is not None:
            self.changes.remember(view)
        stats.removed = len(removed)
        stats.seq = self.log.commit(published, removed)
        stats.published_ids, stats.removed_ids = sorted(published), sorted(removed)
        for change in stats.changes:
            change.seq = stats.seq
        self.recent_changes.extend(stats.changes)
        if published or removed:
            self._confirmed_matrix = None
        stats.objects = len(self.objects)
        stats.confirmed = sum(o.confirmed for o in self.objects.values())
        t5 = time.perf_counter()
        stats.timings_ms = {
            "lift": (t2 - t1) * 1e3,
            "associate": (t3 - t2) * 1e3,
            "merge": (t4 - t3) * 1e3,
            "publish": (t5 - t4) * 1e3,
            "total": (t5 - t1) * 1e3,
        }
        return stats

    def _observe(
        self, frame: FrameInput, detections: FrameDetections, stats: IntegrationStats
    ) -> list[Observation]:
        """Filter (skip set, then the organisation's deferral), lift, de-duplicate and embed
        the frame's detections."""
        skip = {label.lower() for label in self.knobs.skip_mapping_set}
        kept: list[Detection] = []
        for det in detections.detections:
            if det.label.lower() in skip:
                stats.skipped += 1
            else:
                kept.append(det)
        if not kept:
            return []
        kept, points = self.organisation.lift(frame, detections, kept, self.knobs, stats)
        if not kept:
            return []

        text_rows = self.encoder.encode_labels([d.label for d in kept])
        resolution_m = self.organisation.resolution_m(self.knobs)
        observations = []
        for det, pts, text_row in zip(kept, points, text_rows, strict=True):
            if len(pts) < self.knobs.min_detection_points:
                stats.too_small += 1
                continue
            pts = geo.voxel_downsample(pts, resolution_m)
            emb = text_row if det.embedding is None else det.embedding
            observations.append(Observation(det, pts, emb.astype(np.float32), geo.bbox_of(pts)))
        return observations

    # ------------------------------------------------------------------ merging
    def _cap(
        self, points: np.ndarray, support: np.ndarray | None, start_m: float | None = None
    ) -> tuple[np.ndarray, float, np.ndarray | None]:
        """The object's geometry after a merge, as the organisation keeps it, with its
        support (`MapObject.support`; None: unknown).

        start_m: the merged objects' current spacing (the cap never refines it)."""
        return self.organisation.cap_supported(points, support, self.knobs, start_m)

    @property
    def _full(self) -> bool:
        return self.max_objects is not None and len(self.objects) >= self.max_objects

    def _apply(
        self, observations: list[Observation], matches: list[int | None], stats: IntegrationStats
    ) -> set[int]:
        """Merge matched observations, create new objects; returns the ids touched."""
        touched: set[int] = set()
        seen_this_frame: set[int] = set()
        for obs, match in zip(observations, matches, strict=True):
            if match is None and self._full:
                stats.over_cap += 1
                continue
            if match is None:
                obj = MapObject(
                    id=self.next_object_id, first_seen=self.keyframes, first_seen_t=self.last_t
                )
                self.next_object_id += 1
                self.objects[obj.id] = obj
                obj.set_points(*self._cap(obs.points, np.ones(len(obs.points), np.float32)))
                stats.created += 1
            else:
                obj = self.objects[match]
                support = _joined_support(obj, np.ones(len(obs.points), np.float32))
                obj.set_points(
                    *self._cap(np.concatenate([obj.points, obs.points]), support, obj.resolution_m)
                )
                stats.matched += 1
            obj.observe_label(obs.detection.label, obs.embedding)
            obj.n_obs += 1
            obj.last_seen = self.keyframes
            obj.last_seen_t = self.last_t
            obj.version += 1
            if obj.id not in seen_this_frame:
                obj.frames_seen += 1
                obj.seen_at(self.keyframes)
                seen_this_frame.add(obj.id)
            touched.add(obj.id)
        self._changed_since_cleanup |= touched
        self._changed_since_merge_check |= touched
        self._changed_since_settle |= touched
        if stats.over_cap and not self._at_cap:
            log.warning(
                "a map reached its cap of %d objects (server setting max_objects, "
                "--max-objects): new objects are not created until transients are pruned",
                self.max_objects,
            )
        self._at_cap = stats.over_cap > 0
        return touched

    def _one_thing(self, a: MapObject, b: MapObject) -> bool:
        """Whether two objects whose boxes overlap (or come within FRAGMENT_REACH_VOXELS of
        each other: then only a piece) are readings of one thing: their embeddings agree
        (MERGE_SEMANTIC) and the smaller lies on the larger (MERGE_OVERLAP) or is a piece of
        it (`_piece_of`), or each lies on the other (SAME_SPACE_OVERLAP), whatever their
        labels."""
        voxel_m = self.knobs.voxel_size_m
        small, large = (a, b) if len(a.points) <= len(b.points) else (b, a)
        alike = float(a.embedding @ b.embedding) >= MERGE_SEMANTIC
        if not geo.bbox_intersects_matrix(a.bbox[None], b.bbox[None], 0.0)[0, 0]:
            return alike and self._piece_of(small, large)  # boxes apart: only a piece
        on_large = geo.overlap_fraction(small.points, large.tree, voxel_m)
        if alike and (on_large >= MERGE_OVERLAP or self._piece_of(small, large)):
            return True
        return (
            on_large >= SAME_SPACE_OVERLAP
            and geo.overlap_fraction(large.points, small.tree, voxel_m) >= SAME_SPACE_OVERLAP
        )

    def _piece_of(self, small: MapObject, large: MapObject) -> bool:
        """Whether `small` is a piece of `large`: it lies close to its points (FRAGMENT_ON
        within FRAGMENT_REACH_VOXELS voxels), hardly widens its box (FRAGMENT_GROWTH), and no
        keyframe saw the two as two detections (`MapObject.keyframes_seen`): the next book on
        a shelf is detected beside its neighbour, a piece of a sofa in a view that saw it
        alone."""
        voxel_m = self.knobs.voxel_size_m
        return (
            not small.keyframes_seen & large.keyframes_seen
            and geo.box_growth(small.bbox, large.bbox, voxel_m) <= FRAGMENT_GROWTH
            and geo.overlap_fraction(small.points, large.tree, FRAGMENT_REACH_VOXELS * voxel_m)
            >= FRAGMENT_ON
        )

    def _merge_objects(self, keep: MapObject, gone: MapObject) -> None:
        keep.set_points(
            *self._cap(
                np.concatenate([keep.points, gone.points]),
                None if gone.support is None else _joined_support(keep, gone.support),
                max(keep.resolution_m, gone.resolution_m),
            )
        )
        keep.absorb_labels(gone)
        keep.n_obs += gone.n_obs
        keep.frames_seen += gone.frames_seen
        keep.seen_at(gone.keyframes_seen)
        if gone.first_seen < keep.first_seen:
            keep.first_seen, keep.first_seen_t = gone.first_seen, gone.first_seen_t
        if gone.last_seen > keep.last_seen:
            keep.last_seen, keep.last_seen_t = gone.last_seen, gone.last_seen_t
        keep.version += 1
        del self.objects[gone.id]
        self._changed_since_settle.add(keep.id)
        self.changes.forget(gone.id)
        self.sightings.merge(keep, gone)

    def take_out(self, oid: int) -> None:
        """Remove object `oid` from the map, its clean-up and its sightings (change
        detection found it gone, moved into another, or a second reading of one)."""
        del self.objects[oid]
        self._changed_since_cleanup.discard(oid)
        self._changed_since_merge_check.discard(oid)
        self._changed_since_settle.discard(oid)
        self.sightings.forget(oid)

    def mark_changed(self, oid: int) -> None:
        """Object `oid` changed: denoised and compared for a merge again."""
        self._changed_since_cleanup.add(oid)
        self._changed_since_merge_check.add(oid)
        self._changed_since_settle.add(oid)

    def _denoise_due(self) -> list[int]:
        """The objects whose outliers this keyframe removes, in id order: the
        organisation's schedule (`Organisation.denoise_due`)."""
        return self.organisation.denoise_due(
            self._changed_since_cleanup, self.keyframes, self.knobs.cleanup_interval
        )

    def _cleanup(self, touched: set[int], due: list[int], merge: bool = False) -> set[int]:
        """Outlier removal on the `due` objects (`_denoise_due`); every `cleanup_interval`
        keyframes (or when `merge`: the stream has closed, `settle`), merge of duplicates and
        pruning of transients. Both organisations run
        this code. The merge compares only the pairs with an object changed since its last
        merge check: two objects that did not change since they were compared cannot have
        started to qualify, so nothing is compared twice for nothing.

        Adds the objects it changes to `touched`; returns the ids of published objects it
        removed (others were never sent downstream).
        """
        removed: set[int] = set()
        self._changed_since_cleanup.difference_update(due)
        for oid in due:
            obj = self.objects.get(oid)
            if obj is None:
                continue
            if _denoise(obj, settling=merge):
                obj.version += 1
                touched.add(oid)
                self._changed_since_merge_check.add(oid)
        if self.keyframes % self.knobs.cleanup_interval and not merge:
            return removed

        changed = self._changed_since_merge_check & self.objects.keys()
        self._changed_since_merge_check = set()
        merged: set[int] = set()
        if changed:
            objects = sorted(self.objects.values(), key=lambda o: o.id)
            boxes = np.stack([o.bbox for o in objects])
            rows = [k for k, o in enumerate(objects) if o.id in changed]
            reach_m = FRAGMENT_REACH_VOXELS * self.knobs.voxel_size_m
            overlapping = geo.bbox_intersects_matrix(boxes[rows], boxes, reach_m)
            embeddings = np.stack([o.embedding for o in objects])
            alike = (embeddings[rows] @ embeddings.T) >= MERGE_SEMANTIC
            same_space = geo.bbox_iou_matrix(boxes[rows], boxes) >= SAME_SPACE_BOX_IOU
            pairs = set()
            for r, j in zip(*np.nonzero(overlapping & (alike | same_space)), strict=True):
                i = rows[r]
                if i != j:
                    pairs.add((min(i, j), max(i, j)))  # a pair of two changed objects once
            for i, j in sorted(pairs):  # id order, as a scan of the upper triangle
                a, b = objects[i], objects[j]
                if a.id not in self.objects or b.id not in self.objects:
                    continue
                if not self._one_thing(a, b):
                    continue
                keep, gone = (a, b) if a.id < b.id else (b, a)  # the older id survives
                self._merge_objects(keep, gone)
                merged.add(keep.id)
                touched.add(keep.id)
                touched.discard(gone.id)
                self._changed_since_cleanup.discard(gone.id)
                if gone.confirmed:
                    removed.add(gone.id)
        # a merged object grew: compared again at the next merge check
        self._changed_since_merge_check |= merged & self.objects.keys()

        for obj in list(self.objects.values()):
            if not obj.confirmed and self.keyframes - obj.last_seen >= self.knobs.transient_max_age:
                del self.objects[obj.id]
                self._changed_since_cleanup.discard(obj.id)
                self._changed_since_merge_check.discard(obj.id)
                self.sightings.forget(obj.id)
                touched.discard(obj.id)
        return removed

    def settle(self) -> IntegrationStats:
        """The map once its stream has closed: the objects changed since the map last settled
        denoised with the whole object's support (`_denoise`), and those changed since their
        last merge check compared for a merge (during the walk clean-up visits an object only
        on its slot of the clean-up interval, so the last keyframes' strays would stay for
        good; an object that did not change since the last settle is not visited again), the
        changes committed to the delta log. Returns what changed (published_ids, removed_ids,
        seq)."""
        stats = IntegrationStats(seq=self.log.seq, keyframe=self.keyframes)
        touched: set[int] = set()
        due = (self._changed_since_settle | self._changed_since_cleanup) & self.objects.keys()
        self._changed_since_settle = set()
        removed = self._cleanup(touched, sorted(due), merge=True)
        stats.retracted_added.extend(sorted(removed))
        published = {oid for oid in touched if oid in self.objects and self.objects[oid].confirmed}
        for oid in published:
            self.objects[oid].refresh_stay()
        stats.seq = self.log.commit(published, removed)
        stats.published_ids, stats.removed_ids = sorted(published), sorted(removed)
        stats.removed = len(removed)
        if published or removed:
            self._confirmed_matrix = None
        stats.objects = len(self.objects)
        stats.confirmed = sum(o.confirmed for o in self.objects.values())
        return stats

    def _qualifies(self, obj: MapObject) -> bool:
        """Seen on `min_observations` keyframes, or by sightings (`Sightings.qualifies`): an
        object in view for a second or two of a sweep (one keyframe and the frames after
        it) is confirmed; a transient and a label confusion are not."""
        if obj.frames_seen >= self.knobs.min_observations:
            return True
        return self.sightings.qualifies(obj.id, self.knobs.min_observations)

    def _confirm(self, touched: set[int], stats: IntegrationStats) -> set[int]:
        """Confirm objects seen often enough; returns the confirmed ids that changed.

        With negative evidence, a candidate that qualifies while a like object is suspect
        (same label, or embeddings `move_min_similarity` alike, and not seen since the
        candidate appeared) is that object at its new place: it merges into it as a move and
        its own id is never published (`ChangeDetector.found_moved`). Otherwise it is
        confirmed, `added` when remembered keyframes had shown its place empty
        (`ChangeDetector.note_confirmed`)."""
        published = set()
        for oid in sorted(touched):
            obj = self.objects.get(oid)
            if obj is None:
                continue
            if not obj.confirmed and self._qualifies(obj):
                self.sightings.forget(oid)
                old = self.changes.found_moved(obj, stats)
                if old is not None:
                    published.add(old.id)
                    continue
                obj.confirmed = True
                if self.knobs.negative_evidence:
                    self.changes.note_confirmed(obj, stats)
            if obj.confirmed:
                published.add(oid)
        return published

    def sight(self, frame: FrameInput, sent: FrameDetections | None) -> list[int]:
        """Count a non-keyframe's detections as sightings of candidate objects
        (`Sightings.sight`); a sighting that shows a suspect object where it was also
        clears its suspicion, and one that sees through the place of a thing a like object
        appeared elsewhere since lets the next keyframe conclude that move
        (`ChangeDetector.sight_moved_places`).

        frame: validated by `validate_sighting` (or `validate_frame`), which returned
        `sent`. A candidate that now qualifies is confirmed, and published, by the next
        keyframe. Returns the sighted ids."""
        if sent is None:
            return []
        if self.changes.suspects:
            self.changes.clear_seen_suspects(frame, sent)
        if self.changes.appeared:
            self.changes.sight_moved_places(frame, sent)
        return self.sightings.sight(self.objects, self.keyframes, frame, sent, self.knobs)

    # ------------------------------------------------------------------ reading the map
    def confirmed_objects(self) -> list[MapObject]:
        """Confirmed objects in id order (what queries and subscribers see)."""
        return [o for _, o in sorted(self.objects.items()) if o.confirmed]

    def delta_since(self, since: int | None) -> Delta:
        return self.log.since(since)

    def query(self, text: str, k: int = 5) -> list[QueryHit]:
        """Top-k confirmed objects by cosine similarity to the text, best first."""
        return self.query_embedding(self.encoder.encode_query(text), k)

    def query_embedding(self, embedding: np.ndarray, k: int = 5) -> list[QueryHit]:
        if self._confirmed_matrix is None:
            objs = self.confirmed_objects()
            matrix = (
                np.stack([o.embedding for o in objs]).astype(np.float32)
                if objs
                else np.zeros((0, self.encoder.dim), np.float32)
            )
            self._confirmed_matrix = (objs, matrix)
        objs, matrix = self._confirmed_matrix
        if not objs or k <= 0:
            return []
        scores = matrix @ embedding.astype(np.float32)
        top = np.argsort(-scores, kind="stable")[:k]
        return [QueryHit(objs[i], float(scores[i])) for i in top]
