"""Change detection: what the keyframes say changed in the world (added, moved, removed).

Negative evidence (`app.mapping.living`) makes confirmed objects suspect when a keyframe
shows their place without them, and removes them, or finds them moved, once enough
keyframes agree; a new object is `added` when remembered keyframes had shown its place
empty (docs/architecture.md, the living map).
"""

from __future__ import annotations

from collections import deque
from typing import Protocol

import numpy as np

from app.config import Knobs
from app.mapping import geometry as geo
from app.mapping import living
from app.mapping.object import Change, MapObject
from app.mapping.sightings import SIGHTING_MIN_POINTS
from app.mapping.stats import IntegrationStats
from app.perception.base import FrameDetections
from app.protocol import FrameInput
from app.semantics import TextEncoder

REMEMBERED_VIEWS = 600
"""Keyframes remembered (coarse, ~3 KB each) to tell whether a new object's place was seen
empty before: ten minutes of keyframes at one a second."""
REMEMBERED_VIEW_BLOCK = 4
"""Remembered depth keeps the nearest surface of each 4 x 4 block of the uploaded depth."""
REVIVE_WINDOW_S = 120.0
"""A removed object is still found at a new place (moved, not removed) when a like thing
appears within this much device time of its removal: the mug taken from the table before
the shelf it went to came into view."""
RECENTLY_REMOVED = 256
"""Most removed objects kept in memory for REVIVE_WINDOW_S."""
PLACE_TAKEN_OVERLAP = 0.5
"""A new object is no `added` change when this much of it lies on another confirmed object
that is alike..."""
PLACE_TAKEN_BOX_IOU = 0.15
"""...or whose box it shares this much of (intersection over union)."""
VACATED_INSIDE = 0.5
"""An object leaving with most of its box in a place just vacated is a second reading of the
thing that left (`_second_reading_of_vacated`)."""


class WatchedMap(Protocol):
    """The map change detection watches (the engine): what it reads, and how it takes an
    object out of the present map or marks one changed."""

    objects: dict[int, MapObject]
    keyframes: int
    last_t: float | None
    knobs: Knobs
    encoder: TextEncoder

    def take_out(self, oid: int) -> None:
        """Remove object `oid` from the map and from its clean-up and sightings."""

    def mark_changed(self, oid: int) -> None:
        """Object `oid` changed: denoised and compared for a merge again."""


class ChangeDetector:
    """What the keyframes say changed in the world: suspicion gathered by negative evidence,
    removals, moves, appearances. Its state is in memory (like sightings, it starts over
    after a restart)."""

    def __init__(self, watched: WatchedMap) -> None:
        self.map = watched
        self.suspects: dict[int, list[living.Evidence]] = {}
        """Confirmed object id -> the keyframes that showed its place without it."""
        self.views: deque[living.EvidenceView] = deque(maxlen=REMEMBERED_VIEWS)
        """Coarse copies of recent keyframes, oldest first (for `added`)."""
        self.vacated: deque[tuple[int, np.ndarray]] = deque()
        """(keyframe, box) of the places objects left recently, oldest first."""
        self.recently_removed: dict[int, tuple[int, float, MapObject]] = {}
        """Objects removed within REVIVE_WINDOW_S of the newest keyframe, with the keyframe
        and time of their removal (at most RECENTLY_REMOVED)."""
        self.appeared: set[int] = set()
        """Present objects with an `added` change standing (a move found after a restart
        needs a fresh appearance)."""
        self.sighted_through: dict[int, float] = {}
        """Object id -> t of a sighting since the last keyframe that saw through its place
        while a like object had appeared elsewhere (`sight_moved_places`): evidence for that
        move only, read by the next keyframe."""

    def clear(self) -> None:
        """Forget everything (a map restored from the store)."""
        self.suspects.clear()
        self.views.clear()
        self.appeared.clear()
        self.recently_removed.clear()
        self.vacated.clear()
        self.sighted_through.clear()

    def forget(self, oid: int) -> None:
        """Object `oid` left the map without a change of its own (merged into another)."""
        self.suspects.pop(oid, None)
        self.appeared.discard(oid)
        self.sighted_through.pop(oid, None)

    def remember(self, view: living.EvidenceView) -> None:
        """Keep a coarse copy of a mapped keyframe, to tell later whether a new object's
        place was seen empty before."""
        self.views.append(living.coarse_view(view, REMEMBERED_VIEW_BLOCK))

    def found_moved(self, obj: MapObject, stats: IntegrationStats) -> MapObject | None:
        """A candidate `obj` that just qualified for confirmation is a suspect object, or
        one removed within REVIVE_WINDOW_S, at a new place: that object takes `obj`'s place
        (`_move`, a `moved` change) and is returned; `obj` leaves the map. Else None."""
        old = self._like_object(obj, self._suspected_objects(), obj_is_new=True)
        if old is None:
            old = self._revived(obj, stats)
        if old is not None:
            self._move(old, obj, stats)
        return old

    def note_confirmed(self, obj: MapObject, stats: IntegrationStats) -> None:
        """A new object confirmed: `added` when remembered keyframes had shown its place
        empty (`living.place_seen_empty`) and no other object holds it."""
        # the cheaper test first: most new things are found on a first look
        if self._place_seen_empty(obj) and not self._place_taken(obj):
            self.appeared.add(obj.id)
            centroid, _ = obj.place()
            stats.changes.append(Change(obj.id, "added", self._now, obj.label, to_xyz=centroid))

    @property
    def _now(self) -> float:
        return self.map.last_t if self.map.last_t is not None else 0.0

    def evidence_view(self, frame: FrameInput, detections: FrameDetections) -> living.EvidenceView:
        """The keyframe as the evidence test reads it: its depth and every detection it
        carried (deferred and skipped ones too: a thing detected is not absent)."""
        return living.EvidenceView(
            pose=np.asarray(frame.pose, np.float64),
            intrinsics=tuple(frame.intrinsics),  # type: ignore[arg-type]
            rgb_size=frame.rgb_size,
            depth_m=frame.depth_m,
            label_image=detections.instance_image,
            labels={d.instance_id: d.label for d in detections.detections},
            areas={d.instance_id: float(d.bbox_area_px) for d in detections.detections},
            t=self._now,
            keyframe=self.map.keyframes,
        )

    def gather_evidence(
        self, view: living.EvidenceView, observed: set[int], stats: IntegrationStats
    ) -> set[int]:
        """Negative evidence for one keyframe (docs/architecture.md, "The living map"): an
        observation clears suspicion and drops the points the keyframe sees through (a short
        move does not smear an object over both places); every other confirmed object whose
        place the keyframe shows without it gathers evidence, and is removed, or found
        moved, once `living.removal_due`. Returns the published ids it took out of the present map."""
        for oid in observed:
            self.suspects.pop(oid, None)
            self.sighted_through.pop(oid, None)
        seen = [self.map.objects[i] for i in sorted(observed) if self.map.objects[i].confirmed]
        worth = living.seen_through_any_batched(
            [living.object_sample(o.points) for o in seen], view, self.map.knobs
        )
        for obj in (o for o, w in zip(seen, worth, strict=True) if w):
            through = living.classify_points(obj.points, view, self.map.knobs).seen_through
            if not through.all():
                obj.set_points(obj.points[~through], obj.resolution_m)
        floor = self.map.keyframes - living.SUSPICION_MAX_KEYFRAMES
        for oid in list(self.suspects):
            kept = [e for e in self.suspects[oid] if e.keyframe > floor]
            if kept:
                self.suspects[oid] = kept
            else:
                del self.suspects[oid]
        tested = [
            o
            for o in self.map.objects.values()
            if o.confirmed and o.id not in observed and len(o.points)
        ]
        kinds = living.absence_evidence_batched(
            [living.object_sample(o.points) for o in tested],
            self._own_labels(tested, view),
            view,
            self.map.knobs,
        )
        due, doubted = [], []
        for obj, kind in zip(tested, kinds, strict=True):
            if kind is None:
                continue
            evidence = self.suspects.setdefault(obj.id, [])
            evidence.append(
                living.Evidence(kind, view.t, view.keyframe, view.position, view.direction)
            )
            if living.removal_due(evidence, self.map.knobs):
                due.append(obj)
            elif kind == "depth":
                # a place seen through; thin evidence alone is mostly a detector miss,
                # and a like thing added elsewhere would make that miss a false move
                doubted.append(obj)
        removed: set[int] = set()
        # the most observed first: a second reading of the same thing (a confused label)
        # that leaves with it is then seen to share its old place
        for obj in sorted(due, key=lambda o: (-o.n_obs, o.id)):
            if obj.id in self.map.objects:
                removed |= self._conclude_absent(obj, stats)
        movers = {o.id: o for o in doubted}
        movers |= {i: self.map.objects[i] for i in self.sighted_through if i in self.map.objects}
        self.sighted_through.clear()
        for obj in sorted(movers.values(), key=lambda o: (-o.n_obs, o.id)):
            if obj.id in self.map.objects:
                removed |= self._found_already_elsewhere(obj, stats)
        return removed

    def _found_already_elsewhere(self, obj: MapObject, stats: IntegrationStats) -> set[int]:
        """A keyframe saw through `obj`'s place (depth evidence), or a
        sighting since the last keyframe did (`sight_moved_places`), while a like
        object had appeared elsewhere since `obj` was last seen (`_like_object`: its `added`
        change stands): `obj` moved there, concluded now. The same evidence as a candidate
        confirmed while a like object is suspect (`found_moved`), met in the other order: the
        new place seen first. Without such an object the doubt waits for
        `living.removal_due`; so does a second reading of a place just vacated
        (`_second_reading_of_vacated`), which that rule drops. Returns the ids taken out of
        the present map."""
        if self._second_reading_of_vacated(obj):
            return set()
        new = self._like_object(obj, self._appeared_objects(), obj_is_new=False)
        if new is None:
            return set()
        self.suspects.pop(obj.id, None)
        self._move(obj, new, stats)
        stats.retracted_added.append(new.id)
        return {new.id}

    def _appeared_objects(self) -> list[MapObject]:
        """Confirmed objects with their `added` change standing, their own place not seen
        through (depth evidence) since: where a suspect one may be found (`_like_object`
        takes no other as the new place). Thin evidence alone on the new place is mostly a
        detector missing the thing there, and does not hold the move back."""
        return [
            o
            for o in self.map.objects.values()
            if o.id in self.appeared
            and o.confirmed
            and not any(e.kind == "depth" for e in self.suspects.get(o.id, ()))
        ]

    def _own_labels(self, objects: list[MapObject], view: living.EvidenceView) -> list[set[str]]:
        """Per object, the labels a detection of it may carry: every label it has carried,
        and the keyframe's labels alike to its embedding (`association_min_semantic`): the
        detector calling a chair a stool still sees the chair."""
        own = [set(o.label_counts) for o in objects]
        labels = sorted(set(view.labels.values()))
        if not objects or not labels:
            return own
        alike = np.stack([o.embedding for o in objects]) @ self.map.encoder.encode_labels(labels).T
        for i, j in zip(*np.nonzero(alike >= self.map.knobs.association_min_semantic), strict=True):
            own[i].add(labels[j])
        return own

    def _suspected_objects(self) -> list[MapObject]:
        return [self.map.objects[i] for i in sorted(self.suspects) if i in self.map.objects]

    def _like_object(
        self, obj: MapObject, others: list[MapObject], obj_is_new: bool
    ) -> MapObject | None:
        """The object among `others` that is `obj` at another place (obj_is_new: `obj` is
        the new place, `others` old ones; else the other way round), the most alike, then
        the nearest. Old and new must be alike (same label, or embeddings
        `move_min_similarity` alike), the old one not observed since the new one appeared
        (two like things seen at once are two things), and the new one must have appeared:
        at a place seen empty before and not on another object (a second reading of the
        old one, say, from a new viewpoint, is not a move)."""
        best, best_key = None, None
        centroid = obj.centroid
        for other in others:
            old, new = (other, obj) if obj_is_new else (obj, other)
            if old.id == new.id or old.last_seen >= new.first_seen:
                continue
            similarity = float(old.embedding @ new.embedding)
            same = old.label == new.label
            if not same and similarity < self.map.knobs.move_min_similarity:
                continue
            key = (same, similarity, -float(np.linalg.norm(other.centroid - centroid)))
            if best_key is not None and key <= best_key:
                continue
            if not self._appeared_at(new, as_candidate=obj_is_new):
                continue
            best, best_key = other, key
        return best

    def _appeared_at(self, new: MapObject, as_candidate: bool) -> bool:
        """Whether `new` appeared in the world (`_like_object`): a published object had its
        `added` change; a candidate is checked now."""
        if not as_candidate:
            return new.id in self.appeared
        return self._place_seen_empty(new) and not self._place_taken(new)

    def _move(self, old: MapObject, new: MapObject, stats: IntegrationStats) -> None:
        """`old` is found at `new`'s place: it keeps its id and history, takes `new`'s
        geometry and observations (its old points are dropped), starts a new stay; `new`
        leaves the map. A `moved` change."""
        old.refresh_stay()
        self._vacate(old, stats, keep=new.id)
        from_xyz, _ = old.place()
        old.set_points(
            new.points.copy(),
            new.resolution_m,
            None if new.support is None else new.support.copy(),
        )
        old.absorb_labels(new)
        old.n_obs += new.n_obs
        old.frames_seen += new.frames_seen
        old.last_seen, old.last_seen_t = new.last_seen, new.last_seen_t
        t_from = new.first_seen_t if new.first_seen_t is not None else self._now
        old.start_stay(t_from)
        old.version += 1
        self.map.take_out(new.id)
        self.map.mark_changed(old.id)
        self.forget(new.id)
        self.suspects.pop(old.id, None)
        to_xyz, _ = old.place()
        stats.changes.append(Change(old.id, "moved", self._now, old.label, from_xyz, to_xyz))

    def _conclude_absent(self, obj: MapObject, stats: IntegrationStats) -> set[int]:
        """The evidence removes `obj` from its place: moved, when a like object appeared
        elsewhere since it was last seen (that one merges into it and its id is removed),
        else removed from the present map (kept as history). Returns the ids removed."""
        self.suspects.pop(obj.id, None)
        if self._second_reading_of_vacated(obj):
            self._drop_second_reading(obj, stats)
            return {obj.id}
        new = self._like_object(obj, self._appeared_objects(), obj_is_new=False)
        if new is not None:
            self._move(obj, new, stats)
            stats.retracted_added.append(new.id)
            return {new.id}
        self._vacate(obj, stats)
        obj.refresh_stay()
        from_xyz, _ = obj.place()
        obj.state = "removed"
        obj.version += 1
        self.map.take_out(obj.id)
        self.appeared.discard(obj.id)
        self.recently_removed[obj.id] = (self.map.keyframes, self._now, obj)
        while len(self.recently_removed) > RECENTLY_REMOVED:
            del self.recently_removed[next(iter(self.recently_removed))]
        stats.retired.append(obj)
        stats.changes.append(Change(obj.id, "removed", self._now, obj.label, from_xyz=from_xyz))
        return {obj.id}

    def _revived(self, new: MapObject, stats: IntegrationStats) -> MapObject | None:
        """The recently removed object `new` is (`_like_object`), back in the map (state
        present, its removal retracted) for `_move` to take it to its new place; or None."""
        for oid, (_, t_removed, _) in list(self.recently_removed.items()):
            if self._now - t_removed > REVIVE_WINDOW_S:
                del self.recently_removed[oid]
        removed = [obj for _, _, obj in self.recently_removed.values()]
        old = self._like_object(new, removed, obj_is_new=True)
        if old is None:
            return None
        keyframe, _, _ = self.recently_removed.pop(old.id)
        old.state = "present"
        self.map.objects[old.id] = old
        if keyframe < self.map.keyframes:
            stats.retracted_removed.append(old.id)
        else:  # removed by this very keyframe: its removal never leaves it
            stats.retired.remove(old)
            stats.changes[:] = [c for c in stats.changes if c.id != old.id]
            stats.unremoved_ids.append(old.id)
        return old

    def _vacate(self, obj: MapObject, stats: IntegrationStats, keep: int | None = None) -> None:
        """`obj` leaves its place: remember it (`_second_reading_of_vacated`), and drop the
        like objects whose boxes lie mostly in it, second readings of the same thing that
        would otherwise answer queries from where it no longer is (but `keep`)."""
        box = obj.bbox.copy()
        self.vacated.append((self.map.keyframes, box))
        for other in list(self.map.objects.values()):
            if other.id in (obj.id, keep) or not other.confirmed:
                continue
            alike = (
                other.label == obj.label
                or float(other.embedding @ obj.embedding) >= self.map.knobs.move_min_similarity
            )
            if alike and geo.bbox_inside_fraction(other.bbox, box) >= VACATED_INSIDE:
                self._drop_second_reading(other, stats)

    def _drop_second_reading(self, obj: MapObject, stats: IntegrationStats) -> None:
        """Take a duplicate of a thing that moved or left out of the map, as a clean-up
        merge would: its id is removed, with no change of its own."""
        self.map.take_out(obj.id)
        self.forget(obj.id)
        stats.retracted_added.append(obj.id)
        stats.dropped_ids.append(obj.id)

    def _second_reading_of_vacated(self, obj: MapObject) -> bool:
        """Whether most of `obj`'s box lies in the box of a place vacated within
        SUSPICION_MAX_KEYFRAMES: a second reading of the thing that left it (the back of a
        chair read as a stool)."""
        floor = self.map.keyframes - living.SUSPICION_MAX_KEYFRAMES
        while self.vacated and self.vacated[0][0] <= floor:
            self.vacated.popleft()
        return any(
            geo.bbox_inside_fraction(obj.bbox, box) >= VACATED_INSIDE for _, box in self.vacated
        )

    def _place_taken(self, obj: MapObject) -> bool:
        """Whether another confirmed object holds most of `obj`'s place, so that `obj` is a
        second reading of it (a fragment, a confused label), not a new thing: most of its
        points lie on that object's, and the two are alike (embeddings
        `association_min_semantic` alike) or share most of their boxes. Unlike things only
        touching (a mug on a table, a book on a shelf) hold their own places."""
        others = [o for o in self.map.objects.values() if o.confirmed and o.id != obj.id]
        if not others or not len(obj.points):
            return False
        margin = self.map.knobs.voxel_size_m
        boxes = np.stack([o.bbox for o in others])
        near = np.flatnonzero(geo.bbox_intersects_matrix(obj.bbox[None], boxes, margin)[0])
        for j in near:
            other = others[j]
            alike = (
                float(other.embedding @ obj.embedding) >= self.map.knobs.association_min_semantic
            )
            if not alike and geo.bbox_iou(obj.bbox, other.bbox) < PLACE_TAKEN_BOX_IOU:
                continue
            if geo.overlap_fraction(obj.points, other.tree, margin) >= PLACE_TAKEN_OVERLAP:
                return True
        return False

    def _place_seen_empty(self, obj: MapObject) -> bool:
        """Whether keyframes from before `obj` was first seen showed its place without it."""
        earlier = [v for v in self.views if v.keyframe < obj.first_seen]
        if not earlier:
            return False
        seeing = living.views_seeing(obj.centroid, earlier, self.map.knobs)
        return living.place_seen_empty(
            living.object_sample(obj.points),
            list(obj.label_counts),
            [earlier[i] for i in seeing],
            self.map.knobs,
        )

    def doubted_places(self) -> np.ndarray:
        """float64 [K, 5]: (x, y, z, radius, t_ready) of the place of each suspect object
        with depth evidence (a keyframe saw through it), the places the map doubts; metres,
        and the device time from which a keyframe seeing through it can complete its evidence
        (its first depth evidence + `removal_min_span_s`, the least span of a removal's
        evidence) (docs/protocol.md, the ack's `doubted`: a device that picks its
        keyframes makes one when such a place comes into view, so the evidence that settles
        the doubt arrives within a glance). The centre is the median of a sample of its
        points and the radius the 90th percentile of their distances from it (strays do not
        stretch the place)."""
        places = []
        for obj in self._suspected_objects():
            # thin evidence alone is weak (a detector missing a big thing gives it) and
            # needs two viewpoints anyway: only a place seen through is worth a keyframe
            if not len(obj.points) or not any(e.kind == "depth" for e in self.suspects[obj.id]):
                continue
            sample = living.object_sample(obj.points).astype(np.float64)
            centre = np.median(sample, axis=0)
            radius = float(np.percentile(np.linalg.norm(sample - centre, axis=1), 90))
            first = min(e.t for e in self.suspects[obj.id] if e.kind == "depth")
            places.append((*centre, radius, first + self.map.knobs.removal_min_span_s))
        return np.asarray(places, np.float64).reshape(-1, 5)

    def sight_moved_places(self, frame: FrameInput, sent: FrameDetections) -> None:
        """A sighting that sees through the place of a thing a like object has appeared
        elsewhere since (depth evidence, `living.absence_evidence`: occlusion is never
        evidence) notes it in `sighted_through`; the next keyframe concludes the move
        (`_found_already_elsewhere`). Only such places are tested: a sighting alone never
        makes a thing suspect or removes it, it only lets a move found elsewhere be
        concluded at the first glance of the empty old place."""
        movable = self._movable_objects()
        if not movable:
            return
        view = _sighting_view(frame, sent)
        kinds = living.absence_evidence_batched(
            [living.object_sample(o.points) for o in movable],
            self._own_labels(movable, view),
            view,
            self.map.knobs,
        )
        for obj, kind in zip(movable, kinds, strict=True):
            if kind == "depth":
                self.sighted_through[obj.id] = view.t

    def _movable_objects(self) -> list[MapObject]:
        """Confirmed objects with points that a like object appeared elsewhere since they
        were last seen (`_like_object`'s test of likeness and times, without its candidate
        checks): the places a sighting is worth testing for. One matrix product over the
        map: a sighting comes five times a second."""
        appeared = [self.map.objects[i] for i in sorted(self.appeared) if i in self.map.objects]
        appeared = [o for o in appeared if o.confirmed]
        if not appeared:
            return []
        objs = [
            o
            for o in self.map.objects.values()
            if o.confirmed and o.id not in self.appeared and len(o.points)
        ]
        if not objs:
            return []
        alike = np.stack([o.embedding for o in objs]) @ np.stack([a.embedding for a in appeared]).T
        alike = alike >= self.map.knobs.move_min_similarity
        alike |= np.array([o.label for o in objs])[:, None] == np.array([a.label for a in appeared])
        unseen = np.array([o.last_seen for o in objs])[:, None] < np.array(
            [a.first_seen for a in appeared]
        )
        return [objs[i] for i in np.flatnonzero((alike & unseen).any(axis=1))]

    def clear_seen_suspects(self, frame: FrameInput, sent: FrameDetections) -> None:
        """A sighting that shows a suspect object where it was clears its suspicion: at
        least SIGHTING_MIN_POINTS of its points at the sensed depth (the evidence test's
        tolerance) under a detection of one of its labels. A like thing detected nearby, or
        beyond its place, clears nothing."""
        suspects = [self.map.objects[i] for i in list(self.suspects) if i in self.map.objects]
        if not suspects:
            return
        view = _sighting_view(frame, sent)
        own = self._own_labels(suspects, view)
        for obj, labels in zip(suspects, own, strict=True):
            sample = living.object_sample(obj.points)
            verdicts = living.classify_points(sample, view, self.map.knobs)
            at = verdicts.matching
            if at.sum() < SIGHTING_MIN_POINTS:
                continue
            ids = geo.pixels_of(view.label_image, verdicts.u[at], verdicts.v[at], frame.rgb_size[0])
            hits = sum(
                int(n)
                for d, n in zip(*np.unique(ids, return_counts=True), strict=True)
                if d and view.labels.get(int(d)) in labels
            )
            if hits >= SIGHTING_MIN_POINTS:
                del self.suspects[obj.id]


def _sighting_view(frame: FrameInput, sent: FrameDetections) -> living.EvidenceView:
    """What a sighting shows the evidence tests: its pose, depth and detections at its time."""
    return living.EvidenceView(
        pose=np.asarray(frame.pose, np.float64),
        intrinsics=tuple(frame.intrinsics),  # type: ignore[arg-type]
        rgb_size=frame.rgb_size,
        depth_m=frame.depth_m,
        label_image=sent.instance_image,
        labels=sent.labels(),
        t=float(frame.t),
    )
