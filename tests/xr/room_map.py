"""A map of the feed's room as the server would hold it if perception were perfect: one
object per piece of furniture, its true surface points in the tracking frame (WebXR axes),
as a `semanticxr-map` export for POST /v1/sessions/import. The tiny random models the tests
run offline cannot name anything, so a test (or the README's screenshot) that needs the page
to draw a real answer where the thing is asks this map; the page still streams into it."""

from __future__ import annotations

import numpy as np
from scene_feed import TRACKING_FROM_WORLD, SceneFeed

POINTS_PER_OBJECT = 400


def surface_sample(mesh, n: int, rng: np.random.Generator) -> np.ndarray:
    """float64 [n, 3] points uniform over a triangle mesh's surface (area-weighted)."""
    vertices = np.asarray(mesh.vertices, np.float64)
    a, b, c = (vertices[np.asarray(mesh.triangles)[:, k]] for k in range(3))
    area = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    pick = rng.choice(len(area), size=n, p=area / area.sum())
    u, v = rng.random((2, n))
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    return a[pick] + u[:, None] * (b - a)[pick] + v[:, None] * (c - a)[pick]


def room_export(feed: SceneFeed, embedding: dict, name: str = "living room") -> dict:
    """The room's furniture as an export whose embedding is the server's (`embedding`: the
    {"model", "dim"} a session on it announces; labels are embedded on import)."""
    objects = []
    for i, obj in enumerate(o for o in feed.scene.objects if not o.is_background):
        world = surface_sample(obj.mesh, POINTS_PER_OBJECT, np.random.default_rng(i))
        pts = (world @ TRACKING_FROM_WORLD[:3, :3].T + TRACKING_FROM_WORLD[:3, 3]).round(4)
        objects.append(
            {
                "id": i + 1,
                "version": 1,
                "label": obj.category,
                "bbox": [*pts.min(0).tolist(), *pts.max(0).tolist()],
                "centroid": pts.mean(0).tolist(),
                "n_obs": 3,
                "points": pts.tolist(),
            }
        )
    session = {
        "name": name,
        "mode": "semanticxr",
        "knobs": {},
        "embedding": embedding,
        "perception": "models",
        "up": "+y",
    }
    return {"format": "semanticxr-map", "version": 1, "session": session, "objects": objects}
