"""Mesh primitives: a coloured triangle soup (`Parts`) with boxes, cones, cylinders and
ellipsoids, and the rotations the furniture builders pose them with. No world knowledge."""

from __future__ import annotations

import math

import numpy as np

# Outward-wound box faces over corners indexed by bits (x + 2y + 4z).
_BOX_QUADS = np.array(
    [[0, 4, 6, 2], [1, 3, 7, 5], [0, 1, 5, 4], [2, 6, 7, 3], [0, 2, 3, 1], [4, 5, 7, 6]]
)
_BOX_TRIS = np.concatenate([_BOX_QUADS[:, [0, 1, 2]], _BOX_QUADS[:, [0, 2, 3]]])
_BOX_CORNERS = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], float)


def rot_z(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_x(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def shade(color: np.ndarray, factor: float) -> np.ndarray:
    return np.clip(np.asarray(color, float) * factor, 0, 255)


class Parts:
    """Coloured triangle soup of one object in its own frame."""

    def __init__(self) -> None:
        self.vertices: list[np.ndarray] = []
        self.triangles: list[np.ndarray] = []
        self.colors: list[np.ndarray] = []
        self._count = 0

    def add(self, vertices: np.ndarray, triangles: np.ndarray, color: np.ndarray) -> None:
        self.vertices.append(np.asarray(vertices, float))
        self.triangles.append(np.asarray(triangles, np.int64) + self._count)
        self.colors.append(np.broadcast_to(np.asarray(color, float) / 255.0, vertices.shape))
        self._count += len(vertices)

    def box(
        self,
        lo: tuple[float, float, float],
        hi: tuple[float, float, float],
        color: np.ndarray,
        rotation: np.ndarray | None = None,
        pivot: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> None:
        """Axis-aligned box [lo, hi], optionally rotated about `pivot`."""
        lo_a, hi_a = np.asarray(lo, float), np.asarray(hi, float)
        v = lo_a + _BOX_CORNERS * (hi_a - lo_a)
        if rotation is not None:
            v = (v - pivot) @ rotation.T + pivot
        self.add(v, _BOX_TRIS, color)

    def frustum(
        self,
        base: tuple[float, float, float],
        r_bottom: float,
        r_top: float,
        height: float,
        color: np.ndarray,
        segments: int = 16,
        rotation: np.ndarray | None = None,
        scale_xy: tuple[float, float] = (1.0, 1.0),
    ) -> None:
        """Closed (truncated) cone along +z from `base`; `rotation` turns it about `base`."""
        a = np.linspace(0.0, 2 * math.pi, segments, endpoint=False)
        ring = np.stack([np.cos(a) * scale_xy[0], np.sin(a) * scale_xy[1], np.zeros_like(a)], 1)
        bottom = ring * [r_bottom, r_bottom, 0]
        top = ring * [r_top, r_top, 0] + [0, 0, height]
        v = np.concatenate([bottom, top, [[0, 0, 0]], [[0, 0, height]]])
        i = np.arange(segments)
        j = (i + 1) % segments
        n = segments
        side = np.concatenate([np.stack([i, j, j + n], 1), np.stack([i, j + n, i + n], 1)])
        caps = np.concatenate(
            [
                np.stack([np.full(n, 2 * n), j, i], 1),
                np.stack([np.full(n, 2 * n + 1), i + n, j + n], 1),
            ]
        )
        if rotation is not None:
            v = v @ rotation.T
        self.add(v + base, np.concatenate([side, caps]), color)

    def cylinder(
        self,
        base: tuple[float, float, float],
        radius: float,
        height: float,
        color: np.ndarray,
        segments: int = 16,
        rotation: np.ndarray | None = None,
    ) -> None:
        self.frustum(base, radius, radius, height, color, segments, rotation)

    def ellipsoid(
        self,
        center: tuple[float, float, float],
        radii: tuple[float, float, float],
        color: np.ndarray,
        rings: int = 7,
        segments: int = 12,
    ) -> None:
        """Closed UV ellipsoid."""
        theta = np.linspace(0.0, math.pi, rings + 1)[1:-1]  # polar angles without the poles
        phi = np.linspace(0.0, 2 * math.pi, segments, endpoint=False)
        st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
        ring_pts = np.stack(
            [st * np.cos(phi), st * np.sin(phi), np.broadcast_to(ct, (len(theta), segments))], -1
        ).reshape(-1, 3)
        v = np.concatenate([[[0, 0, 1]], ring_pts, [[0, 0, -1]]]) * radii + center
        tris = []
        s = segments
        j = np.arange(s)
        jn = (j + 1) % s
        tris.append(np.stack([np.zeros(s, int), 1 + j, 1 + jn], 1))
        for r in range(len(theta) - 1):
            a, b = 1 + r * s + j, 1 + r * s + jn
            c, d = a + s, b + s
            tris.append(np.stack([a, c, d], 1))
            tris.append(np.stack([a, d, b], 1))
        last = 1 + (len(theta) - 1) * s
        south = len(v) - 1
        tris.append(np.stack([np.full(s, south), last + jn, last + j], 1))
        self.add(v, np.concatenate(tris), color)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(vertices float [N, 3], triangles int [M, 3], colours float [N, 3] in [0, 1])."""
        return (
            np.concatenate(self.vertices),
            np.concatenate(self.triangles),
            np.concatenate(self.colors),
        )


def quad(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two triangles over 4 corners given counter-clockwise seen from the visible side."""
    return corners, np.array([[0, 1, 2], [0, 2, 3]])
