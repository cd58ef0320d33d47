"""Geometry properties (hypothesis): lifting, batching, de-duplication, caps, boxes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from app.mapping import geometry as geo

finite = st.floats(-50, 50, allow_nan=False, width=32)
clouds = arrays(np.float32, st.tuples(st.integers(1, 300), st.just(3)), elements=finite)


def random_pose(rng: np.random.Generator) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = q, rng.normal(size=3)
    return pose


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), ratio=st.sampled_from([1, 2, 3, 5]))
def test_batched_lifting_equals_lifting_each_mask(seed, ratio):
    rng = np.random.default_rng(seed)
    width, height = 60, 45
    ids = rng.integers(0, 5, size=(height, width)).astype(np.uint16)
    depth = rng.uniform(0.0, 6.0, size=(height // ratio, width // ratio)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.1] = 0.0
    intr, pose = (50.0, 52.0, 29.5, 22.0), random_pose(rng)
    batched = geo.lift_instances_batched(ids, [1, 2, 3, 4], depth, intr, pose, 5.0)
    for iid in (1, 2, 3, 4):
        single = geo.lift_detection(ids == iid, depth, intr, pose, 5.0)
        np.testing.assert_allclose(
            np.sort(batched[iid], axis=0), np.sort(single, axis=0), atol=1e-5
        )


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_lifted_points_project_back_to_their_pixels_at_their_depth(seed):
    rng = np.random.default_rng(seed)
    pose, intr = random_pose(rng), (60.0, 60.0, 19.5, 14.5)
    # nearer than the range the lift smooths from: each sample is lifted at its own depth
    depth = rng.uniform(0.5, geo.SMOOTH_FROM_M, size=(30, 40)).astype(np.float32)
    pts = geo.lift_detection(np.ones((30, 40), bool), depth, intr, pose, 10.0)
    cam = (pts.astype(np.float64) - pose[:3, 3]) @ pose[:3, :3]
    u = cam[:, 0] / cam[:, 2] * intr[0] + intr[2]
    v = cam[:, 1] / cam[:, 2] * intr[1] + intr[3]
    vv, uu = np.nonzero(np.ones((30, 40), bool))
    np.testing.assert_allclose(u, uu, atol=1e-2)
    np.testing.assert_allclose(v, vv, atol=1e-2)
    np.testing.assert_allclose(cam[:, 2], depth[vv, uu], rtol=1e-4)


def test_invalid_depth_is_dropped():
    depth = np.array([[0.0, np.nan, np.inf, 9.0, 2.0, -1.0]], np.float32)
    pts = geo.lift_detection(np.ones((1, 6), bool), depth, (10.0, 10.0, 0.0, 0.0), np.eye(4), 8.0)
    assert len(pts) == 1 and pts[0, 2] == np.float32(2.0)


@settings(max_examples=60, deadline=None)
@given(points=clouds, voxel=st.floats(0.01, 2.0))
def test_voxel_downsample_keeps_one_point_per_voxel_inside_the_box(points, voxel):
    out = geo.voxel_downsample(points, voxel)
    assert 1 <= len(out) <= len(points)
    assert len(np.unique(geo._voxel_keys(out, voxel))) == len(out)
    box = geo.bbox_of(points)
    assert np.all(out >= box[:3] - 1e-3) and np.all(out <= box[3:] + 1e-3)


@settings(max_examples=60, deadline=None)
@given(points=clouds, voxel=st.floats(0.01, 2.0))
def test_voxel_downsample_is_the_mean_of_each_voxel_and_voxel_count_counts_them(points, voxel):
    out = geo.voxel_downsample(points, voxel)
    keys = geo._voxel_keys(points, voxel)
    uniq, inverse = np.unique(keys, return_inverse=True)
    expected = np.stack(
        [points[inverse.ravel() == i].astype(np.float64).mean(axis=0) for i in range(len(uniq))]
    )
    if len(uniq) == len(points):  # nothing to merge: the input, as it came
        np.testing.assert_array_equal(out, points)
    else:
        np.testing.assert_allclose(out, expected.astype(np.float32), rtol=1e-6, atol=1e-6)
    assert geo.voxel_count(points, voxel) == len(uniq) == len(geo.voxel_sample(points, voxel))


@settings(max_examples=60, deadline=None)
@given(points=clouds, cap=st.integers(1, 100))
def test_cap_always_holds_and_stays_within_the_object(points, cap):
    out, spacing = geo.cap_points(points, cap, 0.05)
    assert 1 <= len(out) <= cap and spacing >= 0.05
    box = geo.bbox_of(points)
    assert np.all(out >= box[:3] - 1e-3) and np.all(out <= box[3:] + 1e-3)


@settings(max_examples=60, deadline=None)
@given(points=clouds, cap=st.integers(1, 100), start=st.floats(0.01, 5.0))
def test_cap_from_a_start_spacing_holds_and_never_refines_it(points, cap, start):
    out, spacing = geo.cap_points(points, cap, 0.05, start_m=start)
    assert 1 <= len(out) <= cap
    if len(geo.voxel_downsample(points, 0.05)) > cap:  # capped: at least the start spacing
        assert spacing >= start
        assert len(np.unique(geo._voxel_keys(out, spacing))) == len(out) or len(out) == cap


@settings(max_examples=60, deadline=None)
@given(points=clouds, cap=st.integers(1, 100), max_spacing=st.floats(0.05, 2.0))
def test_a_density_cap_never_spreads_points_wider_than_its_spacing(points, cap, max_spacing):
    out, spacing = geo.cap_points(points, cap, 0.05, max_spacing_m=max_spacing)
    assert 0.05 <= spacing <= max_spacing
    if len(out) > cap:  # over the count: only because the spacing reached its ceiling
        assert spacing == max_spacing
        assert len(out) == geo.voxel_count(geo.voxel_downsample(points, 0.05), max_spacing)


def test_a_large_surface_keeps_its_density_under_a_density_cap():
    u, v = np.meshgrid(np.arange(0, 2.0, 0.01), np.arange(0, 1.0, 0.01))
    wall = np.stack([u.ravel(), v.ravel(), np.zeros(u.size)], axis=1).astype(np.float32)
    capped, spacing = geo.cap_points(wall, 200, 0.025)
    dense, dense_spacing = geo.cap_points(wall, 200, 0.025, max_spacing_m=0.04)
    assert len(capped) <= 200 and spacing > 0.09  # 2 m2 in 200 points: ~10 cm apart
    assert dense_spacing == 0.04 and len(dense) == 50 * 25


@settings(max_examples=60, deadline=None)
@given(
    sets=st.lists(
        arrays(np.float32, st.tuples(st.integers(0, 30), st.just(3)), elements=finite), max_size=5
    ),
    target=clouds,
    radius=st.floats(0.01, 20.0),
)
def test_batched_overlap_equals_overlap_of_each_set(sets, target, radius):
    from scipy.spatial import cKDTree

    tree = cKDTree(target)
    batched = geo.overlap_fractions(sets, tree, radius)
    assert batched.shape == (len(sets),)
    boxed = geo.overlap_fractions(sets, tree, radius, geo.bbox_of(target))
    np.testing.assert_array_equal(boxed, batched)
    for points, fraction in zip(sets, batched, strict=True):
        if len(points) == 0:
            assert fraction == 0.0
        else:
            dist, _ = tree.query(points, k=1)
            assert fraction == np.count_nonzero(dist <= radius) / len(points)


@settings(max_examples=60, deadline=None)
@given(points=clouds, voxel=st.floats(0.001, 0.1), far=st.floats(1e3, 1e5))
def test_voxel_keys_stay_exact_for_clouds_wider_than_21_bits_of_voxels(points, voxel, far):
    spread = np.concatenate([points, points + np.float32(far)]).astype(np.float32)
    keys = geo._voxel_keys(spread, voxel)
    cells = np.floor(spread / voxel)
    _, by_cell = np.unique(cells, axis=0, return_inverse=True)
    _, by_key = np.unique(keys, return_inverse=True)
    np.testing.assert_array_equal(by_cell.ravel(), by_key.ravel())  # same grouping, same order


@settings(max_examples=60, deadline=None)
@given(points=clouds, voxel=st.floats(0.01, 5.0))
def test_voxel_sample_keeps_per_voxel_the_point_nearest_its_centre(points, voxel):
    out = geo.voxel_sample(points, voxel)
    keys = geo._voxel_keys(points, voxel)
    offset = points / voxel - np.floor(points / voxel) - 0.5
    dist = np.einsum("ij,ij->i", offset, offset)
    assert len(out) == len(np.unique(keys))
    for point in out:
        same_voxel = np.all(np.floor(points / voxel) == np.floor(point / voxel), axis=1)
        chosen = np.flatnonzero(same_voxel & np.all(points == point, axis=1))[0]
        assert dist[chosen] == dist[same_voxel].min()


boxes = st.lists(finite, min_size=6, max_size=6).map(
    lambda v: np.array(
        [
            min(v[0], v[3]),
            min(v[1], v[4]),
            min(v[2], v[5]),
            max(v[0], v[3]),
            max(v[1], v[4]),
            max(v[2], v[5]),
        ]
    )
)


@settings(max_examples=80, deadline=None)
@given(a=boxes, b=boxes)
def test_box_intersection_is_symmetric_and_agrees_with_the_overlap_per_axis(a, b):
    ab = geo.bbox_intersects_matrix(a[None], b[None], 0.0)[0, 0]
    assert ab == geo.bbox_intersects_matrix(b[None], a[None], 0.0)[0, 0]
    overlap_m = [min(a[3 + k], b[3 + k]) - max(a[k], b[k]) for k in range(3)]
    assert ab == all(o >= 0 for o in overlap_m)


def test_overlap_fraction_counts_points_within_the_radius():
    from scipy.spatial import cKDTree

    tree = cKDTree(np.zeros((1, 3)))
    pts = np.array([[0.01, 0, 0], [0.02, 0, 0], [0.5, 0, 0], [0, 0, 0.024]])
    assert geo.overlap_fraction(pts, tree, 0.025) == 0.75


def test_outlier_removal_drops_a_far_stray_cluster():
    rng = np.random.default_rng(0)
    u, v = np.meshgrid(np.arange(20) * 0.025, np.arange(20) * 0.025)
    body = np.stack([u.ravel(), v.ravel(), np.zeros(400)], axis=1).astype(np.float32)
    stray = rng.uniform(3, 3.05, size=(20, 3)).astype(np.float32)
    kept = geo.remove_outliers(np.concatenate([body, stray]), eps_m=0.1)
    assert len(kept) == 400 and kept.max() <= 0.5


def _plane(n_side: int, spacing: float, origin=(0.0, 0.0, 0.0)) -> np.ndarray:
    u, v = np.meshgrid(np.arange(n_side) * spacing, np.arange(n_side) * spacing)
    return (np.stack([u.ravel(), v.ravel(), np.zeros(u.size)], axis=1) + origin).astype(np.float32)


def test_outlier_removal_drops_lone_points_and_keeps_the_largest_of_two_bodies():
    body, smaller = _plane(20, 0.025), _plane(8, 0.025, origin=(2.0, 0.0, 0.0))
    lone = np.array([[0.8, 0.8, 0.8], [-0.6, 0.2, 0.1]], np.float32)  # nothing within 10 cm
    kept = geo.remove_outliers(np.concatenate([body, smaller, lone]), eps_m=0.1)
    np.testing.assert_array_equal(np.sort(kept, axis=0), np.sort(body, axis=0))


def test_outlier_removal_keeps_a_thin_edge_joined_to_the_body():
    # a handle one point thick, 2.5 cm apart: each has 4 to 8 others within eps
    body = _plane(20, 0.025)
    handle = np.stack([0.475 + 0.025 * np.arange(1, 21), np.zeros(20), np.zeros(20)], 1)
    cloud = np.concatenate([body, handle.astype(np.float32)])
    assert len(geo.remove_outliers(cloud, eps_m=0.1)) == len(cloud)


@given(st.lists(st.floats(-50, 50), min_size=3, max_size=3))
def test_outlier_removal_does_not_depend_on_where_the_object_is(offset):
    rng = np.random.default_rng(1)
    cloud = np.concatenate(
        [_plane(15, 0.025), rng.uniform(0.6, 1.5, size=(12, 3)).astype(np.float32)]
    )
    moved = cloud + np.asarray(offset, np.float32)
    kept, kept_moved = geo.remove_outliers(cloud, 0.1), geo.remove_outliers(moved, 0.1)
    assert len(kept) == len(kept_moved) == 225


@given(st.lists(st.floats(-5, 5), min_size=3, max_size=3), st.floats(0.01, 2))
def test_box_iou_is_one_with_itself_and_zero_apart(corner, size):
    box = np.array([*corner, *(c + size for c in corner)])
    assert geo.bbox_iou(box, box) == pytest.approx(1.0)
    far = box + np.array([10.0] * 6)
    assert geo.bbox_iou(box, far) == 0.0


def test_a_box_inside_another_is_wholly_inside_and_not_the_other_way():
    small = np.array([0.0, 0, 0, 1, 1, 1])
    large = np.array([-1.0, -1, -1, 2, 2, 2])
    assert geo.bbox_inside_fraction(small, large) == pytest.approx(1.0)
    assert geo.bbox_inside_fraction(large, small) == pytest.approx(1 / 27)


@given(st.integers(1, 40), st.lists(st.tuples(st.integers(0, 39), st.integers(0, 39)), max_size=80))
def test_components_match_a_graph_search(n, pairs):
    edges = np.array([(a, b) for a, b in pairs if a < n and b < n], np.int64).reshape(-1, 2)
    roots = geo._components(n, edges)
    neighbours = {i: set() for i in range(n)}
    for a, b in edges:
        neighbours[a].add(b)
        neighbours[b].add(a)
    for start in range(n):  # the component found by a search has one root, its smallest node
        seen, todo = {start}, [start]
        while todo:
            for other in neighbours[todo.pop()] - seen:
                seen.add(other)
                todo.append(other)
        assert {int(roots[i]) for i in seen} == {min(seen)}
