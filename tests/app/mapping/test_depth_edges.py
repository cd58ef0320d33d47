"""Lifting at the coarse depth: a mask's rim on what lies behind does not become points, a
thin part of a thing does."""

from __future__ import annotations

import numpy as np

from app.mapping import geometry as geo

RATIO = 5
WIDTH, HEIGHT = 200, 150
INTRINSICS = (150.0, 150.0, (WIDTH - 1) / 2, (HEIGHT - 1) / 2)
WALL_M = 3.0


def _scene(box_m: float = 1.5, pole_m: float = 2.0, bleed_px: int = 3):
    """A box and a thin pole in front of a wall, as a detector sees them: masks at RGB size
    grown by `bleed_px` onto the wall, depth at RGB size / RATIO (nearest: each depth pixel
    is the RGB pixel at its block's centre). Pole: 4 px wide, under one depth pixel."""
    depth = np.full((HEIGHT, WIDTH), WALL_M, np.float32)
    ids = np.zeros((HEIGHT, WIDTH), np.uint16)
    depth[40:100, 30:90] = box_m
    ids[40 - bleed_px : 100 + bleed_px, 30 - bleed_px : 90 + bleed_px] = 1
    depth[20:130, 141:145] = pole_m
    ids[20:130, 141 - bleed_px : 145 + bleed_px] = 2
    coarse = np.ascontiguousarray(depth[RATIO // 2 :: RATIO, RATIO // 2 :: RATIO])
    return ids, coarse


def test_mask_rim_on_the_wall_behind_is_not_lifted():
    ids, depth = _scene()
    lifted = geo.lift_instances_batched(ids, [1], depth, INTRINSICS, np.eye(4), 10.0)[1]
    assert len(lifted) > 100
    np.testing.assert_allclose(lifted[:, 2], 1.5)  # no point of the wall behind


def test_a_pole_one_depth_pixel_wide_in_front_of_a_wall_is_lifted_whole():
    ids, depth = _scene()
    lifted = geo.lift_instances_batched(ids, [2], depth, INTRINSICS, np.eye(4), 10.0)[2]
    on_pole = np.isclose(lifted[:, 2], 2.0)
    assert on_pole.sum() == len(range(20, 130)) // RATIO  # every sample down the pole
    assert not np.isclose(lifted[:, 2], WALL_M).any()  # its rim on the wall is not


def test_without_the_edge_test_the_rim_would_be_lifted():
    """The scene does bleed onto the wall: the plain mask at the depth pixels holds it."""
    ids, depth = _scene()
    u, v = geo.depth_to_rgb_pixel_grid((depth.shape[1], depth.shape[0]), (WIDTH, HEIGHT))
    sampled = ids[np.ix_(v, u)]
    assert np.isclose(depth[sampled == 1], WALL_M).any()


def test_a_slanted_surface_keeps_its_edge_samples():
    """A floor seen at a slant: depth grows down the image, the mask edge stays."""
    ids, _ = _scene(bleed_px=0)
    rows = np.arange(HEIGHT // RATIO, dtype=np.float32)[:, None]
    depth = np.repeat(1.0 + 0.15 * rows, WIDTH // RATIO, axis=1)  # 15 cm per depth row
    lifted = geo.lift_instances_batched(ids, [1], depth, INTRINSICS, np.eye(4), 10.0)[1]
    u, v = geo.depth_to_rgb_pixel_grid((depth.shape[1], depth.shape[0]), (WIDTH, HEIGHT))
    assert len(lifted) == int((ids[np.ix_(v, u)] == 1).sum())


def test_lifting_one_mask_rejects_the_same_rim():
    ids, depth = _scene()
    single = geo.lift_detection(ids == 1, depth, INTRINSICS, np.eye(4), 10.0)
    np.testing.assert_allclose(single[:, 2], 1.5)
