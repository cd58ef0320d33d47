"""A room of our own, built as a sensor would see it, for an independent client.

Written from the documented contract only (README.md, docs/protocol.md): the map goes in
through `POST /v1/sessions/import` as a JSON export (`format: semanticxr-map`), one object
per thing, each with points sampled on the surfaces a depth camera would see (no bottom
faces, a few points dropped, 3 mm of noise). No pose is ever sent, so the map's up axis
is z (docs/protocol.md: "z without one"); the floor is z = 0. Metres.

The room, about 6.2 m x 5 m:

    y=5 +-------------------------------------------------------------+
        |                 [shelf: mug3]                               |
        |                        [chairB][ sofa + cushion ] [floor lamp]|
        | [side table                                                  |
        |  + table lamp]         [chairC]                              |
        |               [dining table: book2, bottle; bagB under]      |
        |      [box]                                                   |
        | [chairA + bagA]                       [plant]                |
        | [desk: books1, laptop, mug1; bin under] [counter: kettle, mug2]|
    y=0 +-------------------------------------------------------------+
       x=0                                                          x=6.2
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

NOISE_M = 0.003  # depth noise, 1 sigma
DENSITY_PER_M2 = 6000.0  # surface samples before the cap
MAX_POINTS = 700  # per object (keeps the whole import well under the 1 MiB body limit)
DROPOUT = 0.1  # share of samples a sensor misses


@dataclass
class Box:
    """An axis-aligned part: x0, y0, z0, x1, y1, z1."""

    x0: float
    y0: float
    z0: float
    x1: float
    y1: float
    z1: float

    def faces(self):
        """(area, sampler) for each face but the bottom one (resting on something, unseen)."""
        x0, y0, z0, x1, y1, z1 = self.x0, self.y0, self.z0, self.x1, self.y1, self.z1
        dx, dy, dz = x1 - x0, y1 - y0, z1 - z0

        def plane(fixed_axis, value, lo, hi):
            def sample(rng, n):
                p = rng.uniform(lo, hi, size=(n, 3))
                p[:, fixed_axis] = value
                return p

            return sample

        lo, hi = np.array([x0, y0, z0]), np.array([x1, y1, z1])
        return [
            (dx * dy, plane(2, z1, lo, hi)),  # top
            (dx * dz, plane(1, y0, lo, hi)),  # front
            (dx * dz, plane(1, y1, lo, hi)),  # back
            (dy * dz, plane(0, x0, lo, hi)),  # left
            (dy * dz, plane(0, x1, lo, hi)),  # right
        ]


@dataclass
class Cylinder:
    """An upright cylinder: centre (cx, cy), radius r, from z0 to z1; open_top for a bin."""

    cx: float
    cy: float
    r: float
    z0: float
    z1: float
    open_top: bool = False

    def faces(self):
        cx, cy, r, z0, z1 = self.cx, self.cy, self.r, self.z0, self.z1

        def side(rng, n):
            a = rng.uniform(0, 2 * np.pi, n)
            z = rng.uniform(z0, z1, n)
            return np.stack([cx + r * np.cos(a), cy + r * np.sin(a), z], axis=1)

        def top(rng, n):
            a = rng.uniform(0, 2 * np.pi, n)
            rr = r * np.sqrt(rng.uniform(0, 1, n))
            return np.stack([cx + rr * np.cos(a), cy + rr * np.sin(a), np.full(n, z1)], axis=1)

        faces = [(2 * np.pi * r * (z1 - z0), side)]
        if not self.open_top:
            faces.append((np.pi * r * r, top))
        return faces


@dataclass
class Thing:
    key: str  # our own name for it, used by the phrasing set
    label: str  # what a detector would call it (the map's label)
    parts: list = field(default_factory=list)


def _legs(x0, y0, x1, y1, z1, w=0.04):
    """Four legs under a top spanning x0..x1, y0..y1, from the floor up to z1."""
    return [
        Box(x0, y0, 0.0, x0 + w, y0 + w, z1),
        Box(x1 - w, y0, 0.0, x1, y0 + w, z1),
        Box(x0, y1 - w, 0.0, x0 + w, y1, z1),
        Box(x1 - w, y1 - w, 0.0, x1, y1, z1),
    ]


def _chair(x0, y0, back_at_y1=True):
    """A 0.45 m chair: seat at 0.42-0.47 m, a backrest up to 0.95 m on one side, four legs."""
    x1, y1 = x0 + 0.45, y0 + 0.45
    seat = Box(x0, y0, 0.42, x1, y1, 0.47)
    back = (
        Box(x0, y1 - 0.05, 0.47, x1, y1, 0.95)
        if back_at_y1
        else Box(x0, y0, 0.47, x1, y0 + 0.05, 0.95)
    )
    return [seat, back, *_legs(x0, y0, x1, y1, 0.42, w=0.03)]


ROOM: list[Thing] = [
    # the work corner
    Thing(
        "desk",
        "desk",
        [
            Box(0.20, 0.20, 0.72, 1.60, 0.90, 0.75),
            Box(0.20, 0.20, 0.0, 0.25, 0.90, 0.72),
            Box(1.55, 0.20, 0.0, 1.60, 0.90, 0.72),
        ],
    ),
    Thing("chair_desk", "chair", _chair(0.65, 1.00)),
    Thing("bag_on_chair", "bag", [Box(0.72, 1.05, 0.47, 1.02, 1.30, 0.75)]),
    Thing("mug_desk", "mug", [Cylinder(1.25, 0.45, 0.045, 0.75, 0.85)]),
    Thing("books_desk", "book", [Box(0.35, 0.35, 0.75, 0.62, 0.58, 0.83)]),
    Thing(
        "laptop",
        "laptop",
        [Box(0.75, 0.32, 0.75, 1.08, 0.56, 0.77), Box(0.75, 0.30, 0.77, 1.08, 0.32, 0.99)],
    ),
    Thing("bin", "trash can", [Cylinder(1.22, 0.60, 0.13, 0.0, 0.35, open_top=True)]),
    Thing("box", "cardboard box", [Box(1.60, 1.25, 0.0, 1.90, 1.55, 0.30)]),
    # the kitchen side
    Thing("counter", "kitchen counter", [Box(4.20, 0.10, 0.0, 5.80, 0.70, 0.90)]),
    Thing("mug_counter", "mug", [Cylinder(5.05, 0.35, 0.045, 0.90, 1.00)]),
    Thing("kettle", "kettle", [Cylinder(4.60, 0.40, 0.09, 0.90, 1.15)]),
    Thing(
        "plant",
        "potted plant",
        [Cylinder(3.90, 0.35, 0.15, 0.0, 0.35), Box(3.72, 0.17, 0.35, 4.08, 0.53, 0.90)],
    ),
    # the dining table
    Thing(
        "dining_table",
        "dining table",
        [Box(2.00, 1.80, 0.72, 3.20, 2.60, 0.75), *_legs(2.00, 1.80, 3.20, 2.60, 0.72)],
    ),
    Thing("bag_under_table", "bag", [Box(2.45, 2.00, 0.0, 2.85, 2.30, 0.38)]),
    Thing("book_table", "book", [Box(2.30, 2.05, 0.75, 2.52, 2.22, 0.78)]),
    Thing("bottle", "bottle", [Cylinder(2.95, 2.35, 0.035, 0.75, 1.02)]),
    Thing("chair_table", "chair", _chair(2.40, 2.70)),
    # the living corner
    Thing(
        "sofa",
        "sofa",
        [
            Box(3.60, 3.80, 0.0, 5.60, 4.70, 0.45),
            Box(3.60, 4.50, 0.45, 5.60, 4.70, 0.85),
            Box(3.60, 3.80, 0.45, 3.75, 4.50, 0.62),
            Box(5.45, 3.80, 0.45, 5.60, 4.50, 0.62),
        ],
    ),
    Thing("cushion", "cushion", [Box(4.10, 4.20, 0.45, 4.50, 4.50, 0.70)]),
    Thing("chair_sofa", "chair", _chair(3.00, 3.95)),
    Thing(
        "floor_lamp",
        "lamp",
        [
            Cylinder(5.85, 4.30, 0.15, 0.0, 0.03),
            Cylinder(5.85, 4.30, 0.015, 0.03, 1.50),
            Cylinder(5.85, 4.30, 0.20, 1.50, 1.75),
        ],
    ),
    Thing("shelf", "shelf", [Box(2.40, 4.70, 1.20, 3.40, 4.95, 1.24)]),
    Thing("mug_shelf", "mug", [Cylinder(2.85, 4.83, 0.045, 1.24, 1.34)]),
    # the reading corner
    Thing(
        "side_table",
        "side table",
        [Box(0.20, 3.00, 0.50, 0.60, 3.40, 0.55), *_legs(0.20, 3.00, 0.60, 3.40, 0.50, w=0.03)],
    ),
    Thing(
        "table_lamp",
        "lamp",
        [
            Cylinder(0.40, 3.20, 0.07, 0.55, 0.60),
            Cylinder(0.40, 3.20, 0.01, 0.60, 0.85),
            Cylinder(0.40, 3.20, 0.13, 0.85, 1.05),
        ],
    ),
]


def sample_points(thing: Thing, rng: np.random.Generator) -> np.ndarray:
    """Points on the thing's visible surfaces, area-weighted, with dropout and noise."""
    chunks = []
    for part in thing.parts:
        for area, sampler in part.faces():
            n = max(4, int(round(area * DENSITY_PER_M2)))
            chunks.append(sampler(rng, n))
    pts = np.concatenate(chunks)
    pts = pts[rng.uniform(size=len(pts)) >= DROPOUT]
    if len(pts) > MAX_POINTS:
        pts = pts[rng.choice(len(pts), MAX_POINTS, replace=False)]
    return pts + rng.normal(0.0, NOISE_M, size=pts.shape)


def build_export(embedding: dict, seed: int = 27) -> tuple[dict, dict[str, int]]:
    """The room as a `semanticxr-map` JSON export, and our key -> the object id it gets."""
    rng = np.random.default_rng(seed)
    objects, ids = [], {}
    for i, thing in enumerate(ROOM, start=1):
        pts = np.round(sample_points(thing, rng), 4)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        objects.append(
            {
                "id": i,
                "version": 1,
                "label": thing.label,
                "bbox": [*map(float, lo), *map(float, hi)],
                "centroid": [float(v) for v in pts.mean(axis=0)],
                "n_obs": 10,
                "points": pts.tolist(),
            }
        )
        ids[thing.key] = i
    export = {
        "format": "semanticxr-map",
        "version": 1,
        "session": {
            "name": "outside-room",
            "mode": "semanticxr",
            "knobs": {},
            "embedding": embedding,
        },
        "objects": objects,
    }
    return export, ids
