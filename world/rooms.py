"""Room recipes: the floor plan of each named scene and what goes where in each room type.

`make_scene` lays out the rooms (sizes, doorways), has the placement engine draw the walls,
then furnishes each room: big furniture first (a sofa against a wall, a coffee table in front
of it, a tv stand opposite), then wall items, then small objects on the surfaces the
furniture offers. Every draw comes from one generator seeded by (seed, scene name), so a
scene is deterministic for (name, seed).
"""

from __future__ import annotations

import math

import numpy as np

from world.placement import Placed, SceneBuilder
from world.scene import (
    DOOR_HEIGHT_M,
    DOOR_WIDTH_M,
    SCENE_NAMES,
    Doorway,
    Room,
    Scene,
)

_COUNTER_TOPS = ((200, 196, 188), (60, 60, 64), (220, 216, 206), (150, 120, 90))
_DUVETS = ((200, 186, 160), (45, 60, 95), (120, 120, 126), (150, 70, 60), (230, 230, 225))


def make_scene(name: str = "apartment", seed: int = 0) -> Scene:
    """Build the scene `name` (one of SCENE_NAMES); deterministic for (name, seed).

    Single-room scenes hold ~30-60 objects, the apartment (living room, kitchen, bedroom and
    office joined by doorways) ~120-200, plus floor, wall and ceiling surfaces.
    """
    if name not in SCENE_NAMES:
        raise ValueError(f"unknown scene {name!r}; valid names: {', '.join(SCENE_NAMES)}")
    rng = np.random.default_rng([int(seed), SCENE_NAMES.index(name)])
    builder = SceneBuilder(rng)
    if name == "apartment":
        rooms, doorways = _apartment_plan(rng)
    else:
        rooms, doorways = _single_room_plan(name, rng)
    builder.build_architecture(rooms, doorways)
    for index in range(len(builder.rooms)):
        _furnish(builder, index)
    return Scene(
        name=name,
        seed=int(seed),
        objects=builder.objects,
        rooms=builder.rooms,
        doorways=builder.doorways,
    )


# --- floor plans ------------------------------------------------------------------------


def _single_room_plan(room_type: str, rng: np.random.Generator) -> tuple[list[Room], list[Doorway]]:
    size = {
        "living_room": ((5.2, 6.4), (4.2, 5.0)),
        "kitchen": ((3.8, 4.6), (3.6, 4.4)),
        "office": ((4.0, 5.0), (3.6, 4.4)),
        "bedroom": ((4.0, 4.8), (3.8, 4.4)),
    }[room_type]
    w, d = (round(rng.uniform(*r), 2) for r in size)
    height = round(rng.uniform(2.6, 2.8), 2)
    return [Room(room_type, (0.0, 0.0, w, d), height)], []


def _apartment_plan(r: np.random.Generator) -> tuple[list[Room], list[Doorway]]:
    """Living room and kitchen side by side, bedroom and office behind, three doorways."""
    w1, d1 = round(r.uniform(5.4, 6.2), 2), round(r.uniform(4.4, 5.0), 2)
    w2, d2 = round(r.uniform(3.6, 4.2), 2), round(r.uniform(3.8, 4.4), 2)
    w3 = round(r.uniform(4.0, 4.6), 2)
    wt, dt = w1 + w2, d1 + d2
    h = round(r.uniform(2.6, 2.8), 2)
    rooms = [
        Room("living_room", (0.0, 0.0, w1, d1), h),
        Room("kitchen", (w1, 0.0, wt, d1), h),
        Room("bedroom", (0.0, d1, w3, dt), h),
        Room("office", (w3, d1, wt, dt), h),
    ]
    half = DOOR_WIDTH_M / 2 + 0.3
    doorways = [
        Doorway((0, 1), (w1, round(r.uniform(half, d1 - half), 2)), DOOR_WIDTH_M, DOOR_HEIGHT_M, 0),
        Doorway((0, 2), (round(r.uniform(half, w3 - half), 2), d1), DOOR_WIDTH_M, DOOR_HEIGHT_M, 1),
        Doorway(
            (1, 3),
            (round(r.uniform(w1 + half, wt - half), 2), d1),
            DOOR_WIDTH_M,
            DOOR_HEIGHT_M,
            1,
        ),
    ]
    return rooms, doorways


# --- furnishing -------------------------------------------------------------------------


def _furnish(builder: SceneBuilder, room: int) -> None:
    """Windows, the recipe of the room's type, ceiling lights (or a fan), books on shelves."""
    rtype = builder.rooms[room].type
    _windows(builder, room)
    _RECIPES[rtype](builder, room)
    _ceiling(builder, room, fan=rtype in ("living_room", "bedroom") and builder.rng.random() < 0.35)
    builder.fill_shelves(room)


def _windows(builder: SceneBuilder, room: int) -> None:
    sides = tuple(s for s in range(4) if not builder.is_interior_side(room, s))
    for _ in range(builder.random_count(1, 2) if sides else 0):
        # Sills above worktop height so counters and sofas can stand below windows.
        builder.on_wall("window", room, (1.0, 1.1), sides=sides)


def _ceiling(builder: SceneBuilder, room: int, fan: bool) -> None:
    """A fan or a light in the middle; large rooms get a second light along the long axis."""
    x0, y0, x1, y1 = builder.inner_rect(room)
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    if fan or builder.rooms[room].area_m2 > 20:
        dx, dy = ((x1 - x0) / 4, 0.0) if x1 - x0 > y1 - y0 else (0.0, (y1 - y0) / 4)
        if fan:
            builder.on_ceiling("ceiling fan", room, (cx, cy))
            builder.on_ceiling("ceiling light", room, (cx + 1.4 * dx, cy + 1.4 * dy))
        else:
            builder.on_ceiling("ceiling light", room, (cx - dx, cy - dy))
            builder.on_ceiling("ceiling light", room, (cx + dx, cy + dy))
    else:
        builder.on_ceiling("ceiling light", room, (cx, cy))


def _decorate_walls(builder: SceneBuilder, room: int, items: dict[str, tuple[int, int]]) -> None:
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
        for _ in range(builder.random_count(lo, hi)):
            builder.on_wall(category, room, heights[category])


def _furnish_living_room(builder: SceneBuilder, room: int) -> None:
    sofa = builder.against_wall("sofa", room)
    table = None
    if sofa is not None:
        table = builder.in_front_of(sofa, "coffee table", float(builder.rng.uniform(0.35, 0.5)))
        if builder.rng.random() < 0.6:
            builder.on_wall("painting", room, (1.15, 1.35), side=sofa.side, along=sofa.along_wall)
        sign = int(builder.rng.choice([-1, 1]))
        if builder.rng.random() < 0.7:
            builder.beside(sofa, "floor lamp", sign)
        if builder.rng.random() < 0.5:
            builder.beside(sofa, "potted plant", -sign)
    if table is not None:
        for sign in (-1, 1):
            if builder.rng.random() < 0.55:
                size = builder.sample_size("armchair")
                xy = np.array([table.x, table.y]) + table.right * sign * (
                    table.size[0] / 2 + 0.35 + size[1] / 2
                )
                builder.facing("armchair", room, xy, np.array([table.x, table.y]), size=size)
    opposite = (sofa.side + 2) % 4 if sofa is not None else None
    stand = builder.against_wall("tv stand", room, side=opposite) or builder.against_wall(
        "tv stand", room
    )
    if stand is not None:
        tv = builder.on_wall(
            "tv",
            room,
            (stand.size[2] + 0.25, stand.size[2] + 0.45),
            side=stand.side,
            along=stand.along_wall,
            tries=6,
        )
        if tv is None:  # wall taken (a window): the tv stands on its foot on the stand
            top = [s for s in builder.supports if s.owner is stand][0]
            size = builder.sample_size("tv")
            builder.on_support(
                "tv",
                top,
                local=(0.0, 0.0),
                size=(min(size[0], stand.size[0] - 0.1), 0.25, size[2] + 0.1),
                standing=True,
            )
        for sign in (-1, 1):
            if builder.rng.random() < 0.5:
                shelf = builder.room_supports(room, ("tv stand",))
                if shelf:
                    builder.on_support(
                        "speaker", shelf[0], local=(sign * (stand.size[0] / 2 - 0.15), 0.0)
                    )
    for _ in range(builder.random_count(1, 2)):
        builder.against_wall("bookshelf", room)
    if builder.rng.random() < 0.5:
        builder.against_wall("cabinet", room)
    for _ in range(builder.random_count(1, 2)):
        builder.free_standing("potted plant", room, near_wall=True)
    if builder.rng.random() < 0.4:
        builder.free_standing("ottoman", room)
    _decorate_walls(
        builder,
        room,
        {
            "painting": (1, 2),
            "clock": (0, 1),
            "mirror": (0, 1),
            "wall shelf": (1, 2),
            "air conditioner": (0, 1),
        },
    )
    builder.small("remote control", room, builder.random_count(1, 2), ("coffee table", "tv stand"))
    builder.small("mug", room, builder.random_count(1, 3), ("coffee table", "dining table"))
    builder.small("keys", room, 1, ("coffee table", "cabinet", "tv stand"))
    builder.small("vase", room, builder.random_count(1, 2), ("cabinet", "tv stand", "coffee table"))
    builder.small(
        "candle", room, builder.random_count(0, 2), ("coffee table", "cabinet", "wall shelf")
    )
    builder.small(
        "picture frame", room, builder.random_count(1, 2), ("cabinet", "tv stand", "wall shelf")
    )
    builder.small("bowl", room, builder.random_count(0, 1), ("coffee table",))
    builder.small("book", room, builder.random_count(1, 2), ("coffee table",))
    builder.small("cell phone", room, builder.random_count(0, 1), ("coffee table",))
    builder.small("laptop", room, builder.random_count(0, 1), ("coffee table",))
    builder.small("bottle", room, builder.random_count(0, 1), ("coffee table", "cabinet"))
    builder.small("table lamp", room, builder.random_count(0, 1), ("cabinet",))


def _furnish_kitchen(builder: SceneBuilder, room: int) -> None:
    top_color = np.array(_COUNTER_TOPS[builder.rng.integers(len(_COUNTER_TOPS))], float)
    front_color = builder.instance_color("kitchen counter")
    spans = [(s, np.subtract(*builder.wall_span(room, s)[::-1])) for s in range(4)]
    spans.sort(key=lambda sl: -sl[1] + builder.rng.uniform(0, 0.8))
    # Two runs on the two longest walls: fridge + sink + dishwasher, then stove between counters.
    runs = [
        ["refrigerator", "kitchen counter", "sink", "dishwasher"],
        ["kitchen counter", "stove", "kitchen counter"],
    ]
    if builder.rng.random() < 0.5:
        runs[0] = runs[0][::-1]
    placed_run: list[Placed] = []
    for run, (side, _length) in zip(runs, spans[:2], strict=True):
        placed_run += _counter_run(builder, room, side, run, top_color, front_color)
    present = {p.obj.category for p in placed_run}
    missing = [c for c in ("sink", "stove", "refrigerator") if c not in present]
    for side, _length in spans[2:]:
        if missing:
            got = _counter_run(builder, room, side, missing, top_color, front_color)
            placed_run += got
            missing = [c for c in missing if c not in {p.obj.category for p in got}]
    for item in placed_run:
        if item.obj.category in ("kitchen counter", "sink"):
            w = min(item.size[0], 1.2)
            size = (w, *builder.sample_size("wall cabinet")[1:])
            builder.on_wall(
                "wall cabinet",
                room,
                (1.45, 1.5),
                side=item.side,
                along=item.along_wall,
                size=size,
                color=front_color,
                tries=1,
                gap=0.001,
            )
    # Chairs plus a walkway around the table need ~1.3 m; small kitchens push it to a wall.
    size = builder.sample_size("dining table")
    table = builder.free_standing("dining table", room, margin=1.35, size=size)
    if table is None:
        size = (min(size[0], 1.4), *size[1:])
        table = builder.against_wall("dining table", room, size=size, wall_gap=0.05)
    if table is not None:
        _chairs_around(builder, table, room)
    for _ in range(builder.random_count(0, 2)):
        builder.free_standing("bar stool", room, near_wall=True)
    builder.free_standing("trash can", room, near_wall=True)
    if builder.rng.random() < 0.5:
        builder.free_standing("potted plant", room, near_wall=True)
    _decorate_walls(builder, room, {"clock": (0, 1), "painting": (0, 1)})
    counters = ("kitchen counter",)
    builder.small("microwave", room, 1, counters)
    builder.small("kettle", room, 1, counters + ("stove",))
    builder.small("cooking pot", room, builder.random_count(1, 2), ("stove",))
    builder.small("toaster", room, builder.random_count(0, 1), counters)
    builder.small("coffee maker", room, builder.random_count(0, 1), counters)
    builder.small("cutting board", room, 1, counters)
    builder.small("bowl", room, builder.random_count(1, 3), counters + ("dining table",))
    builder.small("mug", room, builder.random_count(2, 4), counters + ("dining table",))
    builder.small("bottle", room, builder.random_count(1, 3), counters + ("dining table",))
    builder.small("vase", room, builder.random_count(0, 1), ("dining table",))
    builder.small("keys", room, builder.random_count(0, 1), counters + ("dining table",))
    builder.small("cell phone", room, builder.random_count(0, 1), ("dining table",))
    builder.small("candle", room, builder.random_count(0, 1), ("dining table",))
    builder.small("book", room, builder.random_count(0, 1), counters)


def _counter_run(builder: SceneBuilder, room, side, items, top_color, front_color) -> list[Placed]:
    """Appliances and counters side by side along one wall, starting at a corner."""
    a0, a1 = builder.wall_span(room, side)
    cursor = a0 + 0.005
    placed = []
    for category in items:
        size = builder.sample_size(category)
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
            p = builder.against_wall(
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


def _chairs_around(builder: SceneBuilder, table: Placed, room: int) -> None:
    long_x = abs(math.sin(table.yaw)) < 0.5  # table width runs along world x
    w, d = table.size[0], table.size[1]
    per_side = max(1, int(w // 0.6))
    centre = np.array([table.x, table.y])
    axis_w = np.array([1.0, 0.0]) if long_x else np.array([0.0, 1.0])
    axis_d = np.array([0.0, 1.0]) if long_x else np.array([1.0, 0.0])
    for sign in (-1, 1):
        for k in range(per_side):
            if builder.rng.random() < 0.15:
                continue
            size = builder.sample_size("chair")
            off = (k - (per_side - 1) / 2) * (w / per_side)
            xy = centre + axis_w * off + axis_d * sign * (d / 2 + 0.12 + size[1] / 2)
            builder.facing("chair", room, xy, centre, size=size, gap=0.02)
    for sign in (-1, 1):
        if builder.rng.random() < 0.4:
            size = builder.sample_size("chair")
            xy = centre + axis_w * sign * (w / 2 + 0.12 + size[1] / 2)
            builder.facing("chair", room, xy, centre, size=size, gap=0.02)


def _furnish_office(builder: SceneBuilder, room: int) -> None:
    desks = []
    for _ in range(builder.random_count(1, 2)):
        desk = builder.against_wall("desk", room)
        if desk is None:
            continue
        desks.append(desk)
        builder.in_front_of(desk, "office chair", 0.05, turn=True)
        top = [s for s in builder.supports if s.owner is desk][0]
        u = float(builder.rng.uniform(-0.2, 0.1))  # left of the drawer pedestal
        builder.on_support("monitor", top, local=(u, desk.size[1] / 2 - 0.14))
        builder.on_support("keyboard", top, local=(u, -desk.size[1] / 2 + 0.12))
        if builder.rng.random() < 0.5:
            builder.on_support("laptop", top)
        if builder.rng.random() < 0.5:
            builder.on_support(
                "table lamp", top, local=(desk.size[0] / 2 - 0.2, desk.size[1] / 2 - 0.17)
            )
        if builder.rng.random() < 0.7:
            builder.beside(desk, "trash can", int(builder.rng.choice([-1, 1])))
    for _ in range(builder.random_count(1, 2)):
        builder.against_wall("bookshelf", room)
    for _ in range(builder.random_count(1, 2)):
        builder.against_wall("filing cabinet", room)
    if builder.rng.random() < 0.5:
        builder.against_wall("cabinet", room)
    if builder.rng.random() < 0.4:
        builder.free_standing("armchair", room, near_wall=True)
    for _ in range(builder.random_count(0, 2)):
        builder.free_standing("potted plant", room, near_wall=True)
    for _ in range(builder.random_count(0, 2)):
        builder.free_standing("cardboard box", room, near_wall=True)
    if builder.rng.random() < 0.5:
        builder.free_standing("backpack", room, near_wall=True)
    if builder.rng.random() < 0.6:
        builder.free_standing("floor lamp", room, near_wall=True)
    _decorate_walls(
        builder,
        room,
        {
            "whiteboard": (0, 1),
            "painting": (0, 2),
            "clock": (0, 1),
            "wall shelf": (1, 2),
            "air conditioner": (0, 1),
        },
    )
    builder.small("printer", room, 1, ("filing cabinet", "cabinet", "desk"))
    builder.small("mug", room, builder.random_count(1, 3), ("desk",))
    builder.small("bottle", room, builder.random_count(0, 2), ("desk",))
    builder.small("cell phone", room, builder.random_count(0, 1), ("desk",))
    builder.small("keys", room, builder.random_count(0, 1), ("desk", "filing cabinet"))
    builder.small("speaker", room, builder.random_count(0, 1), ("desk", "cabinet"))
    builder.small(
        "picture frame", room, builder.random_count(0, 2), ("desk", "wall shelf", "cabinet")
    )
    builder.small("book", room, builder.random_count(1, 3), ("desk", "cabinet"))
    builder.small("coffee maker", room, builder.random_count(0, 1), ("cabinet", "filing cabinet"))


def _furnish_bedroom(builder: SceneBuilder, room: int) -> None:
    duvet = np.array(_DUVETS[builder.rng.integers(len(_DUVETS))], float)
    bed = builder.against_wall("bed", room, duvet=duvet)
    if bed is not None:
        for sign in (-1, 1):
            if builder.rng.random() < 0.85:
                stand = builder.beside(bed, "nightstand", sign, gap=0.04)
                if stand is not None and builder.rng.random() < 0.75:
                    top = [s for s in builder.supports if s.owner is stand][0]
                    builder.on_support("table lamp", top, local=(0.0, 0.0))
        if builder.rng.random() < 0.6:
            builder.on_wall("painting", room, (1.15, 1.4), side=bed.side, along=bed.along_wall)
    builder.against_wall("wardrobe", room)
    if builder.rng.random() < 0.7:
        dresser = builder.against_wall("dresser", room)
        if dresser is not None and builder.rng.random() < 0.6:
            builder.on_wall(
                "mirror",
                room,
                (dresser.size[2] + 0.2, dresser.size[2] + 0.35),
                side=dresser.side,
                along=dresser.along_wall,
                tries=5,
            )
    if builder.rng.random() < 0.5:
        desk = builder.against_wall("desk", room)
        if desk is not None:
            builder.in_front_of(desk, "chair", 0.05, turn=True)
            top = [s for s in builder.supports if s.owner is desk][0]
            if builder.rng.random() < 0.6:
                builder.on_support(
                    "table lamp", top, local=(desk.size[0] / 2 - 0.2, desk.size[1] / 2 - 0.17)
                )
    if builder.rng.random() < 0.6:
        builder.against_wall("bookshelf", room)
    if builder.rng.random() < 0.35:
        builder.free_standing("armchair", room, near_wall=True)
    for category, p in (
        ("potted plant", 0.6),
        ("backpack", 0.4),
        ("cardboard box", 0.4),
        ("trash can", 0.4),
        ("floor lamp", 0.3),
    ):
        if builder.rng.random() < p:
            builder.free_standing(category, room, near_wall=True)
    _decorate_walls(
        builder,
        room,
        {
            "painting": (1, 2),
            "mirror": (0, 1),
            "clock": (0, 1),
            "wall shelf": (1, 2),
            "air conditioner": (0, 1),
        },
    )
    builder.small("teddy bear", room, builder.random_count(0, 1), ("bed",))
    builder.small(
        "book", room, builder.random_count(2, 4), ("nightstand", "bed", "dresser", "desk")
    )
    builder.small("cell phone", room, builder.random_count(0, 1), ("nightstand", "bed"))
    builder.small("mug", room, builder.random_count(0, 2), ("nightstand", "desk"))
    builder.small(
        "candle", room, builder.random_count(1, 2), ("dresser", "nightstand", "wall shelf")
    )
    builder.small(
        "picture frame", room, builder.random_count(1, 3), ("dresser", "nightstand", "wall shelf")
    )
    builder.small("vase", room, builder.random_count(0, 1), ("dresser",))
    builder.small("laptop", room, builder.random_count(0, 1), ("bed", "desk"))
    builder.small("keys", room, 1, ("dresser", "nightstand"))
    builder.small("remote control", room, builder.random_count(0, 1), ("nightstand", "bed"))


_RECIPES = {
    "living_room": _furnish_living_room,
    "kitchen": _furnish_kitchen,
    "office": _furnish_office,
    "bedroom": _furnish_bedroom,
}
