"""The placement engine: a `SceneBuilder` that grows a scene from a floor plan.

It draws the floors, walls (with doorway openings) and ceilings, then places objects by
rejection sampling against the axis-aligned boxes of everything placed so far, so objects
never interpenetrate. Furniture goes against walls, beside or in front of other furniture or
free on the floor (yaw a multiple of 90 degrees); small objects stand on the support
rectangles (table tops, shelf levels, counters) their parent declared, 1 mm above them, at
any yaw. The room recipes (`world.rooms`) say what goes where.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
import open3d as o3d

from world.categories import CATEGORIES
from world.furniture import WHITE, build_furniture
from world.meshes import Parts, quad, rot_z
from world.scene import DOOR_HEIGHT_M, WALL_THICKNESS_M, Doorway, Room, SceneObject

# Clear floor kept in front of each doorway so the rooms stay connected for walking.
DOOR_CLEARANCE_M = 1.0
# Resting objects float this far above their support so that contact faces stay separable
# (the ground-truth sampler drops faces that touch another surface).
REST_GAP_M = 0.001


@dataclass
class Placed:
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

    @property
    def along_wall(self) -> float:
        """Its position along the wall it has its back to (x on sides 0 and 2, else y)."""
        return self.x if self.side in (0, 2) else self.y


@dataclass
class Support:
    """A world-space rectangle small objects may stand on."""

    rect: np.ndarray  # x0, y0, x1, y1
    z: float
    clearance: float
    kind: str
    owner: Placed
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


def _side_of_yaw(yaw: float) -> int:
    """The wall side an object placed with `yaw` has its back to."""
    diffs = [abs(math.remainder(yaw - y, 2 * math.pi)) for y in _SIDE_YAW]
    return int(np.argmin(diffs))


class SceneBuilder:
    """Holds the growing scene and the occupancy boxes used for rejection sampling."""

    def __init__(self, rng: np.random.Generator):
        """Draws the wall colour from `rng`; `build_architecture` sets the floor plan."""
        self.rng = rng
        self.rooms: list[Room] = []
        self.doorways: list[Doorway] = []
        self.objects: list[SceneObject] = []
        self.supports: list[Support] = []
        self._boxes = np.zeros((0, 6))
        self._box_owner: list[int] = []
        self._height = 0.0  # ceiling height, from the floor plan
        self._wall_color = np.array(_WALL_COLORS[rng.integers(len(_WALL_COLORS))], float)

    # --- floor plan ----------------------------------------------------------------------

    def _outer(self) -> tuple[float, float, float, float]:
        b = np.array([room.bounds for room in self.rooms])
        return b[:, 0].min(), b[:, 1].min(), b[:, 2].max(), b[:, 3].max()

    def is_interior_side(self, room_index: int, side: int) -> bool:
        """True if the room's wall `side` (see _SIDE_YAW) is shared with another room."""
        x0, y0, x1, y1 = self.rooms[room_index].bounds
        ox0, oy0, ox1, oy1 = self._outer()
        return not math.isclose((y0, x1, y1, x0)[side], (oy0, ox1, oy1, ox0)[side])

    def inner_rect(self, room_index: int) -> tuple[float, float, float, float]:
        """Room bounds minus half a wall on interior sides (exterior walls are thin quads)."""
        x0, y0, x1, y1 = self.rooms[room_index].bounds
        t = WALL_THICKNESS_M / 2
        s = [t if self.is_interior_side(room_index, k) else 0.0 for k in range(4)]
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
        self, category: str, parts: Parts, color, room: int, texture="plain"
    ) -> None:
        v, t, c = parts.arrays()
        self._new_object(category, v, t, c, tuple(int(x) for x in color), room, texture=texture)

    def build_architecture(self, rooms: list[Room], doorways: list[Doorway]) -> None:
        """Take the floor plan and draw the floors, ceilings and walls (with doorway
        openings) of every room; reserve the floor in front of each doorway."""
        self.rooms = rooms
        self.doorways = doorways
        self._height = rooms[0].height
        h = self._height
        for i, room in enumerate(self.rooms):
            x0, y0, x1, y1 = room.bounds
            floor_color = np.array(_FLOOR_COLORS[room.type][self.rng.integers(3)], float)
            p = Parts()
            p.add(
                *quad(np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]], float)),
                floor_color,
            )
            texture = "tiles" if room.type == "kitchen" else "planks"
            if room.type == "office" and floor_color[0] < 140 and floor_color[2] > 120:
                texture = "plain"  # grey office carpet
            self._add_background("floor", p, floor_color, i, texture)
            p = Parts()
            p.add(
                *quad(np.array([[x0, y0, h], [x0, y1, h], [x1, y1, h], [x1, y0, h]], float)),
                WHITE,
            )
            self._add_background("ceiling", p, WHITE, i)
        # Exterior walls: one inward-facing quad per side of the outline.
        ox0, oy0, ox1, oy1 = self._outer()
        corners = [
            ((ox0, oy0), (ox1, oy0)),
            ((ox1, oy0), (ox1, oy1)),
            ((ox1, oy1), (ox0, oy1)),
            ((ox0, oy1), (ox0, oy0)),
        ]
        for (ax, ay), (bx, by) in corners:
            p = Parts()
            p.add(
                *quad(np.array([[bx, by, 0], [ax, ay, 0], [ax, ay, h], [bx, by, h]], float)),
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
            p = Parts()
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

    def place(
        self,
        category: str,
        room: int,
        candidates,
        size: tuple[float, float, float] | None = None,
        color: np.ndarray | None = None,
        gap: float = 0.04,
        support: Support | None = None,
        side: int = -1,
        **style,
    ) -> Placed | None:
        """Build one object and put it at the first collision-free pose of `candidates`.

        candidates: iterable of (x, y, z, yaw) for the object's bottom centre.
        """
        size = size or self.sample_size(category)
        color = self.instance_color(category) if color is None else color
        v, t, c, local_supports = build_furniture(category, size, color, self.rng, **style)
        ix0, iy0, ix1, iy1 = self.inner_rect(room)
        ignore = support.owner.obj.instance_id if support else 0
        for x, y, z, yaw in candidates:
            rot = rot_z(yaw)
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
            placed = Placed(obj, x, y, z, yaw, size, side)
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
                self.supports.append(Support(rect, z + ls.z, ls.clearance, ls.kind, placed, room))
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
    ) -> Placed | None:
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
    ) -> Placed | None:
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
        self, anchor: Placed, category: str, distance: float, turn: bool = False, **kw
    ) -> Placed | None:
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
        anchor: Placed,
        category: str,
        sign: int,
        gap: float = 0.06,
        facing_yaw: float | None = None,
        **kw,
    ) -> Placed | None:
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
    ) -> Placed | None:
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
    ) -> Placed | None:
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

    def on_ceiling(self, category: str, room: int, xy: tuple[float, float]) -> Placed | None:
        size = self.sample_size(category)
        z = self._height - size[2] - 0.002
        return self.place(category, room, [(xy[0], xy[1], z, 0.0)], size=size, gap=0.02)

    def room_supports(
        self, room: int, owners: tuple[str, ...] = (), kinds: tuple[str, ...] = ()
    ) -> list[Support]:
        out = [s for s in self.supports if s.room == room]
        if owners:
            out = [s for s in out if s.owner.obj.category in owners]
        if kinds:
            out = [s for s in out if s.kind in kinds]
        return out

    def on_support(
        self,
        category: str,
        support: Support,
        tries: int = 12,
        local: tuple[float, float] | None = None,
        yaw_jitter_deg: float = 8.0,
        **kw,
    ) -> Placed | None:
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
                for _ in range(self.random_count(2, 5)):
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

    def random_count(self, lo: int, hi: int) -> int:
        """A uniform integer in [lo, hi]."""
        return int(self.rng.integers(lo, hi + 1))
