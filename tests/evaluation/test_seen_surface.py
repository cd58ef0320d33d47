"""F-mIoU over the seen surfaces: a ground-truth point counts as seen only when a keyframe's
true depth shows it (docs/evaluation.md "Geometry")."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import open3d.core as o3c
import pytest

from evaluation.walk import SEEN_DEPTH_M, SeenSurface, seen_by_view
from world.gt import gt_point_cloud
from world.render import Renderer, default_camera
from world.scene import Room, Scene, SceneObject

CAMERA = default_camera(160, 120)


def _box(instance_id: int, category: str, lo, hi) -> SceneObject:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    mesh = o3d.geometry.TriangleMesh.create_box(*(hi - lo))
    mesh.translate(lo)
    bbox = np.concatenate([lo, hi])
    return SceneObject(instance_id, category, mesh, (180, 180, 180), (lo + hi) / 2, bbox)


def _scene() -> Scene:
    """Looking along +y from the origin: a box 1 m ahead, a wall 2 m ahead (with a hole on
    the right), and a box behind the wall, another in the hole."""
    return Scene(
        "seen",
        0,
        [
            _box(1, "table", [-0.3, 1.0, -0.3], [0.3, 1.3, 0.3]),
            _box(2, "wall", [-3.0, 2.0, -2.0], [0.6, 2.1, 2.0]),
            _box(3, "chair", [-0.5, 3.0, -0.5], [0.5, 3.5, 0.5]),  # behind the wall
            _box(4, "sofa", [1.0, 3.0, -0.3], [1.4, 3.3, 0.3]),  # seen through the hole
        ],
        [Room("living_room", (-3.0, -1.0, 3.0, 4.0), 2.7)],
    )


def _pose(origin=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Camera-to-world, OpenCV axes: x right (+x), y down (-z), looking along +y."""
    pose = np.eye(4)
    pose[:3, :3] = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float).T
    pose[:3, 3] = origin
    return pose


def test_a_point_behind_a_wall_or_a_box_or_out_of_view_is_not_seen():
    scene, pose = _scene(), _pose()
    depth = Renderer(scene).render(pose, CAMERA).depth_m
    points = np.array(
        [
            [0.0, 1.0, 0.0],  # the near box's front face: seen
            [0.0, 1.3, 0.0],  # its back face, 0.3 m behind the front: not seen
            [-1.0, 2.0, 0.0],  # the wall's face beside the box: seen
            [0.0, 3.0, 0.0],  # the chair behind the wall: not seen
            [-1.0, 3.0, 0.0],  # ... also where the wall alone hides it
            [1.2, 3.0, 0.0],  # the sofa seen through the hole in the wall: seen
            [0.0, -1.0, 0.0],  # behind the camera: not seen
            [5.0, 1.0, 0.0],  # out of the field of view: not seen
        ]
    )
    assert seen_by_view(points, depth, pose, CAMERA).tolist() == [
        True,
        False,
        True,
        False,
        False,
        True,
        False,
        False,
    ]
    # Just behind the visible surface is within the tolerance; further is not.
    near = np.array([[0.0, 1.0 + SEEN_DEPTH_M / 2, 0.0], [0.0, 1.0 + 2 * SEEN_DEPTH_M, 0.0]])
    assert seen_by_view(near, depth, pose, CAMERA).tolist() == [True, False]


def test_seen_agrees_with_a_ray_cast_to_each_ground_truth_point():
    """An independent oracle: a point is visible when nothing lies between it and the camera
    (a ray from the camera hits no surface before it), and it is in the image."""
    scene, pose = _scene(), _pose((0.1, 0.2, 0.15))
    gt = gt_point_cloud(scene, spacing_m=0.03)
    depth = Renderer(scene).render(pose, CAMERA).depth_m
    seen = seen_by_view(gt.points, depth, pose, CAMERA)

    raycaster = o3d.t.geometry.RaycastingScene()
    for obj in scene.objects:
        raycaster.add_triangles(
            o3c.Tensor(np.asarray(obj.mesh.vertices, np.float32)),
            o3c.Tensor(np.asarray(obj.mesh.triangles, np.uint32)),
        )
    origin = pose[:3, 3]
    offset = gt.points - origin
    distance = np.linalg.norm(offset, axis=1)
    rays = np.concatenate([np.tile(origin, (len(gt.points), 1)), offset / distance[:, None]], 1)
    first_hit = raycaster.cast_rays(o3c.Tensor(rays.astype(np.float32)))["t_hit"].numpy()
    local = offset @ pose[:3, :3]
    fx, fy, cx, cy = CAMERA.intrinsics
    u = fx * local[:, 0] / local[:, 2] + cx
    v = fy * local[:, 1] / local[:, 2] + cy
    in_image = (
        (local[:, 2] > 0) & (u > 1) & (u < CAMERA.width - 2) & (v > 1) & (v < CAMERA.height - 2)
    )
    visible = in_image & (first_hit >= distance - 0.005)
    hidden = in_image & (first_hit < distance - 0.05)  # something at least 5 cm in front
    assert visible.sum() > 200 and hidden.sum() > 200
    assert seen[visible].mean() > 0.97
    assert seen[hidden].mean() < 0.03
    assert not seen[~in_image & (local[:, 2] <= 0)].any()
    # The chair stands wholly behind the wall: none of it is seen.
    assert not seen[gt.instance_ids == 3].any()
    assert seen[gt.instance_ids == 4].any()


def test_the_seen_surface_is_the_union_over_the_keyframes():
    scene = _scene()
    gt = gt_point_cloud(scene, spacing_m=0.03)
    renderer = Renderer(scene)
    poses = [_pose(), _pose((-2.0, 0.0, 0.0))]
    surface = SeenSurface(gt.points)
    each = []
    for pose in poses:
        depth = renderer.render(pose, CAMERA).depth_m
        surface.look(depth, pose, CAMERA)
        each.append(seen_by_view(gt.points, depth, pose, CAMERA))
    assert np.array_equal(surface.seen, each[0] | each[1])
    assert (each[1] & ~each[0]).any()  # the second view adds what the first did not see


def test_a_depth_image_of_another_size_is_refused():
    with pytest.raises(ValueError, match="depth_m"):
        seen_by_view(np.zeros((1, 3)), np.zeros((10, 10), np.float32), _pose(), CAMERA)
