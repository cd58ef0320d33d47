"""What the two walks of a revisit see of its changes: both walks ray cast at a small analysis
camera (instance ids and depth, no shading), and per changed or occluded object the frames
that see it and its places (`SeenFrames`), with the thresholds a change must reach to be kept."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d
import open3d.core as o3c

from world.render import Camera, camera_rays
from world.scene import Scene

SEEN_PX = 400
"""An object is seen in a frame when it covers this many pixels of a 640 x 480 image."""
MIN_SEEN_FRAMES = 20
"""Frames (four keyframes at one in five) in which a changed object or place must be seen."""
MIN_HIDDEN_FRAMES = 5
"""Second-walk frames in which an occlusion trap must hide what the first walk saw of its
object."""
HIDDEN_FRACTION = 0.5
"""A frame hides an object when its occluder covers this fraction of the object's first-walk
pixels."""
PLACE_VISIBLE_FRACTION = 0.7
"""A place counts as seen when this fraction of its pixels show it or what lies behind it."""

_REFERENCE_PX = 640 * 480
_DEPTH_TOL_M, _DEPTH_TOL_REL = 0.03, 0.01  # the engine's default absence tolerance


@dataclass(frozen=True)
class SeenFrames:
    """How many frames of each walk see a changed (or occluded) object and its places."""

    object_walk1: int
    """Frames of walk 1 showing the object (at its old place) with >= SEEN_PX pixels."""
    object_walk2: int
    """Frames of walk 2 showing the object (at its new place) with >= SEEN_PX pixels."""
    old_place_walk2: int
    """Frames of walk 2 showing its old place unobstructed: of the pixels walk 1 saw it at,
    PLACE_VISIBLE_FRACTION now show something at or behind it (moved and removed objects)."""
    new_place_walk1: int
    """Frames of walk 1 that saw its new place empty: of the pixels walk 2 sees it at, as many
    showed something at or behind it (moved and added objects)."""
    hidden_walk2: int
    """Frames of walk 2 in which its occluder covers HIDDEN_FRACTION of what walk 1 saw of it
    (occluded objects only)."""


@dataclass
class WalkImages:
    """A walk rendered at the analysis camera: instance ids, depth and id counts per frame."""

    ids: np.ndarray  # uint16 [N, H, W]
    depth: np.ndarray  # float32 [N, H, W], 0 = no hit
    counts: np.ndarray  # int64 [N, max_id + 1]


class _InstanceCaster:
    """Instance ids and z-depth of views of a scene: the Renderer's rays without the shading,
    which is most of its cost and which visibility counts do not need."""

    def __init__(self, scene: Scene):
        vertices, triangles, owners = [], [], []
        offset = 0
        for obj in scene.objects:
            v = np.asarray(obj.mesh.vertices, np.float32)
            t = np.asarray(obj.mesh.triangles, np.int64)
            vertices.append(v)
            triangles.append(t + offset)
            owners.append(np.full(len(t), obj.instance_id, np.uint16))
            offset += len(v)
        self._raycaster = o3d.t.geometry.RaycastingScene()
        self._raycaster.add_triangles(
            o3c.Tensor(np.concatenate(vertices)),
            o3c.Tensor(np.concatenate(triangles).astype(np.uint32)),
        )
        self._owner = np.concatenate([*owners, np.zeros(1, np.uint16)])  # last: no hit
        self._rays: dict[Camera, np.ndarray] = {}

    def cast(self, pose: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
        """(instance ids uint16 [H, W], z-depth float32 [H, W], 0 = no hit) from `pose`."""
        rays = self._rays.get(camera)
        if rays is None:
            rays = self._rays[camera] = camera_rays(camera)
        pose = np.asarray(pose, np.float64)
        batch = np.empty((len(rays), 6), np.float32)
        batch[:, :3] = pose[:3, 3]
        batch[:, 3:] = rays @ pose[:3, :3].T.astype(np.float32)
        hits = self._raycaster.cast_rays(o3c.Tensor.from_numpy(batch))
        t_hit = hits["t_hit"].numpy()
        hit = np.isfinite(t_hit)
        triangle = np.where(hit, hits["primitive_ids"].numpy(), len(self._owner) - 1)
        shape = (camera.height, camera.width)
        depth = np.where(hit, t_hit, 0.0).astype(np.float32)
        return self._owner[triangle.astype(np.int64)].reshape(shape), depth.reshape(shape)


def render_walk(scene: Scene, poses: list[np.ndarray], camera: Camera) -> WalkImages:
    caster = _InstanceCaster(scene)
    n_ids = max(o.instance_id for o in scene.objects) + 1
    ids = np.empty((len(poses), camera.height, camera.width), np.uint16)
    depth = np.empty((len(poses), camera.height, camera.width), np.float32)
    counts = np.empty((len(poses), n_ids), np.int64)
    for i, pose in enumerate(poses):
        ids[i], depth[i] = caster.cast(pose, camera)
        counts[i] = np.bincount(ids[i].ravel(), minlength=n_ids)[:n_ids]
    return WalkImages(ids, depth, counts)


def min_seen_px(camera: Camera) -> float:
    return SEEN_PX * camera.width * camera.height / _REFERENCE_PX


def _tolerance(depth: np.ndarray) -> np.ndarray:
    return _DEPTH_TOL_M + _DEPTH_TOL_REL * depth


def at_or_behind(observed: np.ndarray, expected: np.ndarray) -> np.ndarray:
    """Pixels whose observed depth shows the expected surface or something behind it."""
    return (observed == 0) | (observed >= expected - _tolerance(expected))


def count_seen(
    roles: dict[int, str],
    occluders: dict[int, int],
    poses: list[np.ndarray],
    camera: Camera,
    walk1: WalkImages | Scene,
    after: Scene,
) -> dict[int, SeenFrames]:
    """SeenFrames per id of `roles` (id -> "moved" | "removed" | "added" | "occluded"); walk 1
    is rendered from `walk1` when it is a Scene, walk 2 is rendered from `after`."""
    min_px = min_seen_px(camera)
    first = _InstanceCaster(walk1) if isinstance(walk1, Scene) else None
    second = _InstanceCaster(after)
    tally = {k: np.zeros(5, np.int64) for k in roles}
    for i, pose in enumerate(poses):
        if first is not None:
            ids1, depth1 = first.cast(pose, camera)
        else:
            ids1, depth1 = walk1.ids[i], walk1.depth[i]
        ids2, depth2 = second.cast(pose, camera)
        n = max(int(ids1.max()), int(ids2.max()), max(roles, default=0)) + 1
        counts1 = np.bincount(ids1.ravel(), minlength=n)
        counts2 = np.bincount(ids2.ravel(), minlength=n)
        for k, role in roles.items():
            row = tally[k]
            if role != "added" and counts1[k] >= min_px:
                row[0] += 1
                mask = ids1 == k
                if role == "occluded":
                    hidden = np.mean(ids2[mask] == occluders[k])
                    row[4] += hidden >= HIDDEN_FRACTION
                else:
                    place = at_or_behind(depth2[mask], depth1[mask])
                    row[2] += place.mean() >= PLACE_VISIBLE_FRACTION
            if role in ("moved", "added") and counts2[k] >= min_px:
                row[1] += 1
                mask = ids2 == k
                empty = at_or_behind(depth1[mask], depth2[mask])
                row[3] += empty.mean() >= PLACE_VISIBLE_FRACTION
    return {k: SeenFrames(*(int(x) for x in row)) for k, row in tally.items()}
