"""Procedural indoor scenes: rooms, walls with doorways, furniture, wall items and small objects.

The world is Z-up, metres, floor at z = 0. A scene is a list of `SceneObject`s, each one
triangle mesh built from boxes, cylinders and ellipsoids in the object's own frame and then
placed with a yaw that is a multiple of 90 degrees (furniture) or any yaw (small objects).
Placement is rejection sampling against the axis-aligned boxes of everything placed so far,
so objects never interpenetrate; small objects stand on the support rectangles (table tops,
shelf levels, counters) their parent declared, 1 mm above them.

Object frame convention used by the builders: x along the width, y from front (-y) to back
(+y, the side that goes against a wall), z up from the object's bottom (z = 0).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import open3d as o3d

from client_sim.world.categories import BACKGROUND_CLASSES, CATEGORIES

SCENE_NAMES: tuple[str, ...] = ("living_room", "kitchen", "office", "bedroom", "apartment")

WALL_THICKNESS_M = 0.1
DOOR_WIDTH_M = 1.2
DOOR_HEIGHT_M = 2.1
# Clear floor kept in front of each doorway so the rooms stay connected for walking.
DOOR_CLEARANCE_M = 1.0
# Resting objects float this far above their support so that contact faces stay separable
# (the ground-truth sampler drops faces that touch another surface).
REST_GAP_M = 0.001


# --------------------------------------------------------------------------------------
# Public data model
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Room:
    """One room: its type, its floor rectangle (wall centre lines) and its ceiling height."""

    type: str
    bounds: tuple[float, float, float, float]
    """(x0, y0, x1, y1) in metres; interior walls are centred on these lines."""
    height: float
    """Floor-to-ceiling height in metres."""

    def contains_xy(self, x: float, y: float, margin_m: float = 0.0) -> bool:
        """True if (x, y) is inside the bounds shrunk by `margin_m`."""
        x0, y0, x1, y1 = self.bounds
        return (x0 + margin_m <= x <= x1 - margin_m) and (y0 + margin_m <= y <= y1 - margin_m)

    @property
    def area_m2(self) -> float:
        x0, y0, x1, y1 = self.bounds
        return (x1 - x0) * (y1 - y0)


@dataclass(frozen=True)
class Doorway:
    """An opening in an interior wall between two rooms."""

    rooms: tuple[int, int]
    """Indices into Scene.rooms."""
    center: tuple[float, float]
    """(x, y) of the opening's centre on the wall line."""
    width: float
    height: float
    wall_axis: int
    """0: the wall is the line x = const (the opening spans y); 1: the wall is y = const."""


@dataclass
class SceneObject:
    """One object (or background surface) of a scene, in world coordinates."""

    instance_id: int
    """>= 1, unique in the scene."""
    category: str
    """A CATEGORIES key or a BACKGROUND_CLASSES entry."""
    mesh: o3d.geometry.TriangleMesh
    """Legacy open3d mesh with outward-wound triangles and per-vertex colours in [0, 1]."""
    color: tuple[int, int, int]
    """The instance's base RGB colour."""
    center: np.ndarray
    """float64 [3] centre of the bounding box, metres."""
    bbox: np.ndarray
    """float64 [6] axis-aligned [x0, y0, z0, x1, y1, z1], metres."""
    room: int = -1
    """Index into Scene.rooms; -1 for walls shared by several rooms."""
    support_id: int = 0
    """Instance id of the object it stands on; 0 when it stands on the floor / hangs on a wall."""
    texture: str = "plain"
    """Procedural surface pattern for the renderer: "plain", "planks" or "tiles"."""

    @property
    def is_background(self) -> bool:
        return self.category in BACKGROUND_CLASSES


@dataclass
class Scene:
    """A procedural scene: rooms, doorways and all objects including background surfaces."""

    name: str
    seed: int
    objects: list[SceneObject]
    rooms: list[Room]
    doorways: list[Doorway] = field(default_factory=list)
    _index: dict[int, SceneObject] = field(default_factory=dict, init=False, repr=False)

    def object_by_id(self, instance_id: int) -> SceneObject:
        """The object with this instance id; KeyError if there is none."""
        key = int(instance_id)
        if key not in self._index or len(self._index) != len(self.objects):
            self._index = {o.instance_id: o for o in self.objects}
        return self._index[key]

    @property
    def categories_present(self) -> list[str]:
        """Sorted names of the non-background categories in the scene."""
        return sorted({o.category for o in self.objects if not o.is_background})

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(x0, y0, x1, y1) of the union of the rooms."""
        b = np.array([r.bounds for r in self.rooms])
        return (b[:, 0].min(), b[:, 1].min(), b[:, 2].max(), b[:, 3].max())

    def room_index_at(self, x: float, y: float) -> int:
        """Index of the room containing (x, y), or -1."""
        for i, room in enumerate(self.rooms):
            if room.contains_xy(x, y):
                return i
        return -1


def make_scene(name: str = "apartment", seed: int = 0) -> Scene:
    """Build the scene `name` (one of SCENE_NAMES); deterministic for (name, seed).

    Single-room scenes hold ~30-60 objects, the apartment (living room, kitchen, bedroom and
    office joined by doorways) ~120-200, plus floor, wall and ceiling surfaces.
    """
    if name not in SCENE_NAMES:
        raise ValueError(f"unknown scene {name!r}; valid names: {', '.join(SCENE_NAMES)}")
    rng = np.random.default_rng([int(seed), SCENE_NAMES.index(name)])
    builder = _SceneBuilder(name, int(seed), rng)
    if name == "apartment":
        builder.layout_apartment()
    else:
        builder.layout_single_room(name)
    builder.build_architecture()
    for index in range(len(builder.rooms)):
        builder.furnish(index)
    return Scene(
        name=name,
        seed=int(seed),
        objects=builder.objects,
        rooms=builder.rooms,
        doorways=builder.doorways,
    )


# --------------------------------------------------------------------------------------
# Mesh primitives
# --------------------------------------------------------------------------------------

# Outward-wound box faces over corners indexed by bits (x + 2y + 4z).
_BOX_QUADS = np.array(
    [[0, 4, 6, 2], [1, 3, 7, 5], [0, 1, 5, 4], [2, 6, 7, 3], [0, 2, 3, 1], [4, 5, 7, 6]]
)
_BOX_TRIS = np.concatenate([_BOX_QUADS[:, [0, 1, 2]], _BOX_QUADS[:, [0, 2, 3]]])
_BOX_CORNERS = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], float)


def _rot_z(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rot_x(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rot_y(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _shade(color: np.ndarray, factor: float) -> np.ndarray:
    return np.clip(np.asarray(color, float) * factor, 0, 255)


class _Parts:
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


@dataclass(frozen=True)
class _LocalSupport:
    """A rectangle small objects may stand on, in the owner's frame."""

    rect: tuple[float, float, float, float]  # x0, y0, x1, y1
    z: float
    clearance: float
    kind: str  # "top" | "shelf"


# --------------------------------------------------------------------------------------
# Per-category builders. Each draws the object into `p` inside [-w/2, w/2] x [-d/2, d/2] x
# [0, h] and returns the support rectangles it offers.
# --------------------------------------------------------------------------------------

Builder = Callable[..., list[_LocalSupport]]
_BUILDERS: dict[str, Builder] = {}

_DARK_WOOD = np.array([90.0, 64.0, 44.0])
_METAL_GREY = np.array([170.0, 172.0, 176.0])
_BLACK = np.array([28.0, 28.0, 30.0])
_SCREEN = np.array([14.0, 17.0, 24.0])
_WHITE = np.array([238.0, 238.0, 234.0])
_GLASS = np.array([165.0, 195.0, 220.0])


def _builder(*names: str) -> Callable[[Builder], Builder]:
    def register(fn: Builder) -> Builder:
        for n in names:
            _BUILDERS[n] = fn
        return fn

    return register


def _top_support(w: float, d: float, z: float, inset: float = 0.03) -> _LocalSupport:
    return _LocalSupport(
        (-w / 2 + inset, -d / 2 + inset, w / 2 - inset, d / 2 - inset), z, 1.2, "top"
    )


def _legs(p: _Parts, w: float, d: float, h: float, size: float, inset: float, color) -> None:
    for sx, sy in itertools.product((-1, 1), (-1, 1)):
        cx, cy = sx * (w / 2 - inset - size / 2), sy * (d / 2 - inset - size / 2)
        p.box((cx - size / 2, cy - size / 2, 0), (cx + size / 2, cy + size / 2, h), color)


@_builder("sofa", "armchair")
def _build_upholstered(p, w, d, h, color, rng, cushions: int | None = None, **_):
    arm, back, seat = 0.16, 0.2, 0.44
    _legs(p, w, d, 0.07, 0.05, 0.03, _DARK_WOOD)
    p.box((-w / 2, -d / 2, 0.07), (w / 2, d / 2 - back, seat - 0.1), color)
    p.box((-w / 2 + arm, d / 2 - back, 0.07), (w / 2 - arm, d / 2, h), color)
    for sx in (-1, 1):
        x_in, x_out = sx * (w / 2 - arm), sx * w / 2
        p.box(
            (min(x_in, x_out), -d / 2, 0.07), (max(x_in, x_out), d / 2, 0.64), _shade(color, 0.92)
        )
    n = cushions or (1 if w < 1.2 else 3 if w > 2.0 else 2)
    inner = w - 2 * arm
    cushion = _shade(color, 1.08)
    for k in range(n):
        x0 = -w / 2 + arm + k * inner / n + 0.005
        p.box((x0, -d / 2 + 0.02, seat - 0.1), (x0 + inner / n - 0.01, d / 2 - back, seat), cushion)
    return []


@_builder("coffee table", "dining table")
def _build_table(p, w, d, h, color, rng, **_):
    top = 0.04
    p.box((-w / 2, -d / 2, h - top), (w / 2, d / 2, h), color)
    _legs(p, w, d, h - top, 0.05 if h > 0.6 else 0.06, 0.06, _shade(color, 0.8))
    if h < 0.6:  # coffee tables get a magazine shelf between the legs
        p.box((-w / 2 + 0.09, -d / 2 + 0.09, 0.1), (w / 2 - 0.09, d / 2 - 0.09, 0.12), color)
    return [_top_support(w, d, h)]


@_builder("desk")
def _build_desk(p, w, d, h, color, rng, **_):
    top = 0.03
    p.box((-w / 2, -d / 2, h - top), (w / 2, d / 2, h), color)
    x0 = w / 2 - 0.42
    p.box((x0, -d / 2 + 0.02, 0), (w / 2 - 0.01, d / 2 - 0.01, h - top), _shade(color, 0.9))
    for k in range(3):  # drawer fronts on the pedestal
        z0 = 0.02 + k * (h - top - 0.03) / 3
        z1 = z0 + (h - top - 0.03) / 3 - 0.01
        p.box((x0 + 0.01, -d / 2, z0), (w / 2 - 0.02, -d / 2 + 0.02, z1), color)
        p.box(
            (x0 + 0.17, -d / 2 - 0.0, z1 - 0.05),
            (x0 + 0.25, -d / 2 + 0.005, z1 - 0.035),
            _METAL_GREY,
        )
    p.box(
        (-w / 2 + 0.01, -d / 2 + 0.02, 0),
        (-w / 2 + 0.04, d / 2 - 0.01, h - top),
        _shade(color, 0.9),
    )
    p.box((-w / 2 + 0.04, d / 2 - 0.03, 0.3), (x0, d / 2 - 0.01, h - top), _shade(color, 0.85))
    return [_top_support(w, d, h)]


@_builder("chair")
def _build_chair(p, w, d, h, color, rng, **_):
    seat = 0.46
    leg = 0.035
    _legs(p, w, d, seat - 0.04, leg, 0.015, _shade(color, 0.85))
    p.box((-w / 2, -d / 2, seat - 0.04), (w / 2, d / 2, seat), color)
    for sx in (-1, 1):
        x = sx * (w / 2 - 0.015 - leg / 2)
        p.box((x - leg / 2, d / 2 - leg, seat), (x + leg / 2, d / 2, h), _shade(color, 0.85))
    p.box(
        (-w / 2 + 0.015 + leg, d / 2 - 0.03, h - 0.28),
        (w / 2 - 0.015 - leg, d / 2, h - 0.02),
        color,
    )
    return []


@_builder("office chair")
def _build_office_chair(p, w, d, h, color, rng, **_):
    r = min(w, d) / 2 - 0.03
    for k in range(5):
        rot = _rot_z(2 * math.pi * k / 5 + 0.3)
        p.box((0, -0.025, 0.06), (r, 0.025, 0.1), _BLACK, rot)
        cx, cy = (rot @ [r - 0.02, 0, 0])[:2]
        p.cylinder((cx, cy, 0), 0.025, 0.06, _BLACK, 8)
    p.cylinder((0, 0, 0.1), 0.025, 0.32, _METAL_GREY, 10)
    p.box((-w / 2 + 0.06, -d / 2 + 0.02, 0.42), (w / 2 - 0.06, d / 2 - 0.1, 0.5), color)
    p.box((-w / 2 + 0.1, d / 2 - 0.07, 0.56), (w / 2 - 0.1, d / 2, h), color)
    p.box((-0.03, d / 2 - 0.1, 0.45), (0.03, d / 2 - 0.07, 0.62), _BLACK)
    for sx in (-1, 1):
        x = sx * (w / 2 - 0.04)
        p.box((x - 0.02, -0.05, 0.5), (x + 0.02, 0.0, 0.64), _BLACK)
        p.box((x - 0.035, -0.2, 0.64), (x + 0.035, 0.05, 0.67), _BLACK)
    return []


@_builder("ottoman")
def _build_ottoman(p, w, d, h, color, rng, **_):
    if rng.random() < 0.5:
        p.frustum((0, 0, 0), min(w, d) / 2 * 0.92, min(w, d) / 2, h, color, 20)
    else:
        _legs(p, w, d, 0.06, 0.04, 0.04, _DARK_WOOD)
        p.box((-w / 2, -d / 2, 0.06), (w / 2, d / 2, h), color)
    return []


@_builder("bar stool")
def _build_bar_stool(p, w, d, h, color, rng, **_):
    r = min(w, d) / 2
    p.cylinder((0, 0, 0), r * 0.9, 0.03, color, 16)
    p.cylinder((0, 0, 0.03), 0.025, h - 0.08, _METAL_GREY, 10)
    p.cylinder((0, 0, 0.28), r * 0.75, 0.02, _METAL_GREY, 16)
    p.cylinder((0, 0, h - 0.06), r, 0.06, color, 20)
    return []


@_builder("bed")
def _build_bed(p, w, d, h, color, rng, duvet=None, **_):
    duvet = np.asarray(duvet if duvet is not None else (200, 186, 160), float)
    head = 0.06
    _legs(p, w, d - head, 0.12, 0.06, 0.02, _shade(color, 0.8))
    p.box((-w / 2, -d / 2, 0.12), (w / 2, d / 2 - head, 0.32), color)
    p.box((-w / 2, d / 2 - head, 0), (w / 2, d / 2, h), color)
    p.box((-w / 2 + 0.03, -d / 2 + 0.03, 0.32), (w / 2 - 0.03, d / 2 - head - 0.01, 0.54), _WHITE)
    p.box((-w / 2 + 0.01, -d / 2 + 0.01, 0.54), (w / 2 - 0.01, d / 2 - 0.7, 0.58), duvet)
    n_pillows = 2 if w > 1.2 else 1
    pw = (w - 0.1) / n_pillows
    for k in range(n_pillows):
        x0 = -w / 2 + 0.05 + k * pw
        p.box(
            (x0 + 0.02, d / 2 - head - 0.5, 0.54),
            (x0 + pw - 0.02, d / 2 - head - 0.06, 0.66),
            _WHITE,
        )
    return [
        _LocalSupport((-w / 2 + 0.12, -d / 2 + 0.15, w / 2 - 0.12, d / 2 - 0.75), 0.58, 0.6, "top")
    ]


def _drawer_fronts(p, x0, x1, z0, z1, front_y, rows, color) -> None:
    step = (z1 - z0) / rows
    for k in range(rows):
        za, zb = z0 + k * step + 0.005, z0 + (k + 1) * step - 0.005
        p.box((x0 + 0.01, front_y - 0.02, za), (x1 - 0.01, front_y, zb), color)
        cx, cz = (x0 + x1) / 2, (za + zb) / 2
        p.box(
            (cx - 0.05, front_y - 0.03, cz - 0.008),
            (cx + 0.05, front_y - 0.02, cz + 0.008),
            _METAL_GREY,
        )


@_builder("nightstand", "dresser", "filing cabinet")
def _build_drawers(p, w, d, h, color, rng, **_):
    plinth = 0.05
    front = -d / 2 + 0.03
    p.box((-w / 2 + 0.02, front, 0), (w / 2 - 0.02, d / 2, plinth), _shade(color, 0.7))
    p.box((-w / 2, front, plinth), (w / 2, d / 2, h - 0.03), color)
    p.box((-w / 2, -d / 2 + 0.025, h - 0.03), (w / 2, d / 2, h), _shade(color, 0.92))
    rows = max(1, round((h - plinth) / 0.25))
    front_color = _shade(color, 1.06)
    if w > 1.05:  # two columns of drawers on wide dressers
        _drawer_fronts(p, -w / 2, 0, plinth, h - 0.03, front, rows, front_color)
        _drawer_fronts(p, 0, w / 2, plinth, h - 0.03, front, rows, front_color)
    else:
        _drawer_fronts(p, -w / 2, w / 2, plinth, h - 0.03, front, rows, front_color)
    return [_top_support(w, d, h)]


def _doors(p, x0, x1, z0, z1, front_y, n, color) -> None:
    step = (x1 - x0) / n
    for k in range(n):
        xa, xb = x0 + k * step + 0.004, x0 + (k + 1) * step - 0.004
        p.box((xa, front_y - 0.02, z0), (xb, front_y, z1), color)
        hx = xb - 0.04 if k % 2 == 0 else xa + 0.04
        hz0 = 1.0 if z1 > 1.2 else z1 - 0.2  # tall doors get handles at hand height
        p.box(
            (hx - 0.008, front_y - 0.035, hz0),
            (hx + 0.008, front_y - 0.02, hz0 + 0.14),
            _METAL_GREY,
        )


@_builder("wardrobe", "cabinet", "tv stand", "wall cabinet")
def _build_cupboard(p, w, d, h, color, rng, category: str = "cabinet", **_):
    front = -d / 2 + 0.035
    floor_standing = category != "wall cabinet"
    z0 = 0.06 if floor_standing else 0.0
    if floor_standing:
        p.box((-w / 2 + 0.03, front + 0.03, 0), (w / 2 - 0.03, d / 2, z0), _shade(color, 0.6))
    p.box((-w / 2, front, z0), (w / 2, d / 2, h), color)
    n_doors = max(2, round(w / 0.5)) if category != "tv stand" else 3
    _doors(p, -w / 2, w / 2, z0 + 0.01, h - 0.01, front, n_doors, _shade(color, 1.06))
    return [_top_support(w, d, h)] if category in ("cabinet", "tv stand") else []


@_builder("bookshelf")
def _build_bookshelf(p, w, d, h, color, rng, **_):
    t = 0.022
    p.box((-w / 2, -d / 2, 0), (-w / 2 + t, d / 2, h), color)
    p.box((w / 2 - t, -d / 2, 0), (w / 2, d / 2, h), color)
    p.box((-w / 2 + t, d / 2 - 0.012, 0), (w / 2 - t, d / 2, h), _shade(color, 0.8))
    levels = max(3, int((h - 0.08) // 0.34))
    zs = np.linspace(0.06, h - t, levels + 1)
    supports = []
    p.box((-w / 2 + t, -d / 2, 0), (w / 2 - t, d / 2 - 0.012, 0.06), _shade(color, 0.9))
    for k, z in enumerate(zs[1:]):
        p.box((-w / 2 + t, -d / 2, z), (w / 2 - t, d / 2 - 0.012, z + t), color)
        below = zs[k] + (0 if k == 0 else t)
        supports.append(
            _LocalSupport(
                (-w / 2 + t + 0.005, -d / 2 + 0.01, w / 2 - t - 0.005, d / 2 - 0.02),
                below,
                z - below - 0.01,
                "shelf",
            )
        )
    return supports


@_builder("kitchen counter", "sink")
def _build_counter(p, w, d, h, color, rng, top_color=None, category: str = "kitchen counter", **_):
    top_color = np.asarray(top_color if top_color is not None else (200, 196, 188), float)
    slab = 0.04
    p.box((-w / 2, -d / 2 + 0.08, 0), (w / 2, d / 2, 0.1), _BLACK)
    _doors(
        p,
        -w / 2,
        w / 2,
        0.11,
        h - slab - 0.01,
        -d / 2 + 0.03,
        max(1, round(w / 0.5)),
        _shade(color, 1.05),
    )
    if category == "kitchen counter":
        p.box((-w / 2, -d / 2 + 0.03, 0.1), (w / 2, d / 2, h - slab), color)
        p.box((-w / 2, -d / 2, h - slab), (w / 2, d / 2, h), top_color)
        return [_top_support(w, d, h, inset=0.04)]
    # Sink: a slab with a hole, a metal basin below it and a tap behind it; the cabinet is
    # hollow above the basin's bottom so that the basin is open from above.
    bx0, bx1, by0, by1 = -w / 2 + 0.1, w / 2 - 0.1, -d / 2 + 0.08, d / 2 - 0.15
    zb = h - 0.2
    p.box((-w / 2, -d / 2 + 0.03, 0.1), (w / 2, d / 2, zb), color)
    for lo, hi in (
        ((-w / 2, -d / 2 + 0.03, zb), (bx0, d / 2, h - slab)),
        ((bx1, -d / 2 + 0.03, zb), (w / 2, d / 2, h - slab)),
        ((bx0, -d / 2 + 0.03, zb), (bx1, by0, h - slab)),
        ((bx0, by1, zb), (bx1, d / 2, h - slab)),
    ):
        p.box(lo, hi, color)
    p.box((-w / 2, -d / 2, h - slab), (bx0, d / 2, h), top_color)
    p.box((bx1, -d / 2, h - slab), (w / 2, d / 2, h), top_color)
    p.box((bx0, -d / 2, h - slab), (bx1, by0, h), top_color)
    p.box((bx0, by1, h - slab), (bx1, d / 2, h), top_color)
    p.box((bx0, by0, zb), (bx1, by1, zb + 0.01), _METAL_GREY)
    for lo, hi in (
        ((bx0, by0, zb), (bx0 + 0.01, by1, h - slab)),
        ((bx1 - 0.01, by0, zb), (bx1, by1, h - slab)),
        ((bx0, by0, zb), (bx1, by0 + 0.01, h - slab)),
        ((bx0, by1 - 0.01, zb), (bx1, by1, h - slab)),
    ):
        p.box(lo, hi, _METAL_GREY)
    ty = d / 2 - 0.08
    p.cylinder((0, ty, h), 0.015, 0.28, _METAL_GREY, 10)
    p.box((-0.012, ty - 0.2, h + 0.25), (0.012, ty, h + 0.28), _METAL_GREY)
    return []


@_builder("refrigerator")
def _build_fridge(p, w, d, h, color, rng, **_):
    front = -d / 2 + 0.04
    p.box((-w / 2, front, 0), (w / 2, d / 2, h), color)
    split = h * rng.uniform(0.58, 0.68)
    p.box(
        (-w / 2 + 0.005, front - 0.03, 0.02),
        (w / 2 - 0.005, front, split - 0.006),
        _shade(color, 1.04),
    )
    p.box(
        (-w / 2 + 0.005, front - 0.03, split + 0.006),
        (w / 2 - 0.005, front, h - 0.01),
        _shade(color, 1.04),
    )
    hx = w / 2 - 0.06
    p.box(
        (hx - 0.012, -d / 2, split - 0.45),
        (hx + 0.012, front - 0.03, split - 0.1),
        _shade(color, 0.75),
    )
    p.box(
        (hx - 0.012, -d / 2, split + 0.1),
        (hx + 0.012, front - 0.03, split + 0.35),
        _shade(color, 0.75),
    )
    return []


@_builder("stove")
def _build_stove(p, w, d, h, color, rng, **_):
    p.box((-w / 2, -d / 2 + 0.02, 0), (w / 2, d / 2, h - 0.03), color)
    p.box((-w / 2 + 0.05, -d / 2, 0.12), (w / 2 - 0.05, -d / 2 + 0.02, h - 0.2), _SCREEN)
    p.box(
        (-w / 2 + 0.08, -d / 2 - 0.0, h - 0.16),
        (w / 2 - 0.08, -d / 2 + 0.02, h - 0.14),
        _METAL_GREY,
    )
    p.box((-w / 2, -d / 2 + 0.02, h - 0.03), (w / 2, d / 2, h), _BLACK)
    for sx, sy in itertools.product((-1, 1), (-1, 1)):
        p.cylinder((sx * w / 4, sy * d / 4, h), 0.07 if sy < 0 else 0.09, 0.006, (60, 60, 62), 14)
    for k in range(4):
        x = -w / 2 + (k + 0.5) * w / 4
        p.cylinder((x, -d / 2 + 0.02, h - 0.07), 0.018, 0.02, _METAL_GREY, 10, _rot_x(math.pi / 2))
    return [
        _LocalSupport(
            (-w / 2 + 0.04, -d / 2 + 0.06, w / 2 - 0.04, d / 2 - 0.04), h + 0.006, 0.7, "top"
        )
    ]


@_builder("dishwasher")
def _build_dishwasher(p, w, d, h, color, rng, **_):
    p.box((-w / 2, -d / 2 + 0.03, 0), (w / 2, d / 2, h), color)
    p.box(
        (-w / 2 + 0.01, -d / 2 + 0.01, 0.1),
        (w / 2 - 0.01, -d / 2 + 0.03, h - 0.12),
        _shade(color, 1.05),
    )
    p.box((-w / 2 + 0.01, -d / 2 + 0.01, h - 0.11), (w / 2 - 0.01, -d / 2 + 0.03, h - 0.01), _BLACK)
    p.box((-w / 2 + 0.1, -d / 2, h - 0.18), (w / 2 - 0.1, -d / 2 + 0.01, h - 0.16), _METAL_GREY)
    return []


@_builder("microwave")
def _build_microwave(p, w, d, h, color, rng, **_):
    p.box((-w / 2, -d / 2 + 0.01, 0.01), (w / 2, d / 2, h), color)
    for sx in (-1, 1):
        for sy in (-1, 1):
            p.box(
                (sx * w / 2 * 0.8 - 0.01, sy * d / 3 - 0.01, 0),
                (sx * w / 2 * 0.8 + 0.01, sy * d / 3 + 0.01, 0.01),
                _BLACK,
            )
    split = w / 2 - 0.13
    p.box((-w / 2 + 0.03, -d / 2, 0.04), (split - 0.02, -d / 2 + 0.01, h - 0.04), _SCREEN)
    p.box(
        (split, -d / 2 + 0.003, 0.03), (w / 2 - 0.02, -d / 2 + 0.01, h - 0.03), _shade(color, 0.6)
    )
    return []


@_builder("toaster")
def _build_toaster(p, w, d, h, color, rng, **_):
    p.box((-w / 2 + 0.015, -d / 2, 0), (w / 2 - 0.015, d / 2, h - 0.004), color)
    for k in (-1, 1):
        y = k * d / 5
        p.box((-w / 2 + 0.04, y - 0.014, h - 0.004), (w / 2 - 0.04, y + 0.014, h), _BLACK)
    p.box((w / 2 - 0.015, -0.012, h * 0.5), (w / 2, 0.012, h * 0.7), _BLACK)
    return []


@_builder("kettle")
def _build_kettle(p, w, d, h, color, rng, **_):
    r = d / 2
    p.cylinder((0, 0, 0), r, 0.02, _BLACK, 16)
    p.frustum((0, 0, 0.02), r * 0.95, r * 0.72, h - 0.05, color, 16)
    p.cylinder((0, 0, h - 0.03), r * 0.45, 0.03, _BLACK, 14)
    xb = w / 2 - 0.025
    p.box((xb, -0.012, 0.05), (w / 2, 0.012, h - 0.04), _BLACK)
    p.box((r * 0.7, -0.012, h - 0.07), (w / 2, 0.012, h - 0.04), _BLACK)
    p.box((-w / 2, -0.01, h * 0.55), (-r * 0.8, 0.01, h * 0.7), color)
    return []


@_builder("coffee maker")
def _build_coffee_maker(p, w, d, h, color, rng, **_):
    p.box((-w / 2, -d / 2, 0), (w / 2, d / 2, 0.03), color)
    p.box((-w / 2, 0, 0.03), (w / 2, d / 2, h), color)
    p.box((-w / 2, -d / 2, h - 0.08), (w / 2, 0, h), _shade(color, 0.9))
    p.cylinder((0, -d / 4, 0.03), min(w, d) * 0.28, h * 0.45, _SCREEN, 16)
    return []


@_builder("cooking pot")
def _build_pot(p, w, d, h, color, rng, **_):
    r = d / 2
    p.cylinder((0, 0, 0), r, h - 0.02, color, 20)
    p.cylinder((0, 0, h - 0.02), r * 1.02, 0.006, _shade(color, 1.1), 20)
    p.cylinder((0, 0, h - 0.014), 0.015, 0.014, _BLACK, 8)
    for sx in (-1, 1):
        x0, x1 = sorted((sx * r * 0.95, sx * w / 2))
        p.box((x0, -0.02, h - 0.05), (x1, 0.02, h - 0.035), _BLACK)
    return []


@_builder("cutting board", "keyboard", "remote control", "cell phone")
def _build_slab(p, w, d, h, color, rng, category: str = "", **_):
    if category == "cell phone":
        p.box((-w / 2, -d / 2, 0), (w / 2, d / 2, h - 0.001), color)
        p.box(
            (-w / 2 + 0.004, -d / 2 + 0.008, h - 0.001), (w / 2 - 0.004, d / 2 - 0.008, h), _SCREEN
        )
    elif category == "keyboard":
        p.box((-w / 2, -d / 2, 0), (w / 2, d / 2, h * 0.6), color)
        keys = _shade(color, 0.75) if color.mean() > 128 else _shade(color, 1.8)
        p.box((-w / 2 + 0.015, -d / 2 + 0.015, h * 0.6), (w / 2 - 0.015, d / 2 - 0.01, h), keys)
    elif category == "remote control":
        p.box((-w / 2, -d / 2, 0), (w / 2, d / 2, h - 0.003), color)
        for k in range(4):
            x = -w / 2 + 0.03 + k * 0.035
            p.box(
                (x, -0.01, h - 0.003),
                (x + 0.015, 0.01, h),
                (200, 60, 50) if k == 0 else (150, 150, 150),
            )
    else:
        p.box((-w / 2, -d / 2, 0), (w / 2, d / 2, h), color)
    return []


@_builder("bowl")
def _build_bowl(p, w, d, h, color, rng, **_):
    r = min(w, d) / 2
    p.frustum((0, 0, 0), r * 0.5, r, h - 0.002, color, 20)
    p.cylinder((0, 0, h - 0.002), r * 0.9, 0.002, _shade(color, 0.8), 20)
    return []


@_builder("mug")
def _build_mug(p, w, d, h, color, rng, **_):
    r = d / 2
    p.cylinder((-(w - d) / 2, 0, 0), r, h, color, 18)
    p.cylinder((-(w - d) / 2, 0, h), r * 0.85, 0.001, (70, 45, 30), 18)  # coffee, seen from above
    cx = -(w - d) / 2 + r * 0.9
    p.box((cx, -0.006, h - 0.025), (w / 2, 0.006, h - 0.015), color)
    p.box((cx, -0.006, h * 0.25), (w / 2, 0.006, h * 0.25 + 0.01), color)
    p.box((w / 2 - 0.01, -0.006, h * 0.25), (w / 2, 0.006, h - 0.015), color)
    return []


@_builder("bottle")
def _build_bottle(p, w, d, h, color, rng, **_):
    r = min(w, d) / 2
    p.cylinder((0, 0, 0), r, h * 0.6, color, 16)
    p.frustum((0, 0, h * 0.6), r, r * 0.35, h * 0.15, color, 16)
    p.cylinder((0, 0, h * 0.75), r * 0.35, h * 0.2, color, 12)
    p.cylinder((0, 0, h * 0.95), r * 0.4, h * 0.05, _WHITE if color.mean() < 128 else _BLACK, 12)
    return []


@_builder("vase")
def _build_vase(p, w, d, h, color, rng, **_):
    r = min(w, d) / 2
    flowers = rng.random() < 0.5
    body = h * (0.65 if flowers else 1.0)
    p.frustum((0, 0, 0), r * 0.6, r, body * 0.45, color, 18)
    p.frustum((0, 0, body * 0.45), r, r * 0.45, body * 0.4, color, 18)
    p.frustum((0, 0, body * 0.85), r * 0.45, r * 0.6, body * 0.15, color, 18)
    if flowers:
        petal = np.array(
            [(220, 60, 80), (245, 200, 60), (240, 240, 240), (150, 90, 200)][rng.integers(4)], float
        )
        for k in range(4):
            a = 2 * math.pi * k / 4 + 0.4
            fx, fy = math.cos(a) * r * 0.5, math.sin(a) * r * 0.5
            top = h - 0.03 - 0.03 * (k % 2)
            p.box((fx - 0.003, fy - 0.003, body), (fx + 0.003, fy + 0.003, top), (60, 120, 50))
            p.ellipsoid((fx, fy, top), (0.025, 0.025, 0.025), petal, 5, 8)
    return []


@_builder("potted plant")
def _build_plant(p, w, d, h, color, rng, **_):
    r = min(w, d) / 2
    pot_h = min(0.35, h * 0.3)
    pot = np.array([(190, 110, 80), (235, 232, 225), (60, 60, 62)][rng.integers(3)], float)
    p.frustum((0, 0, 0), r * 0.55, r * 0.7, pot_h, pot, 16)
    p.cylinder((0, 0, pot_h), r * 0.65, 0.005, (70, 50, 35), 16)
    if h > 1.0:  # a small tree: trunk and a crown
        p.cylinder((0, 0, pot_h), 0.025, h * 0.45, (100, 75, 50), 8)
        blobs = [
            ((0, 0, h - r * 0.9), r * 0.9),
            ((r * 0.35, 0.1 * r, h - r * 1.4), r * 0.6),
            ((-r * 0.35, -0.1 * r, h - r * 1.3), r * 0.6),
        ]
    else:
        blobs = [
            ((0, 0, pot_h + (h - pot_h) * 0.5), r * 0.85),
            # the top blob touches the plant's full height
            ((r * 0.3, r * 0.2, h - min(r * 0.6, (h - pot_h) * 0.3)), r * 0.6),
            ((-r * 0.3, -r * 0.2, h - (h - pot_h) * 0.35), r * 0.6),
        ]
    for k, (c, rad) in enumerate(blobs):
        zr = min(rad, h - c[2], c[2] - pot_h + rad * 0.5)
        p.ellipsoid(c, (rad, rad, max(0.05, zr)), _shade(color, 0.85 + 0.12 * k), 6, 12)
    return []


@_builder("floor lamp", "table lamp")
def _build_lamp(p, w, d, h, color, rng, **_):
    r = min(w, d) / 2
    tall = h > 1.0
    shade_h = 0.32 if tall else h * 0.45
    base = np.array([(40, 40, 42), (190, 170, 120), (200, 200, 200)][rng.integers(3)], float)
    if tall:
        p.cylinder((0, 0, 0), min(0.15, r), 0.03, base, 18)
    else:
        p.ellipsoid((0, 0, h * 0.13), (r * 0.45, r * 0.45, h * 0.13), base, 6, 12)
    p.cylinder((0, 0, 0.02), 0.012, h - shade_h * 0.5, base, 8)
    p.frustum((0, 0, h - shade_h), r, r * 0.7, shade_h, color, 20)
    return []


@_builder("picture frame")
def _build_picture_frame(p, w, d, h, color, rng, **_):
    p.box((-w / 2, -d / 2, 0), (w / 2, -d / 2 + 0.018, h), color)
    photo = np.array([(120, 160, 200), (200, 170, 130), (110, 150, 100)][rng.integers(3)], float)
    p.box((-w / 2 + 0.02, -d / 2 - 0.0, 0.02), (w / 2 - 0.02, -d / 2 + 0.001, h - 0.02), photo)
    p.box((-0.02, -d / 2 + 0.018, 0), (0.02, d / 2, 0.01), color)
    p.box((-0.02, -d / 2 + 0.018, 0.01), (0.02, -d / 2 + 0.028, h * 0.6), color)
    return []


@_builder("candle")
def _build_candle(p, w, d, h, color, rng, **_):
    r = min(w, d) / 2
    p.cylinder((0, 0, 0), r, h - 0.012, color, 14)
    p.box((-0.0015, -0.0015, h - 0.012), (0.0015, 0.0015, h), _BLACK)
    return []


@_builder("teddy bear")
def _build_teddy(p, w, d, h, color, rng, **_):
    hr = h * 0.2
    p.ellipsoid((0, 0.01, h * 0.3), (w * 0.3, d * 0.38, h * 0.3), color)
    p.ellipsoid((0, 0, h - hr), (hr, hr * 0.95, hr), color)
    for sx in (-1, 1):
        p.ellipsoid(
            (sx * hr * 0.75, 0.01, h - hr * 0.3), (hr * 0.3, hr * 0.2, hr * 0.3), color, 5, 8
        )
        p.ellipsoid(
            (sx * w * 0.36, -d * 0.05, h * 0.4), (w * 0.13, d * 0.18, h * 0.16), color, 5, 8
        )
        p.ellipsoid((sx * w * 0.18, -d * 0.25, h * 0.1), (w * 0.12, d * 0.25, h * 0.1), color, 5, 8)
    p.ellipsoid(
        (0, -hr * 0.85, h - hr * 1.1), (hr * 0.35, hr * 0.25, hr * 0.28), _shade(color, 1.3), 5, 8
    )
    return []


@_builder("laptop")
def _build_laptop(p, w, d, h, color, rng, **_):
    tilt = math.radians(rng.uniform(10, 20))
    base_h = 0.018
    length = (h - base_h) / math.cos(tilt)
    base_d = d - length * math.sin(tilt) - 0.008
    y0 = -d / 2
    hinge_y = y0 + base_d
    p.box((-w / 2, y0, 0), (w / 2, hinge_y, base_h), color)
    p.box(
        (-w / 2 + 0.02, y0 + 0.07, base_h), (w / 2 - 0.02, hinge_y - 0.02, base_h + 0.001), _BLACK
    )
    rot = _rot_x(-tilt)
    pivot = (0.0, hinge_y, base_h)
    p.box((-w / 2, hinge_y, base_h), (w / 2, hinge_y + 0.008, base_h + length), color, rot, pivot)
    p.box(
        (-w / 2 + 0.012, hinge_y - 0.001, base_h + 0.012),
        (w / 2 - 0.012, hinge_y, base_h + length - 0.012),
        _SCREEN,
        rot,
        pivot,
    )
    return []


@_builder("monitor")
def _build_monitor(p, w, d, h, color, rng, **_):
    p.box((-0.12, -d / 2, 0), (0.12, d / 2, 0.015), color)
    p.box((-0.025, 0.02, 0.015), (0.025, 0.05, h * 0.5), color)
    p.box((-w / 2, -0.015, 0.09), (w / 2, 0.02, h), color)
    p.box((-w / 2 + 0.012, -0.017, 0.1), (w / 2 - 0.012, -0.015, h - 0.012), _SCREEN)
    return []


@_builder("printer")
def _build_printer(p, w, d, h, color, rng, **_):
    p.box((-w / 2, -d / 2 + 0.08, 0), (w / 2, d / 2, h), color)
    p.box((-w / 2 + 0.08, -d / 2, 0.03), (w / 2 - 0.08, -d / 2 + 0.08, 0.05), _shade(color, 0.85))
    p.box((-w / 2 + 0.06, -d / 2 + 0.12, h), (w / 2 - 0.06, d / 2 - 0.08, h + 0.002), _BLACK)
    p.box(
        (w / 2 - 0.12, -d / 2 + 0.075, h - 0.06), (w / 2 - 0.02, -d / 2 + 0.08, h - 0.02), _SCREEN
    )
    return []


@_builder("keys")
def _build_keys(p, w, d, h, color, rng, **_):
    ring_r = 0.012
    rx = -w / 2 + ring_r
    p.cylinder((rx, 0, 0), ring_r, 0.003, _METAL_GREY, 10)
    for k, angle in enumerate((-0.35, 0.0, 0.35)[: 2 + rng.integers(2)]):
        rot = _rot_z(angle)
        metal = np.asarray(color, float) if k == 0 else _METAL_GREY
        p.box(
            (rx + ring_r * 0.5, -0.009, 0.001 + 0.002 * k),
            (w / 2 - 0.006, 0.009, 0.003 + 0.002 * k),
            metal,
            rot,
            (rx, 0, 0),
        )
    fob = np.array([(200, 40, 40), (40, 90, 160), (30, 30, 32)][rng.integers(3)], float)
    p.box((rx - 0.01, -d / 2, 0), (rx + 0.012, -d / 2 + 0.02, h), fob)
    return []


@_builder("speaker")
def _build_speaker(p, w, d, h, color, rng, **_):
    p.box((-w / 2, -d / 2 + 0.006, 0), (w / 2, d / 2, h), color)
    front = np.array([40.0, 40.0, 44.0])
    r = min(w, h) * 0.32
    p.cylinder((0, -d / 2 + 0.006, h * 0.35), r, 0.006, front, 18, _rot_x(math.pi / 2))
    p.cylinder((0, -d / 2 + 0.006, h * 0.78), r * 0.35, 0.006, front, 12, _rot_x(math.pi / 2))
    return []


@_builder("book")
def _build_book(p, w, d, h, color, rng, standing: bool = False, **_):
    if standing:
        # Upright on a shelf: thickness h along x, the spine (cover colour) at the front.
        t, depth, height = h, w, d
        p.box((-t / 2, -depth / 2, 0), (t / 2, depth / 2 - 0.003, height - 0.002), _WHITE)
        p.box((-t / 2, -depth / 2, 0), (t / 2, -depth / 2 + 0.006, height), color)
        p.box((-t / 2, -depth / 2, 0), (-t / 2 + 0.002, depth / 2, height), color)
        p.box((t / 2 - 0.002, -depth / 2, 0), (t / 2, depth / 2, height), color)
        return []
    p.box((-w / 2, -d / 2, 0), (w / 2, d / 2, 0.002), color)
    p.box((-w / 2, -d / 2, h - 0.002), (w / 2, d / 2, h), color)
    p.box((-w / 2, -d / 2, 0.002), (-w / 2 + 0.006, d / 2, h - 0.002), color)
    p.box(
        (-w / 2 + 0.006, -d / 2 + 0.002, 0.002), (w / 2 - 0.003, d / 2 - 0.002, h - 0.002), _WHITE
    )
    return []


@_builder("backpack")
def _build_backpack(p, w, d, h, color, rng, **_):
    body_d = d * 0.6
    r = body_d / 2
    p.box((-w / 2, -body_d / 2 + 0.01, 0), (w / 2, body_d / 2 + 0.01, h - r), color)
    p.cylinder((-w / 2, 0.01, h - r), r, w, color, 14, _rot_y(math.pi / 2))
    p.box((-w * 0.35, -d / 2, 0.04), (w * 0.35, -body_d / 2 + 0.01, h * 0.45), _shade(color, 0.85))
    for sx in (-1, 1):
        x = sx * w * 0.25
        p.box((x - 0.025, body_d / 2 + 0.01, 0.08), (x + 0.025, d / 2, h - r), _BLACK)
    return []


@_builder("cardboard box")
def _build_box(p, w, d, h, color, rng, **_):
    p.box((-w / 2, -d / 2, 0), (w / 2, d / 2, h - 0.001), color)
    p.box((-w / 2 + 0.005, -0.025, h - 0.001), (w / 2 - 0.005, 0.025, h), (205, 190, 160))
    return []


@_builder("trash can")
def _build_trash_can(p, w, d, h, color, rng, **_):
    r = min(w, d) / 2
    if rng.random() < 0.6:
        p.frustum((0, 0, 0), r * 0.85, r * 0.97, h - 0.02, color, 20)
        p.cylinder((0, 0, h - 0.02), r, 0.02, _shade(color, 0.7), 20)
    else:
        p.box((-w / 2 + 0.01, -d / 2 + 0.01, 0), (w / 2 - 0.01, d / 2 - 0.01, h - 0.02), color)
        p.box((-w / 2, -d / 2, h - 0.02), (w / 2, d / 2, h), _shade(color, 0.7))
    return []


# --- wall-mounted (back at +y against the wall, z from the item's bottom) ---------------


@_builder("tv")
def _build_tv(p, w, d, h, color, rng, standing: bool = False, **_):
    z0, y0, y1 = 0.0, -d / 2, d / 2
    if standing:  # on a foot: d is the foot's depth, the panel is 6 cm thick
        p.box((-0.15, -d / 2, 0), (0.15, d / 2, 0.015), color)
        p.box((-0.03, 0.0, 0.015), (0.03, 0.04, 0.12), color)
        z0, y0, y1 = 0.1, -0.03, 0.03
    p.box((-w / 2, y0 + 0.004, z0), (w / 2, y1, h), color)
    p.box((-w / 2 + 0.015, y0, z0 + 0.015), (w / 2 - 0.015, y0 + 0.004, h - 0.015), _SCREEN)
    return []


def _frame(p, w, d, h, color, border) -> None:
    for lo, hi in (
        ((-w / 2, -d / 2, 0), (w / 2, d / 2, border)),
        ((-w / 2, -d / 2, h - border), (w / 2, d / 2, h)),
        ((-w / 2, -d / 2, border), (-w / 2 + border, d / 2, h - border)),
        ((w / 2 - border, -d / 2, border), (w / 2, d / 2, h - border)),
    ):
        p.box(lo, hi, color)


@_builder("painting")
def _build_painting(p, w, d, h, color, rng, **_):
    b = 0.035
    _frame(p, w, d, h, color, b)
    palette = np.array(
        [
            (200, 70, 60),
            (235, 200, 90),
            (60, 100, 160),
            (90, 150, 110),
            (230, 225, 210),
            (40, 40, 60),
            (220, 140, 90),
        ],
        float,
    )
    # Abstract art: the canvas split into a few coloured blocks.
    x0, x1, z0, z1 = -w / 2 + b, w / 2 - b, b, h - b
    xs = sorted(rng.uniform(x0 + 0.05, x1 - 0.05, size=rng.integers(1, 3)))
    edges = [x0, *xs, x1]
    zc = rng.uniform(z0 + 0.4 * (z1 - z0), z0 + 0.7 * (z1 - z0))
    colors = palette[rng.permutation(len(palette))]
    k = 0
    for xa, xb in itertools.pairwise(edges):
        for za, zb in ((z0, zc), (zc, z1)):
            p.box((xa, -d / 2 + 0.008, za), (xb, d / 2, zb), colors[k % len(colors)])
            k += 1
    return []


@_builder("mirror")
def _build_mirror(p, w, d, h, color, rng, **_):
    p.box((-w / 2, -d / 2 + 0.004, 0), (w / 2, d / 2, h), color)
    p.box((-w / 2 + 0.03, -d / 2, 0.03), (w / 2 - 0.03, -d / 2 + 0.004, h - 0.03), (196, 208, 215))
    return []


@_builder("clock")
def _build_clock(p, w, d, h, color, rng, **_):
    r = min(w, h) / 2
    face = _rot_x(math.pi / 2)  # cylinder axis +z -> -y (facing out of the wall)
    p.cylinder((0, d / 2, r), r, d - 0.004, color, 24, face)
    p.cylinder((0, -d / 2 + 0.004, r), r * 0.88, 0.002, _WHITE, 24, face)
    for k in range(4):
        a = k * math.pi / 2
        cx, cz = math.sin(a) * r * 0.75, r + math.cos(a) * r * 0.75
        p.box((cx - 0.006, -d / 2, cz - 0.006), (cx + 0.006, -d / 2 + 0.002, cz + 0.006), _BLACK)
    for length, angle in (
        (r * 0.5, rng.uniform(0, 2 * math.pi)),
        (r * 0.75, rng.uniform(0, 2 * math.pi)),
    ):
        rot = _rot_y(angle)
        p.box((-0.004, -d / 2, r), (0.004, -d / 2 + 0.002, r + length), _BLACK, rot, (0, 0, r))
    return []


@_builder("wall shelf")
def _build_wall_shelf(p, w, d, h, color, rng, **_):
    t = 0.03
    p.box((-w / 2, -d / 2, h - t), (w / 2, d / 2, h), color)
    for sx in (-1, 1):
        x = sx * (w / 2 - 0.1)
        p.box((x - 0.01, d / 2 - 0.02, 0), (x + 0.01, d / 2, h - t), _BLACK)
        p.box((x - 0.01, -d / 2 + 0.04, h - t - 0.02), (x + 0.01, d / 2 - 0.02, h - t), _BLACK)
    return [
        _LocalSupport((-w / 2 + 0.01, -d / 2 + 0.01, w / 2 - 0.01, d / 2 - 0.01), h, 0.4, "shelf")
    ]


@_builder("whiteboard")
def _build_whiteboard(p, w, d, h, color, rng, **_):
    _frame(p, w, 0.02, h, _METAL_GREY, 0.02)
    p.box((-w / 2 + 0.02, -0.008, 0.02), (w / 2 - 0.02, 0.01, h - 0.02), color)
    p.box((-w / 2 + 0.1, -d / 2, 0), (w / 2 - 0.1, -0.01, 0.02), _METAL_GREY)
    for k in range(rng.integers(2, 5)):
        ink = np.array([(30, 30, 160), (180, 30, 30), (30, 30, 30), (30, 130, 50)][k % 4], float)
        x = rng.uniform(-w / 2 + 0.1, w / 2 - 0.45)
        z = rng.uniform(0.15, h - 0.15)
        p.box((x, -0.0095, z), (x + rng.uniform(0.15, 0.35), -0.008, z + 0.008), ink)
    p.box((-w / 2 + 0.02, 0.01, 0.02), (w / 2 - 0.02, d / 2, h - 0.02), _METAL_GREY)
    return []


@_builder("window")
def _build_window(p, w, d, h, color, rng, **_):
    b = 0.06
    _frame(p, w, d - 0.02, h, color, b)
    p.box((-w / 2 + b, 0.0, b), (w / 2 - b, d / 2 - 0.01, h - b), _GLASS)
    p.box((-0.02, -d / 2 + 0.02, b), (0.02, 0.0, h - b), color)
    p.box((-w / 2 - 0.03, -d / 2, 0.0), (w / 2 + 0.03, d / 2, 0.03), color)  # sill
    return []


@_builder("air conditioner")
def _build_ac(p, w, d, h, color, rng, **_):
    p.box((-w / 2, -d / 2 + 0.01, 0.04), (w / 2, d / 2, h), color)
    p.box((-w / 2 + 0.03, -d / 2 + 0.03, 0), (w / 2 - 0.03, d / 2, 0.04), _shade(color, 0.75))
    p.box((-w / 2 + 0.05, -d / 2, 0.05), (w / 2 - 0.05, -d / 2 + 0.01, 0.09), _shade(color, 0.6))
    return []


# --- ceiling (z from the item's bottom; the top touches the ceiling) -------------------


@_builder("ceiling light")
def _build_ceiling_light(p, w, d, h, color, rng, **_):
    r = min(w, d) / 2
    p.cylinder((0, 0, h - 0.02), r * 0.4, 0.02, _WHITE, 16)
    p.frustum((0, 0, 0), r * 0.85, r, h - 0.02, color, 24)
    return []


@_builder("ceiling fan")
def _build_ceiling_fan(p, w, d, h, color, rng, **_):
    r = min(w, d) / 2
    p.cylinder((0, 0, h - 0.04), 0.07, 0.04, color, 14)
    p.cylinder((0, 0, 0.12), 0.015, h - 0.16, color, 8)
    p.cylinder((0, 0, 0.06), 0.11, 0.08, color, 18)
    p.ellipsoid((0, 0, 0.06), (0.08, 0.08, 0.06), (250, 246, 230), 5, 10)
    blade = _DARK_WOOD if color.mean() > 150 else _shade(color, 1.4)
    for k in range(5):
        p.box((0.09, -0.06, 0.1), (r, 0.06, 0.11), blade, _rot_z(2 * math.pi * k / 5))
    return []


# --------------------------------------------------------------------------------------
# Scene construction
# --------------------------------------------------------------------------------------


@dataclass
class _Placed:
    """A committed object with the pose it was placed with."""

    obj: SceneObject
    x: float
    y: float
    z: float
    yaw: float
    size: tuple[float, float, float]
    side: int = -1  # wall index (see _SIDE_YAW) for wall-bound objects

    @property
    def front(self) -> np.ndarray:
        return np.array([math.sin(self.yaw), -math.cos(self.yaw)])

    @property
    def right(self) -> np.ndarray:
        return np.array([math.cos(self.yaw), math.sin(self.yaw)])


@dataclass
class _Support:
    """A world-space rectangle small objects may stand on."""

    rect: np.ndarray  # x0, y0, x1, y1
    z: float
    clearance: float
    kind: str
    owner: _Placed
    room: int


# Sides of a room: 0 south (y = y0), 1 east (x = x1), 2 north (y = y1), 3 west (x = x0).
# The yaw that turns an object's back (+y) towards that wall.
_SIDE_YAW = (math.pi, -math.pi / 2, 0.0, math.pi / 2)
_ORIENTED_SMALL = {
    "tv",
    "laptop",
    "monitor",
    "keyboard",
    "printer",
    "microwave",
    "toaster",
    "coffee maker",
    "picture frame",
    "speaker",
}

_FLOOR_COLORS = {
    "living_room": ((176, 132, 90), (150, 110, 75), (198, 160, 118)),
    "bedroom": ((186, 146, 104), (160, 120, 82), (205, 175, 135)),
    "office": ((130, 130, 134), (164, 126, 88), (110, 112, 118)),
    "kitchen": ((214, 210, 200), (180, 176, 168), (160, 150, 135)),
}
_WALL_COLORS = ((236, 232, 222), (222, 226, 230), (232, 222, 204), (214, 224, 214), (240, 240, 236))
_COUNTER_TOPS = ((200, 196, 188), (60, 60, 64), (220, 216, 206), (150, 120, 90))
_DUVETS = ((200, 186, 160), (45, 60, 95), (120, 120, 126), (150, 70, 60), (230, 230, 225))


def _side_of_yaw(yaw: float) -> int:
    """The wall side an object placed with `yaw` has its back to."""
    diffs = [abs(math.remainder(yaw - y, 2 * math.pi)) for y in _SIDE_YAW]
    return int(np.argmin(diffs))


def _quad(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two triangles over 4 corners given counter-clockwise seen from the visible side."""
    return corners, np.array([[0, 1, 2], [0, 2, 3]])


class _SceneBuilder:
    """Holds the growing scene and the occupancy boxes used for rejection sampling."""

    def __init__(self, name: str, seed: int, rng: np.random.Generator):
        self.name = name
        self.seed = seed
        self.rng = rng
        self.rooms: list[Room] = []
        self.doorways: list[Doorway] = []
        self.objects: list[SceneObject] = []
        self.supports: list[_Support] = []
        self._boxes = np.zeros((0, 6))
        self._box_owner: list[int] = []
        self._interior_sides: dict[tuple[int, int], bool] = {}
        self._height = 2.7
        self._wall_color = np.array(_WALL_COLORS[rng.integers(len(_WALL_COLORS))], float)

    # --- layout ---------------------------------------------------------------------------

    def layout_single_room(self, room_type: str) -> None:
        size = {
            "living_room": ((5.2, 6.4), (4.2, 5.0)),
            "kitchen": ((3.8, 4.6), (3.6, 4.4)),
            "office": ((4.0, 5.0), (3.6, 4.4)),
            "bedroom": ((4.0, 4.8), (3.8, 4.4)),
        }[room_type]
        w, d = (round(self.rng.uniform(*r), 2) for r in size)
        self._height = round(self.rng.uniform(2.6, 2.8), 2)
        self.rooms = [Room(room_type, (0.0, 0.0, w, d), self._height)]

    def layout_apartment(self) -> None:
        r = self.rng
        w1, d1 = round(r.uniform(5.4, 6.2), 2), round(r.uniform(4.4, 5.0), 2)
        w2, d2 = round(r.uniform(3.6, 4.2), 2), round(r.uniform(3.8, 4.4), 2)
        w3 = round(r.uniform(4.0, 4.6), 2)
        wt, dt = w1 + w2, d1 + d2
        self._height = round(r.uniform(2.6, 2.8), 2)
        h = self._height
        self.rooms = [
            Room("living_room", (0.0, 0.0, w1, d1), h),
            Room("kitchen", (w1, 0.0, wt, d1), h),
            Room("bedroom", (0.0, d1, w3, dt), h),
            Room("office", (w3, d1, wt, dt), h),
        ]
        half = DOOR_WIDTH_M / 2 + 0.3
        self.doorways = [
            Doorway(
                (0, 1), (w1, round(r.uniform(half, d1 - half), 2)), DOOR_WIDTH_M, DOOR_HEIGHT_M, 0
            ),
            Doorway(
                (0, 2), (round(r.uniform(half, w3 - half), 2), d1), DOOR_WIDTH_M, DOOR_HEIGHT_M, 1
            ),
            Doorway(
                (1, 3),
                (round(r.uniform(w1 + half, wt - half), 2), d1),
                DOOR_WIDTH_M,
                DOOR_HEIGHT_M,
                1,
            ),
        ]

    def _outer(self) -> tuple[float, float, float, float]:
        b = np.array([room.bounds for room in self.rooms])
        return b[:, 0].min(), b[:, 1].min(), b[:, 2].max(), b[:, 3].max()

    def _is_interior_side(self, room_index: int, side: int) -> bool:
        x0, y0, x1, y1 = self.rooms[room_index].bounds
        ox0, oy0, ox1, oy1 = self._outer()
        return not math.isclose((y0, x1, y1, x0)[side], (oy0, ox1, oy1, ox0)[side])

    def inner_rect(self, room_index: int) -> tuple[float, float, float, float]:
        """Room bounds minus half a wall on interior sides (exterior walls are thin quads)."""
        x0, y0, x1, y1 = self.rooms[room_index].bounds
        t = WALL_THICKNESS_M / 2
        s = [t if self._is_interior_side(room_index, k) else 0.0 for k in range(4)]
        return (x0 + s[3], y0 + s[0], x1 - s[1], y1 - s[2])

    # --- objects ----------------------------------------------------------------------------

    def _new_object(
        self,
        category: str,
        vertices: np.ndarray,
        triangles: np.ndarray,
        colors: np.ndarray,
        color: tuple[int, int, int],
        room: int,
        support_id: int = 0,
        texture: str = "plain",
    ) -> SceneObject:
        mesh = o3d.geometry.TriangleMesh(
            o3d.utility.Vector3dVector(vertices),
            o3d.utility.Vector3iVector(triangles.astype(np.int32)),
        )
        mesh.vertex_colors = o3d.utility.Vector3dVector(np.clip(colors, 0.0, 1.0))
        bbox = np.concatenate([vertices.min(0), vertices.max(0)])
        obj = SceneObject(
            instance_id=len(self.objects) + 1,
            category=category,
            mesh=mesh,
            color=tuple(int(c) for c in color),
            center=(bbox[:3] + bbox[3:]) / 2,
            bbox=bbox,
            room=room,
            support_id=support_id,
            texture=texture,
        )
        self.objects.append(obj)
        return obj

    def _add_background(
        self, category: str, parts: _Parts, color, room: int, texture="plain"
    ) -> None:
        v, t, c = parts.arrays()
        self._new_object(category, v, t, c, tuple(int(x) for x in color), room, texture=texture)

    def build_architecture(self) -> None:
        """Floors, ceilings and walls (with doorway openings) of every room."""
        h = self._height
        for i, room in enumerate(self.rooms):
            x0, y0, x1, y1 = room.bounds
            floor_color = np.array(_FLOOR_COLORS[room.type][self.rng.integers(3)], float)
            p = _Parts()
            p.add(
                *_quad(np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]], float)),
                floor_color,
            )
            texture = "tiles" if room.type == "kitchen" else "planks"
            if room.type == "office" and floor_color[0] < 140 and floor_color[2] > 120:
                texture = "plain"  # grey office carpet
            self._add_background("floor", p, floor_color, i, texture)
            p = _Parts()
            p.add(
                *_quad(np.array([[x0, y0, h], [x0, y1, h], [x1, y1, h], [x1, y0, h]], float)),
                _WHITE,
            )
            self._add_background("ceiling", p, _WHITE, i)
        # Exterior walls: one inward-facing quad per side of the outline.
        ox0, oy0, ox1, oy1 = self._outer()
        corners = [
            ((ox0, oy0), (ox1, oy0)),
            ((ox1, oy0), (ox1, oy1)),
            ((ox1, oy1), (ox0, oy1)),
            ((ox0, oy1), (ox0, oy0)),
        ]
        for (ax, ay), (bx, by) in corners:
            p = _Parts()
            p.add(
                *_quad(np.array([[bx, by, 0], [ax, ay, 0], [ax, ay, h], [bx, by, h]], float)),
                self._wall_color,
            )
            self._add_background("wall", p, self._wall_color, -1)
        # Interior walls: boxes along shared room edges, with door openings cut out.
        t = WALL_THICKNESS_M / 2
        for line in self._interior_lines():
            axis, c, a0, a1 = line
            doors = sorted(
                (dw.center[1 - axis] - dw.width / 2, dw.center[1 - axis] + dw.width / 2)
                for dw in self.doorways
                if dw.wall_axis == axis
                and math.isclose(dw.center[axis], c)
                and a0 < dw.center[1 - axis] < a1
            )
            p = _Parts()
            cursor = a0
            for d0, d1 in [*doors, (a1, a1)]:
                if d0 > cursor:
                    p.box(*self._wall_box(axis, c, cursor, d0, 0.0, h, t), self._wall_color)
                if d1 > d0:
                    p.box(*self._wall_box(axis, c, d0, d1, DOOR_HEIGHT_M, h, t), self._wall_color)
                cursor = d1
            self._add_background("wall", p, self._wall_color, -1)
        for dw in self.doorways:
            for room_index in dw.rooms:
                self._reserve_doorway(dw, room_index)

    @staticmethod
    def _wall_box(axis: int, c: float, a0: float, a1: float, z0: float, z1: float, t: float):
        if axis == 0:
            return (c - t, a0, z0), (c + t, a1, z1)
        return (a0, c - t, z0), (a1, c + t, z1)

    def _interior_lines(self) -> list[tuple[int, float, float, float]]:
        """Shared room edges as (axis, coordinate, start, end); axis 0 means x = coordinate."""
        lines: list[tuple[int, float, float, float]] = []
        t = WALL_THICKNESS_M / 2
        for (_i, a), (_j, b) in itertools.combinations(enumerate(self.rooms), 2):
            ax0, ay0, ax1, ay1 = a.bounds
            bx0, by0, bx1, by1 = b.bounds
            for axis, c_a, c_b, lo, hi in (
                (0, ax1, bx0, max(ay0, by0), min(ay1, by1)),
                (0, ax0, bx1, max(ay0, by0), min(ay1, by1)),
                (1, ay1, by0, max(ax0, bx0), min(ax1, bx1)),
                (1, ay0, by1, max(ax0, bx0), min(ax1, bx1)),
            ):
                if math.isclose(c_a, c_b) and hi - lo > 1e-6:
                    lines.append((axis, c_a, lo, hi))
        # Merge collinear touching segments into one wall and trim T-junctions with a
        # perpendicular wall so that boxes do not overlap.
        merged: list[list[float]] = []
        for axis, c, lo, hi in sorted(lines):
            if (
                merged
                and merged[-1][0] == axis
                and math.isclose(merged[-1][1], c)
                and lo <= merged[-1][3] + 1e-6
            ):
                merged[-1][3] = max(merged[-1][3], hi)
            else:
                merged.append([axis, c, lo, hi])
        out = []
        for axis, c, lo, hi in merged:
            for other in merged:
                if other[0] != axis and other[2] - 1e-6 <= c <= other[3] + 1e-6:
                    if math.isclose(other[1], lo):
                        lo += t
                    elif math.isclose(other[1], hi):
                        hi -= t
            out.append((int(axis), float(c), float(lo), float(hi)))
        return out

    def _reserve(self, box, owner: int = -1) -> None:
        self._boxes = np.vstack([self._boxes, np.asarray(box, float)[None]])
        self._box_owner.append(owner)

    def _reserve_doorway(self, dw: Doorway, room_index: int) -> None:
        """Keep the opening and the floor in front of it free of furniture and wall items."""
        x0, y0, x1, y1 = self.inner_rect(room_index)
        half = dw.width / 2 + 0.2
        cx, cy = dw.center
        h = self._height
        if dw.wall_axis == 0:
            inside_low = cx <= x0 + 1e-6  # the room lies on the +x side of the wall
            xa, xb = (
                (x0 - 0.1, x0 + DOOR_CLEARANCE_M)
                if inside_low
                else (x1 - DOOR_CLEARANCE_M, x1 + 0.1)
            )
            self._reserve((xa, cy - half, 0.0, xb, cy + half, h))
        else:
            inside_low = cy <= y0 + 1e-6
            ya, yb = (
                (y0 - 0.1, y0 + DOOR_CLEARANCE_M)
                if inside_low
                else (y1 - DOOR_CLEARANCE_M, y1 + 0.1)
            )
            self._reserve((cx - half, ya, 0.0, cx + half, yb, h))

    def _is_free(self, bbox: np.ndarray, gap: float, ignore: int = 0) -> bool:
        if len(self._boxes) == 0:
            return True
        b = self._boxes
        hit = (
            (bbox[0] < b[:, 3] + gap)
            & (bbox[3] > b[:, 0] - gap)
            & (bbox[1] < b[:, 4] + gap)
            & (bbox[4] > b[:, 1] - gap)
            & (bbox[2] < b[:, 5])
            & (bbox[5] > b[:, 2])
        )
        if ignore:
            hit &= np.asarray(self._box_owner) != ignore
        return not hit.any()

    def sample_size(self, category: str) -> tuple[float, float, float]:
        cat = CATEGORIES[category]
        return tuple(float(self.rng.uniform(lo, hi)) for lo, hi in cat.size_m)  # type: ignore[return-value]

    def instance_color(self, category: str) -> np.ndarray:
        cat = CATEGORIES[category]
        base = np.array(cat.colors[self.rng.integers(len(cat.colors))], float)
        # Per-instance variation: a brightness change plus a small per-channel tint.
        return np.clip(base * self.rng.uniform(0.88, 1.12) + self.rng.uniform(-8, 8, 3), 0, 255)

    def build_local(self, category: str, size, color: np.ndarray, **style):
        parts = _Parts()
        supports = _BUILDERS[category](parts, *size, color, self.rng, category=category, **style)
        v, t, c = parts.arrays()
        return v, t, c, supports

    def place(
        self,
        category: str,
        room: int,
        candidates,
        size: tuple[float, float, float] | None = None,
        color: np.ndarray | None = None,
        gap: float = 0.04,
        support: _Support | None = None,
        side: int = -1,
        **style,
    ) -> _Placed | None:
        """Build one object and put it at the first collision-free pose of `candidates`.

        candidates: iterable of (x, y, z, yaw) for the object's bottom centre.
        """
        size = size or self.sample_size(category)
        color = self.instance_color(category) if color is None else color
        v, t, c, local_supports = self.build_local(category, size, color, **style)
        ix0, iy0, ix1, iy1 = self.inner_rect(room)
        ignore = support.owner.obj.instance_id if support else 0
        for x, y, z, yaw in candidates:
            rot = _rot_z(yaw)
            world = v @ rot.T + (x, y, z)
            lo, hi = world.min(0), world.max(0)
            bbox = np.concatenate([lo, hi])
            if lo[0] < ix0 - 1e-6 or lo[1] < iy0 - 1e-6 or hi[0] > ix1 + 1e-6 or hi[1] > iy1 + 1e-6:
                continue
            if lo[2] < -1e-6 or hi[2] > self._height - 1e-6:
                continue
            if support is not None:
                r = support.rect
                if lo[0] < r[0] or lo[1] < r[1] or hi[0] > r[2] or hi[1] > r[3]:
                    continue
                if hi[2] > support.z + support.clearance:
                    continue
            if not self._is_free(bbox, gap, ignore):
                continue
            obj = self._new_object(
                category,
                world,
                t,
                c,
                tuple(int(a) for a in color),
                room,
                support.owner.obj.instance_id if support else 0,
            )
            self._reserve(bbox, obj.instance_id)
            placed = _Placed(obj, x, y, z, yaw, size, side)
            for ls in local_supports:
                corners = (
                    np.array([[ls.rect[0], ls.rect[1], 0], [ls.rect[2], ls.rect[3], 0]]) @ rot.T
                )
                rect = np.array(
                    [
                        corners[:, 0].min(),
                        corners[:, 1].min(),
                        corners[:, 0].max(),
                        corners[:, 1].max(),
                    ]
                ) + [x, y, x, y]
                self.supports.append(_Support(rect, z + ls.z, ls.clearance, ls.kind, placed, room))
            return placed
        return None

    # --- placement patterns -----------------------------------------------------------------

    def wall_pose(self, room: int, side: int, along: float, depth: float, z: float, gap: float):
        """(x, y, z, yaw) of an object of depth `depth` with its back `gap` off wall `side`."""
        x0, y0, x1, y1 = self.inner_rect(room)
        off = gap + depth / 2
        yaw = _SIDE_YAW[side]
        if side == 0:
            return along, y0 + off, z, yaw
        if side == 1:
            return x1 - off, along, z, yaw
        if side == 2:
            return along, y1 - off, z, yaw
        return x0 + off, along, z, yaw

    def wall_span(self, room: int, side: int) -> tuple[float, float]:
        x0, y0, x1, y1 = self.inner_rect(room)
        return (x0, x1) if side in (0, 2) else (y0, y1)

    def against_wall(
        self,
        category: str,
        room: int,
        side: int | None = None,
        along: float | None = None,
        z: float = REST_GAP_M,
        tries: int = 40,
        wall_gap: float = 0.01,
        sides: tuple[int, ...] = (0, 1, 2, 3),
        **kw,
    ) -> _Placed | None:
        """Place with the back to a wall; random side/position unless given."""
        size = kw.pop("size", None) or self.sample_size(category)
        lengths = np.array([np.subtract(*self.wall_span(room, s)[::-1]) for s in sides])

        def candidates():
            for k in range(tries):
                s = (
                    side
                    if side is not None
                    else int(sides[self.rng.choice(len(sides), p=lengths / lengths.sum())])
                )
                a0, a1 = self.wall_span(room, s)
                if along is not None:
                    a = along + (self.rng.uniform(-0.3, 0.3) if k > 0 else 0.0)
                else:
                    a = self.rng.uniform(a0 + size[0] / 2, max(a0 + size[0] / 2, a1 - size[0] / 2))
                yield self.wall_pose(room, s, a, size[1], z, wall_gap)

        placed = self.place(category, room, candidates(), size=size, **kw)
        if placed is not None:
            placed.side = _side_of_yaw(placed.yaw)
        return placed

    def on_wall(
        self,
        category: str,
        room: int,
        z_range: tuple[float, float],
        side: int | None = None,
        along: float | None = None,
        tries: int = 40,
        sides: tuple[int, ...] = (0, 1, 2, 3),
        **kw,
    ) -> _Placed | None:
        """Hang a wall item with its bottom at a height drawn from z_range."""
        size = kw.pop("size", None) or self.sample_size(category)
        lo, hi = z_range
        hi = min(hi, self._height - size[2] - 0.1)
        if hi < lo:
            return None
        z = float(self.rng.uniform(lo, hi))
        return self.against_wall(
            category,
            room,
            side,
            along,
            z=z,
            tries=tries,
            wall_gap=0.002,
            sides=sides,
            size=size,
            **kw,
        )

    def in_front_of(
        self, anchor: _Placed, category: str, distance: float, turn: bool = False, **kw
    ) -> _Placed | None:
        """In front of the anchor, `distance` from it; `turn` makes it face the anchor (chairs)."""
        size = kw.pop("size", None) or self.sample_size(category)
        f = anchor.front
        base = np.array([anchor.x, anchor.y]) + f * (anchor.size[1] / 2 + distance + size[1] / 2)
        yaw = anchor.yaw + (math.pi if turn else 0.0)
        cands = [(base[0], base[1], REST_GAP_M, yaw)]
        cands += [
            (base[0] + dx, base[1] + dy, REST_GAP_M, yaw)
            for dx, dy in self.rng.uniform(-0.15, 0.15, (8, 2))
        ]
        return self.place(category, anchor.obj.room, cands, size=size, **kw)

    def beside(
        self,
        anchor: _Placed,
        category: str,
        sign: int,
        gap: float = 0.06,
        facing_yaw: float | None = None,
        **kw,
    ) -> _Placed | None:
        """Next to the anchor's left (-1) or right (+1), back aligned with the anchor's back."""
        size = kw.pop("size", None) or self.sample_size(category)
        r, f = anchor.right, anchor.front
        base = (
            np.array([anchor.x, anchor.y])
            + r * sign * (anchor.size[0] / 2 + gap + size[0] / 2)
            - f * (anchor.size[1] / 2 - size[1] / 2)
        )
        yaw = anchor.yaw if facing_yaw is None else facing_yaw
        cands = [(base[0], base[1], REST_GAP_M, yaw)]
        cands += [
            (base[0] + r[0] * sign * s, base[1] + r[1] * sign * s, REST_GAP_M, yaw)
            for s in (0.05, 0.15, 0.3)
        ]
        return self.place(category, anchor.obj.room, cands, size=size, **kw)

    def facing(
        self, category: str, room: int, xy: np.ndarray, target: np.ndarray, **kw
    ) -> _Placed | None:
        """At xy, turned (by a multiple of 90 degrees) so that its front looks at target."""
        d = np.asarray(target, float) - xy
        yaw = math.atan2(d[0], -d[1])
        yaw = round(yaw / (math.pi / 2)) * (math.pi / 2)
        return self.place(category, room, [(xy[0], xy[1], REST_GAP_M, yaw)], **kw)

    def free_standing(
        self,
        category: str,
        room: int,
        near_wall: bool = False,
        tries: int = 40,
        margin: float = 0.7,
        **kw,
    ) -> _Placed | None:
        """Anywhere on the floor (`margin` from the walls) or against a wall, near_wall."""
        size = kw.pop("size", None) or self.sample_size(category)
        x0, y0, x1, y1 = self.inner_rect(room)
        r = max(size[0], size[1]) / 2 + 0.02

        def candidates():
            for _ in range(tries):
                if near_wall:  # plants, lamps and bins sit in corners and along walls
                    s = int(self.rng.integers(4))
                    a0, a1 = self.wall_span(room, s)
                    a = self.rng.uniform(a0 + r, a1 - r)
                    x, y, _z, _yaw = self.wall_pose(room, s, a, 2 * r, REST_GAP_M, 0.05)
                    yield x, y, REST_GAP_M, _SIDE_YAW[s]
                else:
                    # Keep a walkway between central furniture and the walls.
                    m = margin
                    if x1 - x0 < 2 * (m + r) or y1 - y0 < 2 * (m + r):
                        return
                    yield (
                        self.rng.uniform(x0 + m + r, x1 - m - r),
                        self.rng.uniform(y0 + m + r, y1 - m - r),
                        REST_GAP_M,
                        float(self.rng.integers(4)) * math.pi / 2,
                    )

        return self.place(category, room, candidates(), size=size, **kw)

    def on_ceiling(self, category: str, room: int, xy: tuple[float, float]) -> _Placed | None:
        size = self.sample_size(category)
        z = self._height - size[2] - 0.002
        return self.place(category, room, [(xy[0], xy[1], z, 0.0)], size=size, gap=0.02)

    def room_supports(
        self, room: int, owners: tuple[str, ...] = (), kinds: tuple[str, ...] = ()
    ) -> list[_Support]:
        out = [s for s in self.supports if s.room == room]
        if owners:
            out = [s for s in out if s.owner.obj.category in owners]
        if kinds:
            out = [s for s in out if s.kind in kinds]
        return out

    def on_support(
        self,
        category: str,
        support: _Support,
        tries: int = 12,
        local: tuple[float, float] | None = None,
        yaw_jitter_deg: float = 8.0,
        **kw,
    ) -> _Placed | None:
        """Stand a small object on a support; `local` = position in the owner's frame."""
        size = kw.pop("size", None) or self.sample_size(category)
        owner = support.owner
        oriented = category in _ORIENTED_SMALL
        r = support.rect
        z = support.z + REST_GAP_M

        def candidates():
            for k in range(tries):
                if oriented:
                    yaw = owner.yaw + math.radians(self.rng.normal(0, yaw_jitter_deg))
                else:
                    yaw = self.rng.uniform(-math.pi, math.pi)
                if local is not None:
                    jitter = self.rng.normal(0, 0.03, 2) if k else np.zeros(2)
                    xy = (
                        np.array([owner.x, owner.y])
                        + owner.right * (local[0] + jitter[0])
                        + owner.front * -(local[1] + jitter[1])
                    )
                    yield xy[0], xy[1], z, yaw
                else:
                    yield self.rng.uniform(r[0], r[2]), self.rng.uniform(r[1], r[3]), z, yaw

        return self.place(
            category,
            support.owner.obj.room,
            candidates(),
            size=size,
            gap=0.01,
            support=support,
            **kw,
        )

    def small(self, category: str, room: int, count: int, prefer: tuple[str, ...] = ()) -> int:
        """Scatter `count` small objects on the room's surfaces, preferring `prefer` owners."""
        placed = 0
        for _ in range(count):
            candidates = self.room_supports(room, prefer) if prefer else []
            if not candidates or self.rng.random() < 0.2:
                candidates = self.room_supports(room, kinds=("top",)) or self.room_supports(room)
            if not candidates:
                return placed
            areas = np.array(
                [(s.rect[2] - s.rect[0]) * (s.rect[3] - s.rect[1]) for s in candidates]
            )
            for _attempt in range(3):
                s = candidates[int(self.rng.choice(len(candidates), p=areas / areas.sum()))]
                if self.on_support(category, s) is not None:
                    placed += 1
                    break
        return placed

    def fill_shelves(self, room: int, fill: float = 0.65) -> None:
        """Short rows of standing books, or an ornament, on each level of the room's shelves."""
        for s in self.room_supports(room, kinds=("shelf",)):
            owner = s.owner
            along_x = abs(math.sin(owner.yaw)) < 0.5  # the owner's width runs along world x
            lo, hi = (s.rect[0], s.rect[2]) if along_x else (s.rect[1], s.rect[3])
            shelf_depth = s.rect[3] - s.rect[1] if along_x else s.rect[2] - s.rect[0]
            depth_mid = (s.rect[1] + s.rect[3]) / 2 if along_x else (s.rect[0] + s.rect[2]) / 2
            front = owner.front[1] if along_x else owner.front[0]
            if self.rng.random() < fill:
                cursor = lo + self.rng.uniform(0.0, 0.5) * (hi - lo)
                for _ in range(self._count(2, 5)):
                    w, d, t = self.sample_size("book")
                    w = min(w, shelf_depth - 0.02)
                    if d > s.clearance - 0.005 or cursor + t > hi:
                        break
                    # Upright, spine to the front, pushed towards the front edge of the shelf.
                    depth = depth_mid + front * (shelf_depth / 2 - w / 2 - 0.01)
                    c = cursor + t / 2
                    x, y = (c, depth) if along_x else (depth, c)
                    self.place(
                        "book",
                        owner.obj.room,
                        [(x, y, s.z + REST_GAP_M, owner.yaw)],
                        size=(w, d, t),
                        gap=0.001,
                        support=s,
                        standing=True,
                    )
                    cursor += t + 0.002
            ornaments = [
                c
                for c in ("vase", "picture frame", "candle", "speaker")
                if self.rooms[room].type in CATEGORIES[c].rooms
            ]
            if ornaments and self.rng.random() < 0.45:
                self.on_support(str(self.rng.choice(ornaments)), s)

    # --- per-room recipes -------------------------------------------------------------------

    def furnish(self, room: int) -> None:
        rtype = self.rooms[room].type
        self._windows(room)
        getattr(self, f"_furnish_{rtype}")(room)
        self._ceiling(room, fan=rtype in ("living_room", "bedroom") and self.rng.random() < 0.35)
        self.fill_shelves(room)

    def _count(self, lo: int, hi: int) -> int:
        return int(self.rng.integers(lo, hi + 1))

    def _windows(self, room: int) -> None:
        sides = tuple(s for s in range(4) if not self._is_interior_side(room, s))
        for _ in range(self._count(1, 2) if sides else 0):
            # Sills above worktop height so counters and sofas can stand below windows.
            self.on_wall("window", room, (1.0, 1.1), sides=sides)

    def _ceiling(self, room: int, fan: bool) -> None:
        """A fan or a light in the middle; large rooms get a second light along the long axis."""
        x0, y0, x1, y1 = self.inner_rect(room)
        cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
        if fan or self.rooms[room].area_m2 > 20:
            dx, dy = ((x1 - x0) / 4, 0.0) if x1 - x0 > y1 - y0 else (0.0, (y1 - y0) / 4)
            if fan:
                self.on_ceiling("ceiling fan", room, (cx, cy))
                self.on_ceiling("ceiling light", room, (cx + 1.4 * dx, cy + 1.4 * dy))
            else:
                self.on_ceiling("ceiling light", room, (cx - dx, cy - dy))
                self.on_ceiling("ceiling light", room, (cx + dx, cy + dy))
        else:
            self.on_ceiling("ceiling light", room, (cx, cy))

    def _decorate_walls(self, room: int, items: dict[str, tuple[int, int]]) -> None:
        heights = {
            "painting": (1.2, 1.6),
            "clock": (1.7, 1.9),
            "mirror": (1.0, 1.3),
            "wall shelf": (1.3, 1.6),
            "whiteboard": (0.9, 1.1),
            "air conditioner": (2.05, 2.3),
            "tv": (1.0, 1.2),
        }
        for category, (lo, hi) in items.items():
            for _ in range(self._count(lo, hi)):
                self.on_wall(category, room, heights[category])

    def _furnish_living_room(self, room: int) -> None:
        sofa = self.against_wall("sofa", room)
        table = None
        if sofa is not None:
            table = self.in_front_of(sofa, "coffee table", float(self.rng.uniform(0.35, 0.5)))
            if self.rng.random() < 0.6:
                self.on_wall(
                    "painting", room, (1.15, 1.35), side=sofa.side, along=self._along(sofa)
                )
            sign = int(self.rng.choice([-1, 1]))
            if self.rng.random() < 0.7:
                self.beside(sofa, "floor lamp", sign)
            if self.rng.random() < 0.5:
                self.beside(sofa, "potted plant", -sign)
        if table is not None:
            for sign in (-1, 1):
                if self.rng.random() < 0.55:
                    size = self.sample_size("armchair")
                    xy = np.array([table.x, table.y]) + table.right * sign * (
                        table.size[0] / 2 + 0.35 + size[1] / 2
                    )
                    self.facing("armchair", room, xy, np.array([table.x, table.y]), size=size)
        opposite = (sofa.side + 2) % 4 if sofa is not None else None
        stand = self.against_wall("tv stand", room, side=opposite) or self.against_wall(
            "tv stand", room
        )
        if stand is not None:
            tv = self.on_wall(
                "tv",
                room,
                (stand.size[2] + 0.25, stand.size[2] + 0.45),
                side=stand.side,
                along=self._along(stand),
                tries=6,
            )
            if tv is None:  # wall taken (a window): the tv stands on its foot on the stand
                top = [s for s in self.supports if s.owner is stand][0]
                size = self.sample_size("tv")
                self.on_support(
                    "tv",
                    top,
                    local=(0.0, 0.0),
                    size=(min(size[0], stand.size[0] - 0.1), 0.25, size[2] + 0.1),
                    standing=True,
                )
            for sign in (-1, 1):
                if self.rng.random() < 0.5:
                    shelf = self.room_supports(room, ("tv stand",))
                    if shelf:
                        self.on_support(
                            "speaker", shelf[0], local=(sign * (stand.size[0] / 2 - 0.15), 0.0)
                        )
        for _ in range(self._count(1, 2)):
            self.against_wall("bookshelf", room)
        if self.rng.random() < 0.5:
            self.against_wall("cabinet", room)
        for _ in range(self._count(1, 2)):
            self.free_standing("potted plant", room, near_wall=True)
        if self.rng.random() < 0.4:
            self.free_standing("ottoman", room)
        self._decorate_walls(
            room,
            {
                "painting": (1, 2),
                "clock": (0, 1),
                "mirror": (0, 1),
                "wall shelf": (1, 2),
                "air conditioner": (0, 1),
            },
        )
        self.small("remote control", room, self._count(1, 2), ("coffee table", "tv stand"))
        self.small("mug", room, self._count(1, 3), ("coffee table", "dining table"))
        self.small("keys", room, 1, ("coffee table", "cabinet", "tv stand"))
        self.small("vase", room, self._count(1, 2), ("cabinet", "tv stand", "coffee table"))
        self.small("candle", room, self._count(0, 2), ("coffee table", "cabinet", "wall shelf"))
        self.small("picture frame", room, self._count(1, 2), ("cabinet", "tv stand", "wall shelf"))
        self.small("bowl", room, self._count(0, 1), ("coffee table",))
        self.small("book", room, self._count(1, 2), ("coffee table",))
        self.small("cell phone", room, self._count(0, 1), ("coffee table",))
        self.small("laptop", room, self._count(0, 1), ("coffee table",))
        self.small("bottle", room, self._count(0, 1), ("coffee table", "cabinet"))
        self.small("table lamp", room, self._count(0, 1), ("cabinet",))

    def _along(self, placed: _Placed) -> float:
        return placed.x if placed.side in (0, 2) else placed.y

    def _furnish_kitchen(self, room: int) -> None:
        top_color = np.array(_COUNTER_TOPS[self.rng.integers(len(_COUNTER_TOPS))], float)
        front_color = self.instance_color("kitchen counter")
        spans = [(s, np.subtract(*self.wall_span(room, s)[::-1])) for s in range(4)]
        spans.sort(key=lambda sl: -sl[1] + self.rng.uniform(0, 0.8))
        # Two runs on the two longest walls: fridge + sink + dishwasher, then stove between counters.
        runs = [
            ["refrigerator", "kitchen counter", "sink", "dishwasher"],
            ["kitchen counter", "stove", "kitchen counter"],
        ]
        if self.rng.random() < 0.5:
            runs[0] = runs[0][::-1]
        placed_run: list[_Placed] = []
        for run, (side, _length) in zip(runs, spans[:2], strict=True):
            placed_run += self._counter_run(room, side, run, top_color, front_color)
        present = {p.obj.category for p in placed_run}
        missing = [c for c in ("sink", "stove", "refrigerator") if c not in present]
        for side, _length in spans[2:]:
            if missing:
                got = self._counter_run(room, side, missing, top_color, front_color)
                placed_run += got
                missing = [c for c in missing if c not in {p.obj.category for p in got}]
        for item in placed_run:
            if item.obj.category in ("kitchen counter", "sink"):
                w = min(item.size[0], 1.2)
                size = (w, *self.sample_size("wall cabinet")[1:])
                self.on_wall(
                    "wall cabinet",
                    room,
                    (1.45, 1.5),
                    side=item.side,
                    along=self._along(item),
                    size=size,
                    color=front_color,
                    tries=1,
                    gap=0.001,
                )
        # Chairs plus a walkway around the table need ~1.3 m; small kitchens push it to a wall.
        size = self.sample_size("dining table")
        table = self.free_standing("dining table", room, margin=1.35, size=size)
        if table is None:
            size = (min(size[0], 1.4), *size[1:])
            table = self.against_wall("dining table", room, size=size, wall_gap=0.05)
        if table is not None:
            self._chairs_around(table, room)
        for _ in range(self._count(0, 2)):
            self.free_standing("bar stool", room, near_wall=True)
        self.free_standing("trash can", room, near_wall=True)
        if self.rng.random() < 0.5:
            self.free_standing("potted plant", room, near_wall=True)
        self._decorate_walls(room, {"clock": (0, 1), "painting": (0, 1)})
        counters = ("kitchen counter",)
        self.small("microwave", room, 1, counters)
        self.small("kettle", room, 1, counters + ("stove",))
        self.small("cooking pot", room, self._count(1, 2), ("stove",))
        self.small("toaster", room, self._count(0, 1), counters)
        self.small("coffee maker", room, self._count(0, 1), counters)
        self.small("cutting board", room, 1, counters)
        self.small("bowl", room, self._count(1, 3), counters + ("dining table",))
        self.small("mug", room, self._count(2, 4), counters + ("dining table",))
        self.small("bottle", room, self._count(1, 3), counters + ("dining table",))
        self.small("vase", room, self._count(0, 1), ("dining table",))
        self.small("keys", room, self._count(0, 1), counters + ("dining table",))
        self.small("cell phone", room, self._count(0, 1), ("dining table",))
        self.small("candle", room, self._count(0, 1), ("dining table",))
        self.small("book", room, self._count(0, 1), counters)

    def _counter_run(self, room, side, items, top_color, front_color) -> list[_Placed]:
        """Appliances and counters side by side along one wall, starting at a corner."""
        a0, a1 = self.wall_span(room, side)
        cursor = a0 + 0.005
        placed = []
        for category in items:
            size = self.sample_size(category)
            style = {}
            color = None
            if category in ("kitchen counter", "sink"):
                style = {"top_color": top_color}
                color = front_color
            # Slide along the wall past doorways and windows; a failed item leaves the cursor
            # where it was so that a lower item can still use the spot.
            for shift in np.arange(0.0, 1.8, 0.15):
                start = cursor + shift
                if start + size[0] > a1:
                    break
                p = self.against_wall(
                    category,
                    room,
                    side=side,
                    along=start + size[0] / 2,
                    tries=1,
                    size=size,
                    color=color,
                    gap=0.001,
                    **style,
                )
                if p is not None:
                    placed.append(p)
                    cursor = start + size[0] + 0.005
                    break
        # Gaps between cupboards collide with nothing, so small objects may still fill them.
        for p in placed:
            p.side = side
        return placed

    def _chairs_around(self, table: _Placed, room: int) -> None:
        long_x = abs(math.sin(table.yaw)) < 0.5  # table width runs along world x
        w, d = table.size[0], table.size[1]
        per_side = max(1, int(w // 0.6))
        centre = np.array([table.x, table.y])
        axis_w = np.array([1.0, 0.0]) if long_x else np.array([0.0, 1.0])
        axis_d = np.array([0.0, 1.0]) if long_x else np.array([1.0, 0.0])
        for sign in (-1, 1):
            for k in range(per_side):
                if self.rng.random() < 0.15:
                    continue
                size = self.sample_size("chair")
                off = (k - (per_side - 1) / 2) * (w / per_side)
                xy = centre + axis_w * off + axis_d * sign * (d / 2 + 0.12 + size[1] / 2)
                self.facing("chair", room, xy, centre, size=size, gap=0.02)
        for sign in (-1, 1):
            if self.rng.random() < 0.4:
                size = self.sample_size("chair")
                xy = centre + axis_w * sign * (w / 2 + 0.12 + size[1] / 2)
                self.facing("chair", room, xy, centre, size=size, gap=0.02)

    def _furnish_office(self, room: int) -> None:
        desks = []
        for _ in range(self._count(1, 2)):
            desk = self.against_wall("desk", room)
            if desk is None:
                continue
            desks.append(desk)
            self.in_front_of(desk, "office chair", 0.05, turn=True)
            top = [s for s in self.supports if s.owner is desk][0]
            u = float(self.rng.uniform(-0.2, 0.1))  # left of the drawer pedestal
            self.on_support("monitor", top, local=(u, desk.size[1] / 2 - 0.14))
            self.on_support("keyboard", top, local=(u, -desk.size[1] / 2 + 0.12))
            if self.rng.random() < 0.5:
                self.on_support("laptop", top)
            if self.rng.random() < 0.5:
                self.on_support(
                    "table lamp", top, local=(desk.size[0] / 2 - 0.2, desk.size[1] / 2 - 0.17)
                )
            if self.rng.random() < 0.7:
                self.beside(desk, "trash can", int(self.rng.choice([-1, 1])))
        for _ in range(self._count(1, 2)):
            self.against_wall("bookshelf", room)
        for _ in range(self._count(1, 2)):
            self.against_wall("filing cabinet", room)
        if self.rng.random() < 0.5:
            self.against_wall("cabinet", room)
        if self.rng.random() < 0.4:
            self.free_standing("armchair", room, near_wall=True)
        for _ in range(self._count(0, 2)):
            self.free_standing("potted plant", room, near_wall=True)
        for _ in range(self._count(0, 2)):
            self.free_standing("cardboard box", room, near_wall=True)
        if self.rng.random() < 0.5:
            self.free_standing("backpack", room, near_wall=True)
        if self.rng.random() < 0.6:
            self.free_standing("floor lamp", room, near_wall=True)
        self._decorate_walls(
            room,
            {
                "whiteboard": (0, 1),
                "painting": (0, 2),
                "clock": (0, 1),
                "wall shelf": (1, 2),
                "air conditioner": (0, 1),
            },
        )
        self.small("printer", room, 1, ("filing cabinet", "cabinet", "desk"))
        self.small("mug", room, self._count(1, 3), ("desk",))
        self.small("bottle", room, self._count(0, 2), ("desk",))
        self.small("cell phone", room, self._count(0, 1), ("desk",))
        self.small("keys", room, self._count(0, 1), ("desk", "filing cabinet"))
        self.small("speaker", room, self._count(0, 1), ("desk", "cabinet"))
        self.small("picture frame", room, self._count(0, 2), ("desk", "wall shelf", "cabinet"))
        self.small("book", room, self._count(1, 3), ("desk", "cabinet"))
        self.small("coffee maker", room, self._count(0, 1), ("cabinet", "filing cabinet"))

    def _furnish_bedroom(self, room: int) -> None:
        duvet = np.array(_DUVETS[self.rng.integers(len(_DUVETS))], float)
        bed = self.against_wall("bed", room, duvet=duvet)
        if bed is not None:
            for sign in (-1, 1):
                if self.rng.random() < 0.85:
                    stand = self.beside(bed, "nightstand", sign, gap=0.04)
                    if stand is not None and self.rng.random() < 0.75:
                        top = [s for s in self.supports if s.owner is stand][0]
                        self.on_support("table lamp", top, local=(0.0, 0.0))
            if self.rng.random() < 0.6:
                self.on_wall("painting", room, (1.15, 1.4), side=bed.side, along=self._along(bed))
        self.against_wall("wardrobe", room)
        if self.rng.random() < 0.7:
            dresser = self.against_wall("dresser", room)
            if dresser is not None and self.rng.random() < 0.6:
                self.on_wall(
                    "mirror",
                    room,
                    (dresser.size[2] + 0.2, dresser.size[2] + 0.35),
                    side=dresser.side,
                    along=self._along(dresser),
                    tries=5,
                )
        if self.rng.random() < 0.5:
            desk = self.against_wall("desk", room)
            if desk is not None:
                self.in_front_of(desk, "chair", 0.05, turn=True)
                top = [s for s in self.supports if s.owner is desk][0]
                if self.rng.random() < 0.6:
                    self.on_support(
                        "table lamp", top, local=(desk.size[0] / 2 - 0.2, desk.size[1] / 2 - 0.17)
                    )
        if self.rng.random() < 0.6:
            self.against_wall("bookshelf", room)
        if self.rng.random() < 0.35:
            self.free_standing("armchair", room, near_wall=True)
        for category, p in (
            ("potted plant", 0.6),
            ("backpack", 0.4),
            ("cardboard box", 0.4),
            ("trash can", 0.4),
            ("floor lamp", 0.3),
        ):
            if self.rng.random() < p:
                self.free_standing(category, room, near_wall=True)
        self._decorate_walls(
            room,
            {
                "painting": (1, 2),
                "mirror": (0, 1),
                "clock": (0, 1),
                "wall shelf": (1, 2),
                "air conditioner": (0, 1),
            },
        )
        self.small("teddy bear", room, self._count(0, 1), ("bed",))
        self.small("book", room, self._count(2, 4), ("nightstand", "bed", "dresser", "desk"))
        self.small("cell phone", room, self._count(0, 1), ("nightstand", "bed"))
        self.small("mug", room, self._count(0, 2), ("nightstand", "desk"))
        self.small("candle", room, self._count(1, 2), ("dresser", "nightstand", "wall shelf"))
        self.small(
            "picture frame", room, self._count(1, 3), ("dresser", "nightstand", "wall shelf")
        )
        self.small("vase", room, self._count(0, 1), ("dresser",))
        self.small("laptop", room, self._count(0, 1), ("bed", "desk"))
        self.small("keys", room, 1, ("dresser", "nightstand"))
        self.small("remote control", room, self._count(0, 1), ("nightstand", "bed"))
