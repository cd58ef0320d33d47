"""A room of sampled-point boxes with duplicate categories in distinct relations (three mugs
on a desk, a shelf and a table; a chair at the desk and one next to the sofa; a bag under
the table): Z-up, metres. For the relational query tests; its shapes (`faces`, `block`,
`table`, `chair`) serve the relation tests too."""

from __future__ import annotations

import numpy as np


def faces(parts, count: int = 200, seed: int = 0) -> np.ndarray:
    """float64 [count, 3]: points on the faces of boxes ((x0, y0, z0), (x1, y1, z1))."""
    rng = np.random.default_rng(seed)
    lo = np.array([p[0] for p in parts], np.float64)
    hi = np.array([p[1] for p in parts], np.float64)
    size = np.maximum(hi - lo, 1e-3)
    areas = np.stack([size[:, 1] * size[:, 2], size[:, 0] * size[:, 2], size[:, 0] * size[:, 1]])
    weights = np.repeat(areas.T, 2, axis=1).ravel()
    pick = rng.choice(len(weights), count, p=weights / weights.sum())
    box, axis, side = pick // 6, (pick % 6) // 2, pick % 2
    points = lo[box] + rng.uniform(0, 1, (count, 3)) * size[box]
    points[np.arange(count), axis] = np.where(side == 0, lo[box, axis], hi[box, axis])
    return points


def block(x, y, z, w, d, h, seed: int = 0, count: int = 150) -> np.ndarray:
    return faces([((x, y, z), (x + w, y + d, z + h))], count, seed)


def table(x, y, w=1.6, d=0.9, h=0.75, seed: int = 0, count: int = 300) -> np.ndarray:
    """A top on four legs: the space under it is empty."""
    leg = 0.05
    parts = [((x, y, h - 0.04), (x + w, y + d, h))]
    parts += [
        ((lx, ly, 0.0), (lx + leg, ly + leg, h - 0.04))
        for lx in (x, x + w - leg)
        for ly in (y, y + d - leg)
    ]
    return faces(parts, count, seed)


def chair(x, y, seed: int = 0) -> np.ndarray:
    parts = [
        ((x, y, 0.42), (x + 0.45, y + 0.45, 0.46)),
        ((x, y + 0.41, 0.46), (x + 0.45, y + 0.45, 0.9)),
    ]
    parts += [
        ((x + dx, y + dy, 0.0), (x + dx + 0.04, y + dy + 0.04, 0.42))
        for dx in (0, 0.41)
        for dy in (0, 0.41)
    ]
    return faces(parts, 200, seed)


# id -> (label, points): Z-up, metres
SCENE = {
    1: ("desk", table(0.0, 0.0, w=1.2, d=0.6, seed=1)),
    2: ("shelf", block(3.0, 0.0, 0.0, 0.8, 0.3, 1.2, seed=2)),
    3: ("table", table(0.0, 3.0, seed=3)),
    4: ("sofa", block(5.0, 3.0, 0.0, 2.0, 0.9, 0.8, seed=4)),
    10: ("mug", block(0.5, 0.2, 0.75, 0.08, 0.08, 0.1, seed=10)),  # on the desk
    11: ("mug", block(3.3, 0.1, 1.2, 0.08, 0.08, 0.1, seed=11)),  # on the shelf
    12: ("mug", block(1.0, 3.4, 0.75, 0.08, 0.08, 0.1, seed=12)),  # on the table
    20: ("chair", chair(0.3, -0.65, seed=20)),  # at the desk
    21: ("chair", chair(4.4, 3.2, seed=21)),  # next to the sofa
    30: ("bag", block(0.5, 3.2, 0.0, 0.4, 0.3, 0.3, seed=30)),  # under the table
}


TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
"""(x, y, z) Z-up -> (x, z, -y) Y-up: the same room in an XR runtime's frame."""


def map_export(room: dict, name: str, knobs: dict | None = None, turn=None, **session) -> dict:
    """A room ({id: (label, points)}) as a `semanticxr-map` export for POST
    /v1/sessions/import: ids kept, points to 0.1 mm as the export format keeps them, turned
    by `turn` (a 3x3 matrix) when given; `session` adds fields (e.g. up="+y"). No pose: up
    is the session's (Z unless set), and the asker's position is unknown."""
    objects = []
    for i, (label, points) in room.items():
        pts = (points if turn is None else points @ np.asarray(turn).T).round(4)
        objects.append(
            {
                "id": i,
                "version": 1,
                "label": label,
                "bbox": [*pts.min(0).tolist(), *pts.max(0).tolist()],
                "centroid": pts.mean(0).tolist(),
                "n_obs": 3,
                "points": pts.tolist(),
            }
        )
    return {
        "format": "semanticxr-map",
        "version": 1,
        "session": {
            "name": name,
            "mode": "semanticxr",
            "knobs": knobs or {},
            "embedding": {"model": "all-MiniLM-L6-v2", "dim": 384},
            **session,
        },
        "objects": objects,
    }


def scene_export(name: str = "relations") -> dict:
    """SCENE as an import (`map_export`)."""
    return map_export(SCENE, name)
