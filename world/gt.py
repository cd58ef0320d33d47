"""Ground-truth labelled point cloud of a Scene, for semantic-map evaluation.

Every surface is sampled uniformly by area (about one point per spacing^2). Faces that touch
another surface -- the bottom of a mug on a table, the table top under it, the wall behind a
painting -- can never be observed, so samples with another surface within CONTACT_M in front
of them are dropped; otherwise they would count as misses against every map.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d
import open3d.core as o3c

from world.scene import Scene

CONTACT_M = 0.015


@dataclass
class GroundTruthCloud:
    """Labelled surface samples.

    points:       float32 [N, 3] world metres
    instance_ids: int32 [N] SceneObject.instance_id of each point
    class_names:  sorted class names present (background classes included)
    class_idx:    int32 [N] index into class_names
    """

    points: np.ndarray
    instance_ids: np.ndarray
    class_names: list[str]
    class_idx: np.ndarray

    def __len__(self) -> int:
        return len(self.points)


def gt_point_cloud(scene: Scene, spacing_m: float = 0.02, seed: int = 0) -> GroundTruthCloud:
    """Sample every object's visible surfaces about every `spacing_m` metres (deterministic)."""
    if spacing_m <= 0:
        raise ValueError(f"spacing_m must be > 0, got {spacing_m}")
    rng = np.random.default_rng(seed)
    raycaster = o3d.t.geometry.RaycastingScene()
    points, normals, instance_ids = [], [], []
    for obj in scene.objects:
        vertices = np.asarray(obj.mesh.vertices, dtype=np.float64)
        triangles = np.asarray(obj.mesh.triangles, dtype=np.int64)
        raycaster.add_triangles(
            o3c.Tensor(vertices.astype(np.float32)), o3c.Tensor(triangles.astype(np.uint32))
        )
        p, n = _sample_triangles(vertices[triangles], spacing_m, rng)
        points.append(p)
        normals.append(n)
        instance_ids.append(np.full(len(p), obj.instance_id, np.int32))
    points_a = np.concatenate(points)
    normals_a = np.concatenate(normals)
    ids = np.concatenate(instance_ids)

    # A short ray along the outward normal: a hit within CONTACT_M means the face is covered.
    rays = np.concatenate([points_a + normals_a * 1e-4, normals_a], axis=1).astype(np.float32)
    t_hit = raycaster.cast_rays(o3c.Tensor.from_numpy(rays))["t_hit"].numpy()
    visible = ~(t_hit < CONTACT_M)
    points_a, ids = points_a[visible], ids[visible]

    category_of = {o.instance_id: o.category for o in scene.objects}
    class_names = sorted({category_of[i] for i in np.unique(ids)})
    lut = {name: k for k, name in enumerate(class_names)}
    unique_ids, inverse = np.unique(ids, return_inverse=True)
    class_of_unique = np.array([lut[category_of[int(i)]] for i in unique_ids], np.int32)
    return GroundTruthCloud(
        points=points_a.astype(np.float32),
        instance_ids=ids.astype(np.int32),
        class_names=class_names,
        class_idx=class_of_unique[inverse].astype(np.int32),
    )


def _sample_triangles(corners: np.ndarray, spacing_m: float, rng: np.random.Generator):
    """Area-stratified samples: (points [K, 3], unit normals [K, 3]) over triangles [M, 3, 3]."""
    e1 = corners[:, 1] - corners[:, 0]
    e2 = corners[:, 2] - corners[:, 0]
    cross = np.cross(e1, e2)
    double_area = np.linalg.norm(cross, axis=1)
    expected = 0.5 * double_area / spacing_m**2
    # floor(expected + u) has the right mean per triangle and at most one point of jitter.
    counts = np.floor(expected + rng.random(len(expected))).astype(np.int64)
    tri = np.repeat(np.arange(len(corners)), counts)
    if len(tri) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    r1 = np.sqrt(rng.random(len(tri)))
    r2 = rng.random(len(tri))
    a, b = 1.0 - r1, r1 * (1.0 - r2)
    c = r1 * r2
    points = (
        a[:, None] * corners[tri, 0] + b[:, None] * corners[tri, 1] + c[:, None] * corners[tri, 2]
    )
    normals = cross[tri] / np.maximum(double_area[tri], 1e-12)[:, None]
    return points, normals
