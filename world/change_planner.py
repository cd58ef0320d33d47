"""Planning a revisit's changes: things moved to another free spot, removed, added where the
first walk saw empty space, and the occlusion traps, picked one by one on a working copy of
the scene (`Planner`), each an `Edit` that `apply_edits` makes on a copy of the scene."""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numpy as np
import open3d as o3d
import open3d.core as o3c

from world.categories import CATEGORIES
from world.change_visibility import (
    HIDDEN_FRACTION,
    MIN_HIDDEN_FRAMES,
    MIN_SEEN_FRAMES,
    PLACE_VISIBLE_FRACTION,
    SeenFrames,
    WalkImages,
    at_or_behind,
    min_seen_px,
)
from world.furniture import build_furniture
from world.meshes import Parts, rot_z
from world.placement import REST_GAP_M
from world.render import Camera
from world.scene import WALL_THICKNESS_M, Scene, SceneObject

MIN_MOVE_M = 0.5
"""Moved things land at least this far from where they were."""

_PATH_CLEARANCE_M = 0.4  # things on the floor stay this far from the walked path
_DOOR_CLEARANCE_M = 1.0
_CHANGE_SPACING_M = 0.25  # from a new place to the places of other changes
_SEEN_MARGIN_FRAMES = 6  # predictions must clear the thresholds by this much
_RAY_START_M = 0.4  # support rays start this far above the support's top
_FLAT_TOLERANCE_M = 0.004

# Chosen in this order of preference; what the walk sees best wins within a category.
_SMALL_MOVES = (
    "keys", "mug", "cell phone", "remote control", "laptop", "book", "bottle", "bowl", "vase",
    "teddy bear", "speaker", "kettle", "candle", "picture frame", "table lamp", "cooking pot",
    "toaster", "coffee maker", "cutting board", "keyboard",
)  # fmt: skip
_LARGE_MOVES = (
    "chair", "backpack", "armchair", "office chair", "bar stool", "ottoman", "trash can",
    "potted plant", "floor lamp", "cardboard box",
)  # fmt: skip
_THIN = ("laptop", "book", "keys", "cell phone", "remote control", "cutting board", "keyboard")
_THIN_MAX_HEIGHT_M = 0.06  # a book lying flat, not standing on a shelf
_TABLES = (
    "coffee table", "dining table", "desk", "nightstand", "dresser", "kitchen counter",
    "tv stand", "cabinet", "filing cabinet",
)  # fmt: skip
_REMOVALS = (
    "laptop", "book", "cell phone", "remote control", "keys", "vase", "bottle", "speaker",
    "teddy bear", "picture frame", "bowl", "candle", "backpack", "ottoman", "potted plant",
    "table lamp", "kettle", "toaster", "mug", "chair",
)  # fmt: skip
_SMALL_ADDITIONS = (
    "laptop", "book", "bottle", "vase", "bowl", "mug", "teddy bear", "speaker", "candle",
    "kettle", "picture frame", "table lamp", "cell phone", "remote control", "toaster",
)  # fmt: skip
_FLOOR_ADDITIONS = ("backpack", "potted plant", "ottoman", "trash can", "floor lamp", "chair")
_COVER_TARGETS = (
    "trash can", "backpack", "mug", "bowl", "vase", "bottle", "kettle", "speaker", "candle",
    "teddy bear", "toaster", "coffee maker",
)  # fmt: skip
_FRONT_TARGETS = (
    "mug", "bowl", "vase", "bottle", "candle", "speaker", "kettle", "toaster", "teddy bear",
    "coffee maker", "cooking pot", "picture frame", "backpack", "trash can", "ottoman",
)  # fmt: skip
_OCCLUDER = "cardboard box"
_SUPPORT_SKIP = ("bookshelf",)  # its top is above eye level
# Surfaces that only take some things (anything goes on the others).
_SURFACE_ONLY = {
    "bed": ("teddy bear", "book", "cell phone", "laptop", "remote control"),
    "stove": ("cooking pot", "kettle"),
}
# How many changes of each sort one revisit scripts (fewer when the walk offers fewer).
_PLAN = {"cover": 1, "front": 1, "thin removal": 1, "removal": 2, "large move": 2,
         "small move": 5, "small addition": 2, "floor addition": 1}  # fmt: skip


@dataclass
class Edit:
    """One planned change: the object before and after it (None where it does not exist)."""

    kind: str
    instance_id: int
    category: str
    old: SceneObject | None
    new: SceneObject | None
    covers: int = 0
    """Instance id of the object this added thing hides (an occlusion trap), else 0."""


def edit_roles(edits: list[Edit]) -> dict[int, str]:
    roles = {e.instance_id: e.kind for e in edits}
    roles.update({e.covers: "occluded" for e in edits if e.covers})
    return roles


def occluders_of(edits: list[Edit]) -> dict[int, int]:
    return {e.covers: e.instance_id for e in edits if e.covers}


def acceptable(edit: Edit, seen: dict[int, SeenFrames]) -> bool:
    s = seen[edit.instance_id]
    ok = True
    if edit.kind in ("moved", "removed"):
        ok &= s.object_walk1 >= MIN_SEEN_FRAMES and s.old_place_walk2 >= MIN_SEEN_FRAMES
    if edit.kind in ("moved", "added"):
        ok &= s.object_walk2 >= MIN_SEEN_FRAMES
    if edit.kind == "added":
        ok &= s.new_place_walk1 >= MIN_SEEN_FRAMES
    if edit.covers:
        hidden = seen[edit.covers]
        ok &= hidden.object_walk1 >= MIN_SEEN_FRAMES and hidden.hidden_walk2 >= MIN_HIDDEN_FRAMES
    return bool(ok)


def apply_edits(before: Scene, edits: list[Edit]) -> Scene:
    """A deep copy of `before` with the edits made."""
    replaced = {e.instance_id: e.new for e in edits if e.kind != "added"}
    objects = []
    for obj in before.objects:
        obj = replaced.get(obj.instance_id, obj)
        if obj is not None:
            objects.append(copy.deepcopy(obj))
    objects += [copy.deepcopy(e.new) for e in edits if e.kind == "added"]
    return Scene(before.name, before.seed, objects, list(before.rooms), list(before.doorways))


def xyz(p: np.ndarray) -> tuple[float, float, float]:
    return (float(p[0]), float(p[1]), float(p[2]))


def _related(a: str, b: str) -> bool:
    """Same category, or one a detector may call by the other's name (or a shared one)."""
    ca, cb = CATEGORIES[a].confusions, CATEGORIES[b].confusions
    return a == b or a in cb or b in ca or bool(set(ca) & set(cb))


def _new_object(
    instance_id: int,
    category: str,
    vertices: np.ndarray,
    triangles: np.ndarray,
    colors: np.ndarray,
    color: tuple[int, int, int],
    room: int,
    support_id: int,
) -> SceneObject:
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(vertices),
        o3d.utility.Vector3iVector(np.asarray(triangles, np.int32)),
    )
    mesh.vertex_colors = o3d.utility.Vector3dVector(np.clip(colors, 0.0, 1.0))
    bbox = np.concatenate([vertices.min(0), vertices.max(0)])
    return SceneObject(
        instance_id=instance_id,
        category=category,
        mesh=mesh,
        color=color,
        center=(bbox[:3] + bbox[3:]) / 2,
        bbox=bbox,
        room=room,
        support_id=support_id,
    )


def _open_box(inner: tuple[float, float, float], color: np.ndarray) -> Parts:
    """A carton upside down: four walls and a top, open at the bottom, in its own frame."""
    w, d, h = inner
    t = 0.008  # cardboard
    p = Parts()
    x0, x1, y0, y1 = -w / 2 - t, w / 2 + t, -d / 2 - t, d / 2 + t
    p.box((x0, y0, 0), (x1, -d / 2, h), color)
    p.box((x0, d / 2, 0), (x1, y1, h), color)
    p.box((x0, -d / 2, 0), (-w / 2, d / 2, h), color)
    p.box((w / 2, -d / 2, 0), (x1, d / 2, h), color)
    p.box((x0, y0, h), (x1, y1, h + t - 0.001), color)
    p.box((x0 + 0.005, -0.025, h + t - 0.001), (x1 - 0.005, 0.025, h + t), (205, 190, 160))
    return p


class Planner:
    """Picks the changes one by one on a working copy of the scene, so that each new place is
    checked against everything already changed."""

    def __init__(
        self,
        before: Scene,
        poses: list[np.ndarray],
        walk1: WalkImages,
        camera: Camera,
        rng: np.random.Generator,
    ):
        self.before = before
        self.poses = np.asarray(poses, np.float64)
        self.walk1 = walk1
        self.camera = camera
        self.rng = rng
        self.min_px = min_seen_px(camera)
        self.seen1 = (walk1.counts >= self.min_px).sum(axis=0)
        self.objects: dict[int, SceneObject] = {
            o.instance_id: o for o in before.objects if not o.is_background
        }
        self.floor_ids = {o.instance_id for o in before.objects if o.category == "floor"}
        self.supporting = {o.support_id for o in before.objects if o.support_id}
        self.next_id = max(o.instance_id for o in before.objects) + 1
        self.edits: list[Edit] = []
        self.taken: set[int] = set()  # changed, hiding or hidden
        self.vanishing: list[str] = []  # categories of things moved away or removed
        self.appearing: list[str] = []  # categories of things moved here or added
        self.places: list[np.ndarray] = []  # old and new centres of changes
        self._box_cache: tuple[np.ndarray, np.ndarray] | None = None
        # Per changed or trapped object, walk 1's views of it: (camera centre, world points of
        # its pixels) per frame that sees it.
        self.protected: list[list[tuple[np.ndarray, np.ndarray]]] = []
        self._raycaster = o3d.t.geometry.RaycastingScene()
        self._geometry_owner: dict[int, int] = {}
        for obj in before.objects:
            gid = self._raycaster.add_triangles(
                o3c.Tensor(np.asarray(obj.mesh.vertices, np.float32)),
                o3c.Tensor(np.asarray(obj.mesh.triangles, np.uint32)),
            )
            self._geometry_owner[int(gid)] = obj.instance_id

    # --- the script ---

    def plan(self) -> list[Edit]:
        for _ in range(_PLAN["cover"]):
            self._cover_trap()
        for _ in range(_PLAN["front"]):
            self._front_trap()
        for _ in range(_PLAN["thin removal"]):
            self._remove(thin=True)
        for _ in range(_PLAN["removal"]):
            self._remove(thin=False)
        for _ in range(_PLAN["large move"]):
            self._move(_LARGE_MOVES, on_floor=True)
        for _ in range(_PLAN["small move"]):
            self._move(_SMALL_MOVES, on_floor=False)
        for _ in range(_PLAN["small addition"]):
            self._add(_SMALL_ADDITIONS, on_floor=False)
        for _ in range(_PLAN["floor addition"]):
            self._add(_FLOOR_ADDITIONS, on_floor=True)
        return self.edits

    def _candidates(
        self, preference: tuple[str, ...], on_floor: bool | None, kind: str | None
    ) -> list[SceneObject]:
        """Unchanged leaf objects of these categories that walk 1 sees well, best first, that
        can take a change of `kind` (None: be hidden by a trap)."""
        out = []
        for obj in self.objects.values():
            if (
                obj.category not in preference
                or obj.instance_id in self.taken
                or obj.instance_id in self.supporting
                or self.seen1[obj.instance_id] < MIN_SEEN_FRAMES + _SEEN_MARGIN_FRAMES
                or (kind is not None and not self._category_free(obj.category, kind))
                or (on_floor is not None and on_floor != (obj.support_id == 0))
            ):
                continue
            out.append(obj)
        used = set(self.vanishing + self.appearing)  # variety first
        out.sort(
            key=lambda o: (
                o.category in used,
                preference.index(o.category),
                -self.seen1[o.instance_id],
            )
        )
        return out

    def _category_free(self, category: str, kind: str) -> bool:
        """Whether a change of `kind` to a thing of `category` leaves every change unambiguous:
        nothing that vanishes (moved from, removed) may pass for something that appears
        (moved to, added) in a related category, or the map could join the two."""
        others = []
        if kind in ("moved", "removed"):
            others += self.appearing
        if kind in ("moved", "added"):
            others += self.vanishing
        return not any(_related(category, c) for c in others)

    def _commit(self, edit: Edit) -> None:
        self.edits.append(edit)
        self.taken.add(edit.instance_id)
        if edit.old is not None:
            self.vanishing.append(edit.category)
        if edit.new is not None:
            self.appearing.append(edit.category)
        for obj in (edit.old, edit.new):
            if obj is not None:
                self.places.append(obj.center)
        if edit.old is not None:
            self._protect(edit.instance_id)
            del self.objects[edit.instance_id]
        if edit.new is not None:
            self.objects[edit.instance_id] = edit.new
        self._box_cache = None

    def _remove(self, thin: bool) -> None:
        for obj in self._candidates(_THIN if thin else _REMOVALS, on_floor=None, kind="removed"):
            if thin and not self._lies_on_a_table(obj):
                continue
            self._commit(Edit("removed", obj.instance_id, obj.category, obj, None))
            return

    def _lies_on_a_table(self, obj: SceneObject) -> bool:
        """A thin thing (a laptop counts: its base is 2 cm, its lid up) on a table-like top."""
        if obj.support_id == 0:
            return False
        thin = obj.category == "laptop" or obj.bbox[5] - obj.bbox[2] <= _THIN_MAX_HEIGHT_M
        return thin and self.before.object_by_id(obj.support_id).category in _TABLES

    def _move(self, preference: tuple[str, ...], on_floor: bool) -> None:
        for obj in self._candidates(preference, on_floor=on_floor, kind="moved"):
            vertices = np.asarray(obj.mesh.vertices, np.float64)
            local = vertices - [obj.center[0], obj.center[1], obj.bbox[2]]
            if on_floor:
                turn = float(self.rng.choice([0.0, 0.5, 1.0, -0.5])) * math.pi
                turn += float(self.rng.uniform(-0.3, 0.3))
            else:
                turn = float(self.rng.uniform(-math.pi, math.pi))
            local = local @ rot_z(turn).T
            placed = self._find_place(local, obj.category, obj.room, on_floor, away_from=obj.center)
            if placed is None:
                continue
            world, room, support_id = placed
            new = copy.deepcopy(obj)
            new.mesh.vertices = o3d.utility.Vector3dVector(world)
            new.bbox = np.concatenate([world.min(0), world.max(0)])
            new.center = (new.bbox[:3] + new.bbox[3:]) / 2
            new.room, new.support_id = room, support_id
            self._commit(Edit("moved", obj.instance_id, obj.category, obj, new))
            return

    def _add(self, preference: tuple[str, ...], on_floor: bool) -> None:
        rooms = self._rooms_by_fewest_changes()
        for room in rooms:
            room_type = self.before.rooms[room].type
            options = [
                c
                for c in preference
                if room_type in CATEGORIES[c].rooms
                and c not in self.appearing
                and self._category_free(c, "added")
            ]
            for category in options[:4]:
                vertices, triangles, colors, color = self._build(category)
                placed = self._find_place(vertices, category, room, on_floor, elsewhere=False)
                if placed is None:
                    continue
                world, room_index, support_id = placed
                new = _new_object(
                    self.next_id, category, world, triangles, colors, color, room_index, support_id
                )
                self.next_id += 1
                self._commit(Edit("added", new.instance_id, category, None, new))
                return

    def _rooms_by_fewest_changes(self) -> list[int]:
        counts = [0] * len(self.before.rooms)
        for e in self.edits:
            obj = e.new if e.new is not None else e.old
            if obj is not None and 0 <= obj.room < len(counts):
                counts[obj.room] += 1
        return sorted(range(len(counts)), key=lambda r: (counts[r], r))

    def _build(
        self,
        category: str,
        yaw: float | None = None,
        size: tuple[float, float, float] | None = None,
    ):
        """(vertices [N, 3] about the footprint centre, triangles, colours, base colour) of a
        new object of `category`, turned by `yaw` (random when None), of `size` (w, d, h;
        drawn from the category's sizes when None)."""
        cat = CATEGORIES[category]
        if size is None:
            size = tuple(float(self.rng.uniform(lo, hi)) for lo, hi in cat.size_m)
        base = np.array(cat.colors[int(self.rng.integers(len(cat.colors)))], float)
        color = np.clip(base * self.rng.uniform(0.88, 1.12) + self.rng.uniform(-8, 8, 3), 0, 255)
        v, t, c, _supports = build_furniture(category, size, color, self.rng)
        if yaw is None:
            yaw = float(self.rng.uniform(-math.pi, math.pi))
        return v @ rot_z(yaw).T, t, c, tuple(int(x) for x in color)

    # --- occlusion traps ---

    def _cover_trap(self) -> None:
        """A carton put upside down over an object: it stays, hidden entirely."""
        for target in self._candidates(_COVER_TARGETS, on_floor=None, kind=None):
            lo, hi = target.bbox[:3], target.bbox[3:]
            inner = (hi[0] - lo[0] + 0.04, hi[1] - lo[1] + 0.04, hi[2] - lo[2] + 0.03)
            if max(inner[:2]) > 0.55 or inner[2] > 0.7:
                continue  # no carton that big
            color = np.array(CATEGORIES[_OCCLUDER].colors[0], float)
            color = np.clip(color * self.rng.uniform(0.9, 1.1), 0, 255)
            v, t, c = _open_box(inner, color).arrays()
            world = self._fits(
                v + [target.center[0], target.center[1], 0.0],
                target.support_id,
                covers=target.instance_id,
            )
            if world is None or self._hides_changes(world.min(0), world.max(0)):
                continue
            box = _new_object(
                self.next_id,
                _OCCLUDER,
                world,
                t,
                c,
                tuple(int(x) for x in color),
                target.room,
                target.support_id,
            )
            self.next_id += 1
            self._commit_trap(target, box)
            return

    def _front_trap(self) -> None:
        """A carton set between an object and where walk 1 looked at it from."""
        for target in self._candidates(_FRONT_TARGETS, on_floor=None, kind=None):
            frames = np.flatnonzero(self.walk1.counts[:, target.instance_id] >= self.min_px)
            points = [self._backproject(f, target.instance_id) for f in frames]
            toward = self.poses[frames, :2, 3] - target.center[:2]
            toward /= np.maximum(np.linalg.norm(toward, axis=1, keepdims=True), 1e-9)
            ahead = toward.mean(axis=0)
            if np.linalg.norm(ahead) < 0.3:
                continue  # seen from all sides: no single front
            ahead /= np.linalg.norm(ahead)
            side = np.array([-ahead[1], ahead[0]])
            target_radius = 0.5 * (target.bbox[3:5] - target.bbox[:2]).max()
            target_height = target.bbox[5] - target.bbox[2]
            drawn = np.array([self.rng.uniform(lo, hi) for lo, hi in CATEGORIES[_OCCLUDER].size_m])
            best, best_hidden = None, MIN_HIDDEN_FRAMES + _SEEN_MARGIN_FRAMES - 1
            for scale in (1.0, 0.75, 0.55):  # smaller cartons fit on smaller tables
                w, d = max(drawn[0] * scale, 0.18), max(drawn[1] * scale, 0.15)
                h = min(max(drawn[2] * scale, 1.3 * target_height + 0.05), 0.45)
                # Its width across the line of sight.
                vertices, triangles, colors, color = self._build(
                    _OCCLUDER, math.atan2(ahead[0], -ahead[1]), (w, d, h)
                )
                for gap in (0.03, 0.1, 0.2, 0.3):
                    for lateral in (0.0, -0.08, 0.08):
                        xy = target.center[:2] + ahead * (target_radius + d / 2 + gap)
                        xy = xy + side * lateral
                        world = self._fits(vertices + [xy[0], xy[1], 0.0], target.support_id)
                        if world is None:
                            continue
                        lo, hi = world.min(0), world.max(0)
                        if self._hides_changes(lo, hi):
                            continue
                        hidden = sum(
                            self._hidden_fraction(self.poses[f, :3, 3], p, lo, hi)
                            >= HIDDEN_FRACTION
                            for f, p in zip(frames, points, strict=True)
                        )
                        if hidden > best_hidden:
                            best, best_hidden = (world, triangles, colors, color), hidden
                if best is not None:
                    break
            if best is None:
                continue
            world, triangles, colors, color = best
            room, support_id = target.room, target.support_id
            box = _new_object(
                self.next_id, _OCCLUDER, world, triangles, colors, color, room, support_id
            )
            self.next_id += 1
            self._commit_trap(target, box)
            return

    def _commit_trap(self, target: SceneObject, box: SceneObject) -> None:
        self.taken.add(target.instance_id)
        self.places.append(target.center)
        self.vanishing.append(target.category)  # hidden, it could pass for gone
        self._protect(target.instance_id)
        self._commit(Edit("added", box.instance_id, _OCCLUDER, None, box, target.instance_id))

    def _protect(self, instance_id: int) -> None:
        """Keep later changes from blocking walk 2's view of this object's place."""
        frames = np.flatnonzero(self.walk1.counts[:, instance_id] >= self.min_px)
        views = [(self.poses[f, :3, 3], self._backproject(f, instance_id)) for f in frames]
        self.protected.append(views)

    def _hides_changes(self, lo: np.ndarray, hi: np.ndarray) -> bool:
        """Whether a new thing with bounds [lo, hi] would hide the place of a change (or a
        trapped object) from so many frames of walk 2 that too few still see it."""
        for views in self.protected:
            blocked = sum(
                self._hidden_fraction(origin, points, lo, hi) > 1 - PLACE_VISIBLE_FRACTION
                for origin, points in views
            )
            if blocked and len(views) - blocked < MIN_SEEN_FRAMES + _SEEN_MARGIN_FRAMES:
                return True
        return False

    def _backproject(self, frame: int, instance_id: int) -> np.ndarray:
        """World points [K, 3] of the pixels walk 1 saw `instance_id` at in `frame`."""
        v, u = np.nonzero(self.walk1.ids[frame] == instance_id)
        z = self.walk1.depth[frame][v, u].astype(np.float64)
        fx, fy, cx, cy = self.camera.intrinsics
        cam = np.stack([(u - cx) / fx * z, (v - cy) / fy * z, z], axis=1)
        pose = self.poses[frame]
        return cam @ pose[:3, :3].T + pose[:3, 3]

    @staticmethod
    def _hidden_fraction(
        origin: np.ndarray, points: np.ndarray, lo: np.ndarray, hi: np.ndarray
    ) -> float:
        """Fraction of the segments origin -> point that pass through the box [lo, hi]."""
        if len(points) == 0:
            return 0.0
        d = points - origin
        with np.errstate(divide="ignore", invalid="ignore"):
            t0 = (lo - origin) / d
            t1 = (hi - origin) / d
        t_near = np.nanmax(np.minimum(t0, t1), axis=1)
        t_far = np.nanmin(np.maximum(t0, t1), axis=1)
        return float(np.mean((t_near <= t_far) & (t_far > 0) & (t_near < 0.98)))

    # --- places ---

    def _find_place(
        self,
        local: np.ndarray,
        category: str,
        room: int,
        on_floor: bool,
        away_from: np.ndarray | None = None,
        elsewhere: bool = True,
    ) -> tuple[np.ndarray, int, int] | None:
        """(world vertices, room, support id) of a free, well-seen spot for an object given by
        its vertices [N, 3] about its footprint centre (bottom at z = 0), or None. Tried in
        `room` first, then (`elsewhere`) in the other rooms its category belongs in."""
        others = [
            r
            for r, spec in enumerate(self.before.rooms)
            if elsewhere and r != room and spec.type in CATEGORIES[category].rooms
        ]
        lo, hi = local.min(0), local.max(0)
        for r, tries in [(room, 200)] + [(r, 80) for r in others]:
            if on_floor:
                x0, y0, x1, y1 = self.before.rooms[r].bounds
                areas = [(0, np.array([x0, y0]) - lo[:2], np.array([x1, y1]) - hi[:2])]
            else:  # footprint centres that keep it within the support's top
                areas = [
                    (o.instance_id, o.bbox[:2] - lo[:2], o.bbox[3:5] - hi[:2])
                    for o in self._supports(r, category)
                ]
                areas = [a for a in areas if (a[1] < a[2]).all()]
            if not areas:
                continue
            for _ in range(tries):
                support_id, low, high = areas[int(self.rng.integers(len(areas)))]
                xy = self.rng.uniform(low, high)
                world = local + [xy[0], xy[1], 0.0]
                surface = self._surface_under(world, support_id, r)
                if surface is None:
                    continue
                world[:, 2] += surface + REST_GAP_M - world[:, 2].min()
                center = (world.min(0) + world.max(0)) / 2
                if away_from is not None and np.linalg.norm(center - away_from) < MIN_MOVE_M:
                    continue
                if not (self._free(world, support_id) and self._spaced(center, category)):
                    continue
                if self._predicted_frames(world) < MIN_SEEN_FRAMES + _SEEN_MARGIN_FRAMES:
                    continue
                if self._hides_changes(world.min(0), world.max(0)):
                    continue
                return world, r, support_id
        return None

    def _supports(self, room: int, category: str) -> list[SceneObject]:
        """The surfaces of `room` a thing of `category` may be put on."""
        return [
            o
            for o in self.objects.values()
            if o.room == room
            and CATEGORIES[o.category].is_surface
            and o.category not in _SUPPORT_SKIP
            and category in _SURFACE_ONLY.get(o.category, (category,))
            and o.instance_id not in self.taken
            and self.seen1[o.instance_id] >= MIN_SEEN_FRAMES  # else its top is not seen either
        ]

    def _surface_under(
        self, world: np.ndarray, support_id: int, room: int, covers: int = 0
    ) -> float | None:
        """Height of the flat surface of `support_id` (0: the floor of `room`) under the
        footprint of `world`, or None if the footprint is not all on it, flat and clear.
        With `covers`, only the footprint's rim must be (it stands over that object)."""
        lo, hi = world.min(0), world.max(0)
        x0, y0, x1, y1 = self.before.rooms[room].bounds
        inset = WALL_THICKNESS_M / 2 + 0.02
        if lo[0] < x0 + inset or lo[1] < y0 + inset or hi[0] > x1 - inset or hi[1] > y1 - inset:
            return None
        grid = np.linspace(0.0, 1.0, 4)
        if covers:  # the rim: corners and edge points, 5 mm inside
            lo_in, hi_in = lo[:2] + 0.005, hi[:2] - 0.005
            edge = [(a, b) for a in grid for b in grid if a in (0.0, 1.0) or b in (0.0, 1.0)]
            xy = np.array([lo_in + (hi_in - lo_in) * [a, b] for a, b in edge])
        else:
            xy = np.array([lo[:2] + (hi[:2] - lo[:2]) * [a, b] for a in grid for b in grid])
        if support_id:
            start = self.objects[support_id].bbox[5] + _RAY_START_M
        else:
            start = min(hi[2] - lo[2] + 0.3, 2.2)
        rays = np.zeros((len(xy), 6), np.float32)
        rays[:, :2], rays[:, 2], rays[:, 5] = xy, start, -1.0
        hits = self._raycaster.cast_rays(o3c.Tensor(rays))
        t_hit = hits["t_hit"].numpy()
        if not np.isfinite(t_hit).all():
            return None
        owners = {self._geometry_owner.get(int(g), -1) for g in hits["geometry_ids"].numpy()}
        if owners - ({support_id} if support_id else self.floor_ids):
            return None
        heights = start - t_hit
        if np.ptp(heights) > _FLAT_TOLERANCE_M:
            return None
        return float(heights.max())

    def _free(self, world: np.ndarray, support_id: int, ignore: int = 0) -> bool:
        """No overlap with anything but its support (and `ignore`); on the floor, also off the
        walked path and clear of the doorways."""
        lo, hi = world.min(0), world.max(0)
        ids, boxes = self._boxes()
        gap = 0.01 if support_id else 0.04
        hit = (
            (lo[0] < boxes[:, 3] + gap)
            & (hi[0] > boxes[:, 0] - gap)
            & (lo[1] < boxes[:, 4] + gap)
            & (hi[1] > boxes[:, 1] - gap)
            & (lo[2] < boxes[:, 5])
            & (hi[2] > boxes[:, 2])
            & (ids != support_id)
            & (ids != ignore)
        )
        if hit.any():
            return False
        if support_id == 0:
            if _distance_to_rect(self.poses[:, :2, 3], lo, hi).min() < _PATH_CLEARANCE_M:
                return False
            doors = np.array([d.center for d in self.before.doorways]).reshape(-1, 2)
            if len(doors) and _distance_to_rect(doors, lo, hi).min() < _DOOR_CLEARANCE_M:
                return False
        return True

    def _boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """(instance ids [M], bounding boxes [M, 6]) of the working scene's objects."""
        if self._box_cache is None:
            ids = np.array(list(self.objects), np.int64)
            boxes = np.array([o.bbox for o in self.objects.values()]).reshape(-1, 6)
            self._box_cache = (ids, boxes)
        return self._box_cache

    def _fits(self, local: np.ndarray, support_id: int, covers: int = 0) -> np.ndarray | None:
        """An occluder's vertices set down on its support (0: the floor) where they are, or
        None where it would not stand free; with `covers` it stands over that object."""
        lo, hi = local.min(0), local.max(0)
        room = self.before.room_index_at(*((lo[:2] + hi[:2]) / 2))
        if room < 0:
            return None
        surface = self._surface_under(local, support_id, room, covers)
        if surface is None:
            return None
        world = local + [0.0, 0.0, surface + REST_GAP_M - lo[2]]
        return world if self._free(world, support_id, ignore=covers) else None

    def _spaced(self, center: np.ndarray, category: str) -> bool:
        """Away from the places of other changes and from things a detector may confuse."""
        if any(np.linalg.norm(center - p) < _CHANGE_SPACING_M for p in self.places):
            return False
        return not any(
            _related(category, o.category) and np.linalg.norm(center - o.center) < MIN_MOVE_M
            for o in self.objects.values()
        )

    def _predicted_frames(self, world: np.ndarray) -> int:
        """Frames of walk 1 whose depth shows this spot empty, in view and big enough."""
        step = max(1, len(world) // 48)
        points = np.vstack([world[::step], (world.min(0) + world.max(0)) / 2])
        rotation, origin = self.poses[:, :3, :3], self.poses[:, :3, 3]
        cam = (points[None] - origin[:, None]) @ rotation  # R^T (p - t), row vectors
        z = cam[..., 2]
        fx, fy, cx, cy = self.camera.intrinsics
        w, h = self.camera.width, self.camera.height
        ahead = (z > 0.3) & (z < 4.0)
        z_safe = np.where(ahead, z, 1.0)
        u = fx * cam[..., 0] / z_safe + cx
        v = fy * cam[..., 1] / z_safe + cy
        inside = ahead & (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
        ui = np.clip(np.round(u), 0, w - 1).astype(np.int64)
        vi = np.clip(np.round(v), 0, h - 1).astype(np.int64)
        frame = np.broadcast_to(np.arange(len(self.poses))[:, None], z.shape)
        visible = inside & at_or_behind(self.walk1.depth[frame, vi, ui], z)
        n_inside = inside.sum(axis=1)
        # The projected box of the points, half filled: a rough area in pixels.
        big = np.float64(1e9)
        u_span = np.where(inside, u, -big).max(1) - np.where(inside, u, big).min(1)
        v_span = np.where(inside, v, -big).max(1) - np.where(inside, v, big).min(1)
        area = 0.5 * np.maximum(u_span, 0) * np.maximum(v_span, 0)
        ok = (
            (n_inside >= 0.9 * len(points))
            & (visible.sum(axis=1) >= 0.8 * np.maximum(n_inside, 1))
            & (area >= self.min_px)
        )
        return int(ok.sum())


def _distance_to_rect(xy: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Distances [N] of points [N, 2] to the rectangle [lo, hi] (x, y) (0 inside)."""
    dx = np.maximum(np.maximum(lo[0] - xy[:, 0], xy[:, 0] - hi[0]), 0.0)
    dy = np.maximum(np.maximum(lo[1] - xy[:, 1], xy[:, 1] - hi[1]), 0.0)
    return np.hypot(dx, dy)
