"""The incremental clean-up (the mapping speed-up target): only objects changed since their last
clean-up are denoised and compared for a merge, and semanticxr spreads that work over the
keyframes instead of paying for every changed object on one."""

from __future__ import annotations

import itertools

import pytest
from analytic_world import Rect, render_rects

from app.config import Knobs
from app.mapping import geometry as geo
from app.mapping.engine import MappingEngine, make_perception

# two chairs whose boxes overlap at a corner (the right one hides the left one's corner):
# compared for a merge, never merged
LEFT = Rect(1, "chair", -0.6, -0.3, -0.1, 0.3, 2.0)
RIGHT = Rect(2, "chair", -0.3, 0.2, 0.35, 0.6, 2.0)
FAR = Rect(3, "table", 1.0, -0.3, 1.5, 0.3, 2.0)
SHELF = Rect(4, "bookshelf", -1.4, -0.3, -0.9, 0.3, 2.0)


class Calls:
    """Counts the clean-up's geometry calls per object (by the object's points array)."""

    def __init__(self, engine: MappingEngine, monkeypatch):
        self.engine = engine
        self.denoised: list[int] = []
        self.compared: list[int] = []
        outlier_free, overlap_fraction = geo.outlier_free, geo.overlap_fraction

        def counted_remove(points, *args, **kwargs):
            self.denoised += self._owners(points)
            return outlier_free(points, *args, **kwargs)

        def counted_overlap(points, *args, **kwargs):
            self.compared += self._owners(points)
            return overlap_fraction(points, *args, **kwargs)

        monkeypatch.setattr(geo, "outlier_free", counted_remove)
        monkeypatch.setattr(geo, "overlap_fraction", counted_overlap)

    def _owners(self, points) -> list[int]:
        return [o.id for o in self.engine.objects.values() if o.points is points]

    def reset(self) -> None:
        self.denoised.clear()
        self.compared.clear()


def make_engine(encoder, mode="semanticxr", **knobs) -> MappingEngine:
    defaults = {
        "min_mapping_bbox_area": 100,
        "min_observations": 2,
        "cleanup_interval": 2,
        "transient_max_age": 1000,
    }
    return MappingEngine(
        encoder, Knobs(**{**defaults, **knobs}), mode=mode, backend=make_perception(mode=mode)
    )


@pytest.mark.parametrize("mode", ["semanticxr", "baseline"])
def test_the_clean_up_touches_only_changed_objects(encoder, monkeypatch, mode):
    engine = make_engine(encoder, mode)
    for _ in range(4):
        engine.integrate(render_rects([LEFT, RIGHT]))
    assert sorted(o.label for o in engine.objects.values()) == ["chair", "chair"]
    for _ in range(2):  # every changed object is cleaned within one interval
        engine.integrate(render_rects([]))
    calls = Calls(engine, monkeypatch)
    for _ in range(6):  # three clean-up intervals in which nothing changes
        engine.integrate(render_rects([]))
    assert calls.denoised == [] and calls.compared == []
    versions = {oid: o.version for oid, o in engine.objects.items()}

    calls.reset()
    engine.integrate(render_rects([FAR]))  # a new object, away from the chairs
    for _ in range(3):
        engine.integrate(render_rects([]))
    assert calls.denoised == [3]  # the table, once; the chairs are left alone
    assert calls.compared == []  # the table overlaps nothing
    assert {oid: engine.objects[oid].version for oid in versions} == versions

    calls.reset()
    engine.integrate(render_rects([RIGHT]))  # one chair changes: compared with its neighbour
    for _ in range(3):
        engine.integrate(render_rects([]))
    assert calls.denoised == [2]
    assert calls.compared and set(calls.compared) <= {1, 2}
    assert len(engine.objects) == 3  # compared, not merged


def test_semanticxr_spreads_the_clean_up_over_keyframes(encoder, monkeypatch):
    engine = make_engine(encoder, cleanup_interval=2)
    scene = [SHELF, LEFT, FAR]
    engine.integrate(render_rects(scene))
    calls = Calls(engine, monkeypatch)
    per_keyframe = []
    for _ in range(6):  # every object changes on every keyframe
        calls.reset()
        engine.integrate(render_rects(scene))
        per_keyframe.append(sorted(calls.denoised))
    # no keyframe cleans every changed object; each one is cleaned every other keyframe
    assert all(len(ids) < len(engine.objects) for ids in per_keyframe)
    for oid in engine.objects:
        assert all(oid in a or oid in b for a, b in itertools.pairwise(per_keyframe))


def test_the_baseline_cleans_up_the_whole_scene_every_interval(encoder, monkeypatch):
    engine = make_engine(encoder, "baseline", cleanup_interval=2)
    scene = [SHELF, LEFT, FAR]
    engine.integrate(render_rects(scene))
    calls = Calls(engine, monkeypatch)
    per_keyframe = []
    for _ in range(4):
        calls.reset()
        engine.integrate(render_rects(scene))
        per_keyframe.append(sorted(calls.denoised))
    assert per_keyframe == [[1, 2, 3], [], [1, 2, 3], []]


def test_duplicates_still_merge_when_only_one_of_them_changed(encoder):
    engine = make_engine(encoder, association_threshold=2.0)  # never associate: duplicates
    engine.integrate(render_rects([LEFT]))
    engine.integrate(render_rects([LEFT]))
    for _ in range(2):
        engine.integrate(render_rects([]))
    assert len(engine.objects) == 1


def test_one_thing_read_under_two_labels_becomes_one_object_a_thing_on_another_does_not(encoder):
    engine = make_engine(encoder, association_threshold=2.0)  # never associate: duplicates
    sofa = Rect(1, "sofa", -0.8, -0.4, 0.8, 0.4, 2.5)
    loveseat = Rect(5, "loveseat", -0.8, -0.4, 0.8, 0.4, 2.5)  # the same thing, read otherwise
    bed = Rect(6, "bed", 1.2, -0.5, 2.4, 0.5, 2.5)
    blanket = Rect(7, "blanket", 1.4, -0.3, 2.0, 0.3, 2.5)  # lies on the bed: all of it on it
    for frame in ([sofa, bed], [loveseat, blanket], [sofa, bed], [loveseat, blanket]):
        engine.integrate(render_rects(frame))
    labels = sorted(o.label for o in engine.objects.values())
    assert labels.count("blanket") == 1 and labels.count("bed") == 1
    seats = [o for o in engine.objects.values() if o.label in ("sofa", "loveseat")]
    assert len(seats) == 1, labels
    assert seats[0].n_obs == 4  # both readings' observations
