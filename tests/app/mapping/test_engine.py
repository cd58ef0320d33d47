"""The mapping engine, specified on analytic frames (exact depth and masks)."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from analytic_world import Rect, render_rects

from app.config import Knobs
from app.mapping import geometry as geo
from app.mapping.engine import MappingEngine, make_perception
from app.perception.base import InputError

CHAIR = Rect(1, "chair", -0.6, -0.3, -0.1, 0.3, 2.0)
TABLE = Rect(2, "table", 0.1, -0.3, 0.7, 0.3, 2.0)


def make_engine(encoder, mode="semanticxr", **knobs) -> MappingEngine:
    defaults = {"min_mapping_bbox_area": 100, "min_observations": 2, "cleanup_interval": 1000}
    return MappingEngine(
        encoder, Knobs(**{**defaults, **knobs}), mode=mode, backend=make_perception(mode=mode)
    )


def snapshot(engine: MappingEngine):
    return (
        engine.keyframes,
        engine.log.state(),
        {
            oid: (o.version, o.points.tobytes(), o.embedding_sum.tobytes(), dict(o.label_counts))
            for oid, o in engine.objects.items()
        },
    )


@pytest.mark.parametrize("mode", ["semanticxr", "baseline"])
def test_two_views_of_one_chair_become_one_object(encoder, mode):
    engine = make_engine(encoder, mode)
    engine.integrate(render_rects([CHAIR], cam_xy=(0.0, 0.0)))
    engine.integrate(render_rects([CHAIR], cam_xy=(0.15, 0.05)))
    assert len(engine.objects) == 1
    (obj,) = engine.objects.values()
    assert obj.label == "chair" and obj.frames_seen == 2 and obj.confirmed


@pytest.mark.parametrize("mode", ["semanticxr", "baseline"])
def test_two_adjacent_different_objects_stay_two(encoder, mode):
    engine = make_engine(encoder, mode)
    for step in range(3):
        engine.integrate(render_rects([CHAIR, TABLE], cam_xy=(0.05 * step, 0.0)))
    labels = sorted(o.label for o in engine.objects.values())
    assert labels == ["chair", "table"]


def test_object_bbox_matches_the_rectangle(encoder):
    engine = make_engine(encoder)
    engine.integrate(render_rects([CHAIR]))
    (obj,) = engine.objects.values()
    expected = np.array([CHAIR.x0, CHAIR.y0, CHAIR.depth_m, CHAIR.x1, CHAIR.y1, CHAIR.depth_m])
    np.testing.assert_allclose(obj.bbox, expected, atol=0.03)


def test_point_cap_holds_after_many_merges(encoder):
    engine = make_engine(
        encoder, max_object_points_server=150, voxel_size_m=0.01, max_object_spacing_m=None
    )
    big = Rect(1, "sofa", -1.0, -0.6, 1.0, 0.6, 2.5)
    for step in range(12):
        engine.integrate(render_rects([big], cam_xy=(0.03 * step, -0.02 * step), ratio=1))
        assert all(len(o.points) <= 150 for o in engine.objects.values())
    (obj,) = engine.objects.values()
    # capped geometry still spans the whole object
    assert obj.bbox[3] - obj.bbox[0] > 1.8 and obj.bbox[4] - obj.bbox[1] > 1.0


def test_a_density_cap_keeps_a_large_object_as_dense_as_its_spacing(encoder):
    engine = make_engine(encoder, max_object_points_server=150, max_object_spacing_m=0.05)
    for step in range(4):
        sofa = Rect(1, "sofa", -1.0, -0.6, 1.0, 0.6, 2.5)
        engine.integrate(render_rects([sofa], cam_xy=(0.02 * step, 0.0), ratio=1))
        (obj,) = engine.objects.values()
        # 2 m x 1.2 m at 5 cm: ~40 x 24 points, more than the count cap of 150 allows
        assert obj.resolution_m <= 0.05 and len(obj.points) > 600


def test_baseline_keeps_uncapped_geometry(encoder):
    engine = make_engine(encoder, "baseline", max_object_points_server=150)
    engine.integrate(render_rects([Rect(1, "sofa", -1.0, -0.6, 1.0, 0.6, 2.5)], ratio=1))
    (obj,) = engine.objects.values()
    assert len(obj.points) > 150


def test_transient_detections_are_pruned_and_never_published(encoder):
    engine = make_engine(encoder, min_observations=3, cleanup_interval=2, transient_max_age=3)
    ghost = Rect(3, "umbrella", 0.8, 0.4, 1.0, 0.6, 1.5)
    engine.integrate(render_rects([CHAIR, ghost]))
    assert {o.label for o in engine.objects.values()} == {"chair", "umbrella"}
    for _ in range(6):
        engine.integrate(render_rects([CHAIR]))
    assert [o.label for o in engine.objects.values()] == ["chair"]
    assert engine.delta_since(0).removed == []  # it never reached a subscriber


def test_objects_are_confirmed_after_min_observations(encoder):
    engine = make_engine(encoder, min_observations=3)
    for expected_confirmed in (False, False, True):
        engine.integrate(render_rects([CHAIR]))
        assert next(iter(engine.objects.values())).confirmed is expected_confirmed
    assert [o.label for o in engine.confirmed_objects()] == ["chair"]


def test_delta_since_contains_exactly_the_objects_changed_after_it(encoder):
    engine = make_engine(encoder, min_observations=1)
    engine.integrate(render_rects([CHAIR, TABLE]))
    after_both = engine.log.seq
    chair_id = next(o.id for o in engine.objects.values() if o.label == "chair")
    engine.integrate(render_rects([CHAIR]))
    delta = engine.delta_since(after_both)
    assert delta.upserts == [chair_id] and delta.removed == [] and not delta.full
    assert engine.delta_since(engine.log.seq).upserts == []
    assert sorted(engine.delta_since(0).upserts) == sorted(engine.objects)


def test_small_detections_are_deferred_and_skip_set_is_never_mapped(encoder):
    engine = make_engine(encoder, min_mapping_bbox_area=4000, skip_mapping_set=["Table"])
    tiny = Rect(3, "cup", 0.8, 0.4, 0.9, 0.5, 2.0)  # ~14x14 px
    stats = engine.integrate(render_rects([CHAIR, TABLE, tiny]))
    assert stats.deferred == 1 and stats.skipped == 1
    assert [o.label for o in engine.objects.values()] == ["chair"]


def test_a_cushion_on_a_sofa_stays_a_separate_object(encoder):
    engine = make_engine(encoder)
    sofa = Rect(1, "sofa", -1.0, -0.5, 1.0, 0.5, 2.5)
    cushion = Rect(2, "cushion", -0.2, -0.15, 0.2, 0.15, 2.48)  # 2 cm in front of the sofa
    for step in range(3):
        engine.integrate(render_rects([sofa, cushion], cam_xy=(0.03 * step, 0.0)))
    assert sorted(o.label for o in engine.objects.values()) == ["cushion", "sofa"]


def test_query_for_a_category_returns_that_object_first(encoder):
    engine = make_engine(encoder, min_observations=1)
    rects = [CHAIR, TABLE, Rect(3, "refrigerator", -1.5, -0.8, -0.8, 0.8, 3.0)]
    engine.integrate(render_rects(rects))
    assert engine.query("something to keep food cold", k=1)[0].object.label == "refrigerator"
    assert engine.query("a seat", k=1)[0].object.label == "chair"
    scores = [h.score for h in engine.query("table", k=3)]
    assert scores == sorted(scores, reverse=True)


def test_batched_and_one_by_one_modes_build_the_same_objects(encoder):
    maps = {}
    for mode in ("semanticxr", "baseline"):
        engine = make_engine(encoder, mode, max_object_points_server=1_000_000)
        for step in range(4):
            engine.integrate(render_rects([CHAIR, TABLE], cam_xy=(0.04 * step, 0.0)))
        maps[mode] = {o.label: o.points for o in engine.objects.values()}
    assert maps["semanticxr"].keys() == maps["baseline"].keys()
    for label, pts in maps["semanticxr"].items():
        full = maps["baseline"][label]
        assert len(full) > len(pts)  # the baseline keeps sensor resolution
        np.testing.assert_allclose(geo.bbox_of(pts), geo.bbox_of(full), atol=0.03)


BAD_FRAMES = {
    "pose": lambda f: setattr(f, "pose", np.full((4, 4), np.nan)),
    "pose ": lambda f: f.pose.__setitem__((0, 0), 2.0),  # scaled: not rigid
    "depth": lambda f: setattr(f, "depth_m", f.depth_m[:, :-3].copy()),
    "depth ": lambda f: setattr(f, "depth_m", f.depth_m.astype(np.float64)),
    "detections": lambda f: setattr(f, "instance_ids", f.instance_ids[:-1]),
    "detections.instances": lambda f: f.instances.pop(),
    "intrinsics": lambda f: setattr(f, "intrinsics", (0.0, 277.0, 159.5, 119.5)),
    # Finite but absurd: would lift to points beyond float32 (the map would hold inf).
    "pose  ": lambda f: f.pose.__setitem__((0, 3), 3e38),
    "intrinsics ": lambda f: setattr(f, "intrinsics", (277.0, 277.0, 1e300, 119.5)),
}


@pytest.mark.parametrize("field", list(BAD_FRAMES))
def test_bad_input_names_the_field_and_leaves_the_map_unchanged(encoder, field):
    engine = make_engine(encoder)
    engine.integrate(render_rects([CHAIR, TABLE]))
    before = copy.deepcopy(snapshot(engine))
    frame = render_rects([CHAIR, TABLE], cam_xy=(0.1, 0.0))
    BAD_FRAMES[field](frame)
    with pytest.raises(InputError) as err:
        engine.integrate(frame)
    assert err.value.field == field.strip()
    assert snapshot(engine) == before


def test_at_max_objects_matches_still_map_and_new_objects_wait_for_room(encoder, caplog):
    engine = make_engine(encoder, cleanup_interval=2, transient_max_age=2)
    engine.max_objects = 1
    engine.integrate(render_rects([CHAIR]))
    stats = engine.integrate(render_rects([CHAIR, TABLE]))  # the map is full: no table
    assert (stats.matched, stats.created, stats.over_cap) == (1, 0, 1)
    assert [o.label for o in engine.objects.values()] == ["chair"]
    assert engine.objects[1].n_obs == 2  # the chair's view was mapped
    assert sum("--max-objects" in r.getMessage() for r in caplog.records) == 1
    engine.integrate(render_rects([CHAIR, TABLE]))
    assert sum("--max-objects" in r.getMessage() for r in caplog.records) == 1  # once a streak

    engine = make_engine(encoder, cleanup_interval=1, transient_max_age=1, min_observations=5)
    engine.max_objects = 1
    engine.integrate(render_rects([TABLE]))  # a candidate that is never seen again
    engine.integrate(render_rects([CHAIR]))  # no room yet; the table is pruned as a transient
    stats = engine.integrate(render_rects([CHAIR]))  # room again
    assert stats.created == 1 and [o.label for o in engine.objects.values()] == ["chair"]
