"""Clean-up keeps a thing's own parts and drops what is not its own; a map settles once its
stream has closed."""

from __future__ import annotations

import numpy as np
from clouds import disc

from app.config import Knobs
from app.mapping import geometry as geo
from app.mapping.engine import OUTLIER_EPS_M, MappingEngine, make_perception
from app.mapping.object import MapObject

RNG = np.random.default_rng(0)


def _lamp() -> np.ndarray:
    """A lamp as a capped cloud: a dense base and shade, a pole of one point per 4 cm."""
    base = disc(RNG, (0.0, 0.0, 0.0), 0.1, 150)
    pole = np.stack([np.zeros(30), np.zeros(30), 0.02 + 0.04 * np.arange(30)], 1)
    shade = disc(RNG, (0.0, 0.0, 1.25), 0.15, 150)
    return np.concatenate([base, pole, shade]).astype(np.float32)


def test_a_lamps_pole_and_base_survive_outlier_removal():
    lamp = _lamp()
    kept = geo.remove_outliers(lamp, OUTLIER_EPS_M)
    assert len(kept) == len(lamp)


def test_a_stray_touching_the_thing_does_not_survive_outlier_removal():
    lamp = _lamp()
    stray = np.array([[0.17, 0.0, -0.02], [0.19, 0.01, -0.03]], np.float32)  # 7-9 cm off the base
    kept = geo.remove_outliers(np.concatenate([lamp, stray]), OUTLIER_EPS_M)
    assert len(kept) == len(lamp)
    assert kept[:, 0].max() < 0.16


def test_a_far_cluster_under_a_quarter_of_the_thing_is_dropped_even_when_most_is_scattered():
    """No 'keep everything' fallback: a cloud whose largest cluster is a minority still
    loses its strays."""
    body = disc(RNG, (0.0, 0.0, 0.0), 0.1, 100)
    strays = RNG.uniform(-3, 3, size=(300, 3))  # scattered single points, far apart
    kept = geo.remove_outliers(np.concatenate([body, strays]).astype(np.float32), OUTLIER_EPS_M)
    assert np.abs(kept).max() <= 0.11


def _engine_with(encoder, points: np.ndarray, changed: bool = True) -> MappingEngine:
    engine = MappingEngine(encoder, Knobs(), backend=make_perception())
    obj = MapObject(id=1, first_seen=1, first_seen_t=0.0, last_seen_t=1.0, confirmed=True)
    obj.set_points(points, 0.025)
    obj.observe_label("lamp", encoder.encode(["lamp"])[0])
    engine.objects[1] = obj
    if changed:
        engine.mark_changed(1)  # as mapping a keyframe into it would
    engine.next_object_id = 2
    return engine


def test_settling_a_closed_stream_drops_the_strays_clean_up_had_not_visited(encoder):
    lamp = _lamp()
    stray = np.array([[0.6, 0.6, 0.0]], np.float32)
    engine = _engine_with(encoder, np.concatenate([lamp, stray]))
    seq = engine.log.seq
    stats = engine.settle()
    assert stats.published_ids == [1] and stats.seq == seq + 1
    assert len(engine.objects[1].points) == len(lamp)
    np.testing.assert_allclose(engine.objects[1].bbox, geo.bbox_of(lamp))


def test_a_settled_map_publishes_nothing_when_settled_again(encoder):
    lamp = _lamp()
    engine = _engine_with(encoder, np.concatenate([lamp, np.array([[0.6, 0.6, 0.0]], np.float32)]))
    engine.settle()
    seq = engine.log.seq
    assert engine.settle().seq == seq and engine.log.seq == seq


def test_settling_leaves_an_object_unchanged_since_the_map_last_settled(encoder):
    """Settle visits only the objects changed since the map last settled, not the whole map."""
    stray = np.array([[0.6, 0.6, 0.0]], np.float32)
    engine = _engine_with(encoder, np.concatenate([_lamp(), stray]), changed=False)
    seq = engine.log.seq
    assert engine.settle().seq == seq and len(engine.objects[1].points) == len(_lamp()) + 1


def test_settle_visits_only_the_objects_changed_since_the_map_last_settled(encoder, monkeypatch):
    from analytic_world import Rect, render_rects

    knobs = Knobs(
        min_mapping_bbox_area=100, min_observations=2, cleanup_interval=2, transient_max_age=1000
    )
    engine = MappingEngine(encoder, knobs, backend=make_perception())
    chair = Rect(1, "chair", -0.6, -0.3, -0.1, 0.3, 2.0)
    table = Rect(2, "table", 1.0, -0.3, 1.5, 0.3, 2.0)
    for _ in range(4):
        engine.integrate(render_rects([chair, table]))
    engine.settle()
    engine.integrate(render_rects([table]))  # only the table is seen again
    denoised: list[str] = []
    outlier_free = geo.outlier_free

    def counted(points, *args, **kwargs):
        denoised.extend(o.label for o in engine.objects.values() if o.points is points)
        return outlier_free(points, *args, **kwargs)

    monkeypatch.setattr(geo, "outlier_free", counted)
    engine.settle()
    assert denoised == ["table"]


def test_settling_flattens_a_far_views_skin_onto_the_surface_many_views_agree_on(encoder):
    """The settled box of a wall is the wall's: the voxels a far view or two reached (3 cm
    range noise) are moved onto the plane the well-seen voxels pin, not tilted towards it."""
    rng = np.random.default_rng(5)
    grid = np.stack(np.meshgrid(np.arange(40), np.arange(40)), -1).reshape(-1, 2) * 0.025
    wall = np.column_stack([grid, rng.normal(0, 0.003, len(grid))])
    far = np.column_stack([rng.uniform(0, 0.975, (300, 2)), rng.normal(0, 0.03, 300)])
    engine = _engine_with(encoder, np.concatenate([wall, far]).astype(np.float32))
    support = np.concatenate([np.full(len(wall), 8.0), np.full(len(far), 2.0)])
    engine.objects[1].support = support.astype(np.float32)
    engine.settle()
    box = engine.objects[1].bbox
    assert box[5] - box[2] < 0.03  # 16 cm of skin before; 8 cm with an unweighted fit
    assert box[3] - box[0] > 0.95 and box[4] - box[1] > 0.95
