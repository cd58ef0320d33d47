"""A point's support (how many keyframes' views it stands for) rides along every merge and
cap, so that what a single view saw apart from the others can be told from the surface."""

from __future__ import annotations

import numpy as np
import pytest

from app.mapping import geometry as geo
from app.mapping.object import MapObject


def test_a_voxels_points_merge_into_their_support_weighted_mean_with_the_sum_of_support():
    points = np.array([[0.01, 0.01, 0.01], [0.02, 0.01, 0.01], [0.30, 0.0, 0.0]], np.float32)
    merged, support = geo.voxel_merge(points, np.array([3.0, 1.0, 1.0]), 0.025)
    assert len(merged) == 2
    np.testing.assert_allclose(merged[0], [0.0125, 0.01, 0.01], atol=1e-6)
    np.testing.assert_allclose(support, [4.0, 1.0])


def test_a_coarse_cap_keeps_each_voxels_best_supported_point_with_the_voxels_support():
    rng = np.random.default_rng(0)
    points = rng.uniform(0, 1, (3000, 3)).astype(np.float32)
    support = rng.integers(1, 5, len(points)).astype(np.float32)
    capped, spacing, kept_support = geo.cap_points_supported(points, support, 200, 0.025)
    assert len(capped) <= 200 and len(kept_support) == len(capped)
    assert kept_support.sum() == support.sum()  # a voxel's views are its kept point's
    unsupported, unsupported_spacing = geo.cap_points(points, 200, 0.025)
    assert spacing == unsupported_spacing and len(capped) == len(unsupported)


def test_a_cap_without_support_is_the_plain_cap():
    rng = np.random.default_rng(1)
    points = rng.uniform(0, 1, (3000, 3)).astype(np.float32)
    capped, spacing, support = geo.cap_points_supported(points, None, 200, 0.025)
    plain, plain_spacing = geo.cap_points(points, 200, 0.025)
    assert support is None and spacing == plain_spacing
    np.testing.assert_array_equal(capped, plain)


def test_points_kept_from_an_objects_geometry_keep_their_support_and_new_ones_unknown():
    obj = MapObject(id=1)
    points = np.arange(30, dtype=np.float32).reshape(10, 3)
    obj.set_points(points, 0.025, np.arange(10, dtype=np.float32))
    obj.set_points(points[[1, 5, 7]], 0.025)
    np.testing.assert_array_equal(obj.support, [1, 5, 7])
    obj.set_points(points[[1]] + 0.5, 0.025)
    assert obj.support is None


def test_points_few_views_agree_on_are_not_well_supported_unless_the_object_was_seen_once():
    seen_often = np.array([12, 11, 10, 12, 9, 1, 2, 10], np.float32)
    np.testing.assert_array_equal(geo.well_supported(seen_often), [1, 1, 1, 1, 1, 0, 0, 1])
    assert geo.well_supported(np.ones(8, np.float32)).all()


def test_a_noisy_wall_comes_back_onto_its_plane_and_keeps_its_extent():
    rng = np.random.default_rng(2)
    xy = rng.uniform(0, 1, (1500, 2))
    wall = np.column_stack([xy, rng.normal(0, 0.02, len(xy))]).astype(np.float32)
    flat = geo.onto_local_surface(wall)
    assert flat[:, 2].std() < 0.5 * wall[:, 2].std()  # range noise cut by about sqrt(k)
    np.testing.assert_allclose(flat[:, :2].min(axis=0), wall[:, :2].min(axis=0), atol=0.02)
    np.testing.assert_allclose(flat[:, :2].max(axis=0), wall[:, :2].max(axis=0), atol=0.02)


def test_a_pole_is_not_flattened_onto_a_plane():
    pole = np.stack([np.zeros(40), np.zeros(40), 0.03 * np.arange(40)], 1).astype(np.float32)
    pole += np.random.default_rng(3).normal(0, 0.002, pole.shape).astype(np.float32)
    np.testing.assert_array_equal(geo.onto_local_surface(pole), pole)


def test_a_part_few_views_have_shown_stays_while_a_tail_beside_a_well_seen_surface_goes():
    grid = np.stack(np.meshgrid(np.arange(20), np.arange(10)), -1).reshape(-1, 2) * 0.025
    front = np.column_stack([grid, np.zeros(len(grid))])  # seen by 10 views
    side = np.column_stack([np.full(len(grid), -0.3), grid[:, 0], grid[:, 1] + 0.05])
    tail = front[::20] + [0.0, 0.0, 0.03]  # a range-noise tail one voxel off the front
    points = np.concatenate([front, side, tail]).astype(np.float32)
    support = np.concatenate([np.full(len(front), 10.0), np.ones(len(side)), np.ones(len(tail))])
    kept = geo.locally_supported(points, support.astype(np.float32))
    assert kept[: len(front) + len(side)].all()  # the side, seen once so far, stays
    assert not kept[len(front) + len(side) :].any()
    assert not geo.well_supported(support.astype(np.float32))[len(front) :].any()


def _wall_with_a_far_skin(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A 1 m wall at z = 0 of 2.5 cm voxels eight views fused (3 mm noise), and 300 voxels
    only a far view or two reached (3 cm range noise): points float32 [N, 3], support [N]."""
    rng = np.random.default_rng(seed)
    grid = np.stack(np.meshgrid(np.arange(40), np.arange(40)), -1).reshape(-1, 2) * 0.025
    wall = np.column_stack([grid, rng.normal(0, 0.003, len(grid))])
    far = np.column_stack([rng.uniform(0, 0.975, (300, 2)), rng.normal(0, 0.03, 300)])
    support = np.concatenate([np.full(len(wall), 8.0), np.full(len(far), 2.0)])
    return np.concatenate([wall, far]).astype(np.float32), support.astype(np.float32)


def test_the_voxels_many_views_agree_on_set_the_local_surface_not_a_far_views_skin():
    points, support = _wall_with_a_far_skin(0)
    flat = geo.onto_local_surface(points, support=support)
    assert np.ptp(flat[:, 2]) < 0.02  # the skin (16 cm thick) onto the wall, within 1 cm
    assert np.ptp(geo.onto_local_surface(points)[:, 2]) > 0.03  # unweighted, it tilts planes
    np.testing.assert_allclose(
        np.ptp(flat[:, :2], axis=0), np.ptp(points[:, :2], axis=0), atol=0.01
    )


def test_a_pole_is_not_flattened_whatever_its_support():
    pole = np.stack([np.zeros(40), np.zeros(40), 0.03 * np.arange(40)], 1).astype(np.float32)
    pole += np.random.default_rng(3).normal(0, 0.002, pole.shape).astype(np.float32)
    support = np.random.default_rng(4).integers(1, 9, len(pole)).astype(np.float32)
    np.testing.assert_array_equal(geo.onto_local_surface(pole, support=support), pole)


def test_support_of_another_length_is_a_clear_error():
    points, support = _wall_with_a_far_skin(1)
    with pytest.raises(ValueError, match="support has 10 values"):
        geo.onto_local_surface(points, support=support[:10])
