"""The geometry eval: its figures mean what docs/evaluation.md says, and it runs end to end."""

from __future__ import annotations

import numpy as np
import pytest

from evaluation import geometry
from world import make_scene
from world.noise import DetectionModel
from world.render import Renderer, default_camera

RNG = np.random.default_rng(0)


def _box_surface(lo, hi, n=2000) -> np.ndarray:
    return RNG.uniform(lo, hi, size=(n, 3)).astype(np.float32)


def test_a_thing_scored_against_itself_is_perfect():
    truth = _box_surface([0, 0, 0], [0.1, 0.1, 0.2])
    row = geometry.score_object(truth, truth)
    assert row["box_iou"] == pytest.approx(1.0)
    assert row["volume_ratio"] == pytest.approx(1.0)
    assert row["extent_ratio"] == pytest.approx(1.0)
    assert row["near_surface"] == 1.0


def test_one_stray_point_blows_the_box_up_but_barely_the_near_surface_share():
    truth = _box_surface([0, 0, 0], [0.1, 0.1, 0.2])
    mapped = np.concatenate([truth, [[0.05, 0.05, -0.5]]]).astype(np.float32)  # the floor below
    row = geometry.score_object(mapped, truth)
    assert row["volume_ratio"] > geometry.OVERSIZE_VOLUME_RATIO
    assert row["box_iou"] < 0.5
    assert row["near_surface"] > 0.99
    assert geometry._summary([row])["oversize"] == 1


def test_the_bleed_profile_grows_masks_past_the_standard_ones_and_smears_depth_edges():
    scene = make_scene("living_room", 0)
    camera = default_camera(160, 120)
    from world.trajectory import walk_trajectory

    view = Renderer(scene).render(walk_trajectory(scene, 10, 0)[5], camera)
    standard = DetectionModel(scene, "standard", 0).detect(view, 5)
    bleed = DetectionModel(scene, "bleed", 0).detect(view, 5)
    assert (bleed.instance_ids > 0).sum() > (standard.instance_ids > 0).sum()
    off_bleed = (np.abs(bleed.depth_m - view.depth_m) > 0.1).sum()
    off_standard = (np.abs(standard.depth_m - view.depth_m) > 0.1).sum()
    assert off_bleed > 10 * max(off_standard, 1)  # flying pixels at the depth edges


@pytest.mark.slow
def test_the_geometry_eval_runs_on_a_tiny_walk(encoder):
    cfg = geometry.GeometryConfig(
        scene="living_room", frames=40, width=160, height=120, noise="none", modes=("semanticxr",)
    )
    doc = geometry.run(cfg, encoder, progress=lambda _: None).document
    mode = doc["modes"]["semanticxr"]
    assert set(mode) == {"semantic", *geometry.STATES}
    assert "F_mIoU" in mode["semantic"] and "query_top1" in mode["semantic"]
    scored = mode["walk"]["all"]
    assert scored["objects"] > 0
    assert 0.0 < scored["median_box_iou"] <= 1.0
    assert scored["near_surface_pooled"] > 0.9  # noise-free detections lie on their things
    assert "geometry" not in geometry.format_geometry_table(doc).splitlines()[0]
