"""The scene model: rooms, doorways and objects of a procedural indoor scene.

The world is Z-up, metres, floor at z = 0. A scene is a list of `SceneObject`s (furniture,
wall items, small objects and the floor, wall and ceiling surfaces), each one triangle mesh
in world coordinates. `world.rooms.make_scene` builds one of `SCENE_NAMES`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import open3d as o3d

from world.categories import BACKGROUND_CLASSES

SCENE_NAMES: tuple[str, ...] = ("living_room", "kitchen", "office", "bedroom", "apartment")
"""The scenes `make_scene` can build: one room of each type, or the four-room apartment."""

WALL_THICKNESS_M = 0.1
"""Interior walls are boxes this thick centred on the room bounds; exterior walls are quads."""
DOOR_WIDTH_M = 1.2
DOOR_HEIGHT_M = 2.1


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
