"""Lifting averages a sample's range noise with its neighbours on the same surface: a far
view's skin gets thinner, a plane stays where it is, and no depth step is smeared."""

from __future__ import annotations

import numpy as np

from app.mapping import geometry as geo

WIDTH, HEIGHT = 160, 120
INTRINSICS = (150.0, 150.0, (WIDTH - 1) / 2, (HEIGHT - 1) / 2)


def _noisy(depth: np.ndarray, sigma_m: float, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return (depth + sigma_m * rng.standard_normal(depth.shape)).astype(np.float32)


def test_range_noise_on_a_far_plane_is_averaged_down():
    true = np.full((HEIGHT, WIDTH), 4.0, np.float32)
    ids = np.zeros((HEIGHT, WIDTH), np.uint16)
    ids[20:100, 30:130] = 1
    depth = _noisy(true, 0.03)
    lifted = geo.lift_instances_batched(ids, [1], depth, INTRINSICS, np.eye(4), 10.0)[1]
    raw = depth[20:100, 30:130]
    assert len(lifted) > 0.9 * raw.size
    # the mean of up to 9 samples: about a third of the per-sample scatter
    assert np.std(lifted[:, 2] - 4.0) < 0.5 * np.std(raw - 4.0)
    assert abs(np.mean(lifted[:, 2]) - 4.0) < 0.005
    # the skin's thickness (its 1-99 % spread) shrinks less: rim samples have fewer neighbours
    spread = np.diff(np.percentile(lifted[:, 2], [1, 99]))[0]
    assert spread < 0.6 * np.diff(np.percentile(raw, [1, 99]))[0]


def test_a_slanted_plane_is_not_bent():
    v, u = np.mgrid[0:HEIGHT, 0:WIDTH]
    depth = (3.0 + 0.01 * u).astype(np.float32)  # a surface sloping away to the right
    ids = np.zeros((HEIGHT, WIDTH), np.uint16)
    ids[10:110, 10:150] = 3
    lifted = geo.lift_instances_batched(ids, [3], depth, INTRINSICS, np.eye(4), 10.0)[3]
    unsmoothed = geo.backproject(
        u[ids == 3], v[ids == 3], depth[ids == 3].astype(np.float64), INTRINSICS, np.eye(4)
    )
    inner = (u[ids == 3] > 11) & (u[ids == 3] < 148) & (v[ids == 3] > 11) & (v[ids == 3] < 108)
    by_pixel = {tuple(p): True for p in np.round(lifted, 4)}
    assert all(tuple(p) in by_pixel for p in np.round(unsmoothed[inner], 4))


def test_two_things_side_by_side_and_a_step_are_not_averaged_together():
    depth = np.full((HEIGHT, WIDTH), 5.0, np.float32)
    ids = np.zeros((HEIGHT, WIDTH), np.uint16)
    ids[20:100, 20:80] = 1  # a thing at 3.5 m ...
    depth[20:100, 20:80] = 3.5
    ids[20:100, 80:140] = 2  # ...and the next one, touching it, at 3.6 m
    depth[20:100, 80:140] = 3.6
    depth[20:100, 20:40] = 3.3  # a step of 20 cm inside the first thing's own mask
    lifted = geo.lift_instances_batched(ids, [1, 2], depth, INTRINSICS, np.eye(4), 10.0)
    z = lifted[1][:, 2]
    assert np.all(np.isclose(z, 3.3, atol=1e-6) | np.isclose(z, 3.5, atol=1e-6))
    assert np.isclose(z, 3.3, atol=1e-6).any() and np.isclose(z, 3.5, atol=1e-6).any()
    np.testing.assert_allclose(lifted[2][:, 2], 3.6, atol=1e-6)


def test_a_patch_lift_averages_too_and_both_lifts_agree_on_one_mask():
    true = np.full((HEIGHT, WIDTH), 3.0, np.float32)
    depth = _noisy(true, 0.02, seed=1)
    ids = np.zeros((HEIGHT, WIDTH), np.uint16)
    ids[30:90, 40:120] = 5
    patch = geo.lift_in_patch(
        ids, 5, (40, 30, 120, 90), depth[30:90, 40:120], INTRINSICS, np.eye(4), 10.0
    )
    assert np.std(patch[:, 2] - 3.0) < 0.5 * np.std(depth[30:90, 40:120] - 3.0)
    one = geo.lift_detection(ids == 5, depth, INTRINSICS, np.eye(4), 10.0)
    many = geo.lift_instances_batched(ids, [5], depth, INTRINSICS, np.eye(4), 10.0)[5]
    np.testing.assert_array_equal(one, many)


def test_a_slanted_plane_keeps_its_place_on_the_mask_edge_too():
    v, u = np.mgrid[0:HEIGHT, 0:WIDTH]
    depth = (3.0 + 0.02 * u + 0.01 * v).astype(np.float32)  # steep: 2 cm a pixel
    ids = np.zeros((HEIGHT, WIDTH), np.uint16)
    ids[10:110, 10:150] = 3
    lifted = geo.lift_instances_batched(ids, [3], depth, INTRINSICS, np.eye(4), 10.0)[3]
    # every lifted point lies on the plane: z = 2 + 0.02 u + 0.01 v with u, v from x / z, y / z
    fx, fy, cx, cy = INTRINSICS
    uu = lifted[:, 0] / lifted[:, 2] * fx + cx
    vv = lifted[:, 1] / lifted[:, 2] * fy + cy
    np.testing.assert_allclose(lifted[:, 2], 3.0 + 0.02 * uu + 0.01 * vv, atol=1e-4)


def test_a_near_view_is_lifted_as_measured():
    depth = _noisy(np.full((HEIGHT, WIDTH), 1.5, np.float32), 0.01)
    ids = np.zeros((HEIGHT, WIDTH), np.uint16)
    ids[20:100, 30:130] = 1
    lifted = geo.lift_instances_batched(ids, [1], depth, INTRINSICS, np.eye(4), 10.0)[1]
    np.testing.assert_allclose(
        np.sort(lifted[:, 2]), np.sort(depth[20:100, 30:130].ravel()), atol=1e-6
    )
