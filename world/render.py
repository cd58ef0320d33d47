"""Ray-cast RGB-D + instance rendering of a Scene with open3d's RaycastingScene.

Pixel (u, v) (integer column and row) looks along the camera ray through
((u - cx) / fx, (v - cy) / fy, 1), so back-projecting a pixel with the camera's intrinsics
and its depth recovers the hit point exactly. Rays are cast with that un-normalised
direction, which makes the returned hit distance the z-depth directly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import open3d as o3d
import open3d.core as o3c

from world.scene import Scene


@dataclass(frozen=True)
class Camera:
    """Pinhole intrinsics of an image of width x height pixels."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @property
    def intrinsics(self) -> tuple[float, float, float, float]:
        """(fx, fy, cx, cy) in pixels."""
        return (self.fx, self.fy, self.cx, self.cy)


def camera_rays(camera: Camera) -> np.ndarray:
    """float32 [H*W, 3] ray directions in the camera frame with z = 1, row-major pixels."""
    u, v = np.meshgrid(
        np.arange(camera.width, dtype=np.float32), np.arange(camera.height, dtype=np.float32)
    )
    return np.stack(
        [(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones_like(u)], -1
    ).reshape(-1, 3)


def default_camera(width: int = 640, height: int = 480) -> Camera:
    """A 60 degree horizontal field of view with square pixels and a centred principal point."""
    f = (width / 2) / math.tan(math.radians(60.0) / 2)
    return Camera(width, height, f, f, (width - 1) / 2, (height - 1) / 2)


@dataclass
class View:
    """One rendered frame.

    rgb:          uint8 [H, W, 3]
    depth_m:      float32 [H, W] z-depth along the optical axis in metres, 0 where no hit
    instance_ids: uint16 [H, W] SceneObject.instance_id of the visible surface, 0 = none
    """

    rgb: np.ndarray
    depth_m: np.ndarray
    instance_ids: np.ndarray


# Two directional lights (a key light from above and a weaker fill) plus ambient: enough
# shading for surfaces of one colour to read as 3D without a global-illumination renderer.
_KEY_LIGHT = np.array([0.35, 0.55, 1.0], np.float32) / np.linalg.norm([0.35, 0.55, 1.0])
_FILL_LIGHT = np.array([-0.7, -0.4, 0.35], np.float32) / np.linalg.norm([-0.7, -0.4, 0.35])
_AMBIENT, _KEY, _FILL = 0.5, 0.45, 0.2

_TEXTURES = {"plain": 0, "planks": 1, "tiles": 2}
_GRAIN_PRIMES = np.array([73856093, 19349663, 83492791], np.int32)
_GRAIN_TABLE = np.random.default_rng(7).uniform(-1.0, 1.0, 4096).astype(np.float32)


class Renderer:
    """Renders views of one scene; builds the ray-casting acceleration structure once.

    All meshes go into one RaycastingScene as a single triangle set (about 25% faster to
    cast than one geometry per object); per-triangle tables map a hit triangle to its
    instance id, its lit colour (for either face) and its surface pattern.
    """

    def __init__(self, scene: Scene):
        self.scene = scene
        vertices, triangles, colors, instances, textures = [], [], [], [], []
        offset = 0
        for obj in scene.objects:
            v = np.asarray(obj.mesh.vertices, dtype=np.float32)
            t = np.asarray(obj.mesh.triangles, dtype=np.int64)
            if obj.mesh.has_vertex_colors():
                c = np.asarray(obj.mesh.vertex_colors, dtype=np.float32)[t[:, 0]] * 255.0
            else:
                c = np.tile(np.asarray(obj.color, np.float32), (len(t), 1))
            vertices.append(v)
            triangles.append(t + offset)
            colors.append(c)
            instances.append(np.full(len(t), obj.instance_id, np.uint16))
            textures.append(np.full(len(t), _TEXTURES.get(obj.texture, 0), np.uint8))
            offset += len(v)
        all_vertices = np.concatenate(vertices)
        all_triangles = np.concatenate(triangles)
        self._raycaster = o3d.t.geometry.RaycastingScene()
        self._raycaster.add_triangles(
            o3c.Tensor(all_vertices), o3c.Tensor(all_triangles.astype(np.uint32))
        )
        self._n_triangles = len(all_triangles)

        corners = all_vertices[all_triangles]
        normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
        self._normals = normals.astype(np.float32)
        self._anchor = corners[:, 0].astype(np.float32)
        albedo = np.concatenate(colors)

        def lit(n: np.ndarray) -> np.ndarray:
            shade = (
                _AMBIENT
                + _KEY * np.clip(n @ _KEY_LIGHT, 0, None)
                + _FILL * np.clip(n @ _FILL_LIGHT, 0, None)
            )
            return albedo * shade[:, None]

        # Row 2k: triangle k seen from the side its normal points to; row 2k+1: from behind
        # (two-sided lighting). The extra last row is the colour of rays that hit nothing.
        table = np.empty((2 * self._n_triangles + 1, 3), np.float32)
        table[0:-1:2] = lit(self._normals)
        table[1:-1:2] = lit(-self._normals)
        table[-1] = 0.0
        self._lit = table
        self._instance = np.concatenate([*instances, np.zeros(1, np.uint16)])
        self._texture = np.concatenate([*textures, np.zeros(1, np.uint8)])
        self._ray_cache: dict[Camera, np.ndarray] = {}

    def _camera_rays(self, camera: Camera) -> np.ndarray:
        """float32 [H*W, 3] ray directions in the camera frame with z = 1."""
        rays = self._ray_cache.get(camera)
        if rays is None:
            rays = self._ray_cache[camera] = camera_rays(camera)
        return rays

    def render(
        self,
        pose: np.ndarray,
        camera: Camera,
        texture_noise: float = 0.0,
        rng: np.random.Generator | None = None,
    ) -> View:
        """Render the view from `pose` (4x4 camera-to-world, OpenCV camera axes).

        texture_noise: relative amplitude of a fixed, world-anchored surface grain (the same on
            every frame, like real texture) plus, when `rng` is given, per-frame sensor noise
            of a third of that amplitude.
        """
        pose = np.asarray(pose, dtype=np.float64)
        h, w = camera.height, camera.width
        rotation = pose[:3, :3].astype(np.float32)
        origin = pose[:3, 3].astype(np.float32)
        directions = self._camera_rays(camera) @ rotation.T
        rays = np.empty((h * w, 6), np.float32)
        rays[:, :3] = origin
        rays[:, 3:] = directions
        hits = self._raycaster.cast_rays(o3c.Tensor.from_numpy(rays))
        t_hit = hits["t_hit"].numpy()
        hit = np.isfinite(t_hit)
        triangle = np.where(hit, hits["primitive_ids"].numpy(), self._n_triangles).astype(np.int64)
        depth = np.where(hit, t_hit, 0.0).astype(np.float32)
        instance_ids = self._instance[triangle]

        # Which face of each triangle the camera sees depends only on the camera position,
        # so the two-sided lighting is chosen per triangle, then gathered once per pixel.
        behind = np.einsum("ij,ij->i", self._normals, origin - self._anchor) < 0
        lit = self._lit[2 * np.arange(self._n_triangles + 1) + np.append(behind, False)]
        rgb = lit[triangle]

        texture = self._texture[triangle]
        factor = None
        if texture_noise > 0 or texture.any():
            points = directions * depth[:, None]
            points += origin
            factor = self._surface_pattern(points, texture, texture_noise)
        if rng is not None and texture_noise > 0:
            # Uniform noise with the std of texture_noise / 3 (cheaper to draw than normal).
            noise = rng.random(h * w, dtype=np.float32)
            noise -= 0.5
            noise *= math.sqrt(12.0) * texture_noise / 3
            noise += 1.0
            factor = noise if factor is None else factor * noise
        if factor is not None:
            rgb *= factor[:, None]
        np.clip(rgb, 0, 255, out=rgb)
        return View(
            rgb.astype(np.uint8).reshape(h, w, 3), depth.reshape(h, w), instance_ids.reshape(h, w)
        )

    @staticmethod
    def _surface_pattern(points: np.ndarray, texture: np.ndarray, grain: float) -> np.ndarray:
        """float32 [N] brightness factor: planks/tiles on floors plus a fine hashed grain."""
        if grain > 0:
            # 1 cm cells hashed (wrapping int32 arithmetic) into a table of random brightness
            # offsets: surface grain that stays put on the surface from frame to frame.
            cells = (points * 100.0).astype(np.int32)
            cells *= _GRAIN_PRIMES
            hashed = cells.sum(axis=1, dtype=np.int32)
            factor = _GRAIN_TABLE[hashed & (len(_GRAIN_TABLE) - 1)]
            factor *= grain
            factor += 1.0
        else:
            factor = np.ones(len(points), np.float32)
        planks = np.flatnonzero(texture == 1)
        if len(planks):
            p = points[planks]
            row = np.floor(p[:, 1] / 0.18)
            shifted = (p[:, 0] + (row * 0.37) % 1.0 * 1.2) / 1.2  # staggered plank ends
            col = np.floor(shifted)
            tone = ((row * 7 + col * 13) % 5) / 5.0
            seam = (np.abs(p[:, 1] / 0.18 - np.round(p[:, 1] / 0.18)) < 0.03) | (
                np.abs(shifted - np.round(shifted)) < 0.004
            )
            factor[planks] *= (0.9 + 0.16 * tone) * np.where(seam, 0.75, 1.0)
        tiles = np.flatnonzero(texture == 2)
        if len(tiles):
            p = points[tiles][:, :2] / 0.4
            grout = (np.abs(p - np.round(p)) < 0.02).any(axis=1)
            factor[tiles] *= np.where(grout, 0.7, 1.0)
        return factor
