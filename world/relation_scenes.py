"""Rooms for questions about how things stand: duplicates of a category in distinct relations.

`make_relation_scene(seed)` furnishes one room so that copies of a category can only be told
apart by what they stand in relation to (docs/evaluation.md "Relations"): mugs on a desk, on a level of
a bookcase and on a dining table (and perhaps a coffee table); a chair at the desk, one by the
sofa and two against a wall with a cardboard box between them; a backpack on one of those
chairs and another under the dining table; a table lamp on the side table by the sofa (another
on the desk in some rooms) and a floor lamp on the floor; books lying on the desk and
standing in the bookcase; a painting above the sofa and another elsewhere. Which wall holds
which group, the room's size, the sizes and colours, and the optional extras are drawn from
one generator seeded by `seed`, so a room is deterministic per seed and seeds vary the layout.

Nothing here records relations: the ground truth of every question
(`world.relation_queries`) comes from the scene's geometry and from the
placement engine's `support_id` (what each thing was stood on), as for any other scene.
"""

from __future__ import annotations

import math

import numpy as np

from world.placement import REST_GAP_M, Placed, SceneBuilder, Support
from world.scene import Room, Scene

RELATION_SCENE = "relations"
"""`Scene.name` of the relation rooms."""
_ROOM_TYPE = "living_room"  # floor and wall palettes, the ornaments on the bookcase
_CHAIR_SEAT_M = 0.46  # the seat height world.furniture draws chairs with
_SEAT_BACK_M = 0.05  # the part of a seat's depth the chair's back stands on
_UNDER_TABLE_INSET_M = 0.15  # keeps a bag under a table clear of its legs


def make_relation_scene(seed: int = 0) -> Scene:
    """One furnished room (about 6 x 5 m, ~35-45 objects); deterministic for `seed`."""
    rng = np.random.default_rng([int(seed), 0x2E1A7])
    builder = SceneBuilder(rng)
    width = round(float(rng.uniform(5.6, 6.4)), 2)
    depth = round(float(rng.uniform(4.8, 5.4)), 2)
    height = round(float(rng.uniform(2.6, 2.8)), 2)
    builder.build_architecture([Room(_ROOM_TYPE, (0.0, 0.0, width, depth), height)], [])
    room = 0
    sides = [int(s) for s in rng.permutation(4)]  # which wall holds which group
    _sofa_corner(builder, room, sides[0])
    desk = _desk_corner(builder, room, sides[1])
    _bookcase_corner(builder, room, sides[2])
    _chairs_with_a_box(builder, room, sides[3])
    _dining_table(builder, room)
    _extras(builder, room, desk)
    x0, y0, x1, y1 = builder.inner_rect(room)
    builder.on_ceiling("ceiling light", room, ((x0 + x1) / 2, (y0 + y1) / 2))
    builder.fill_shelves(room, fill=0.6)
    for _ in range(builder.random_count(1, 2)):
        builder.on_wall("window", room, (1.0, 1.1))
    return Scene(
        name=RELATION_SCENE,
        seed=int(seed),
        objects=builder.objects,
        rooms=builder.rooms,
        doorways=builder.doorways,
    )


def _top(builder: SceneBuilder, owner: Placed | None) -> Support | None:
    """The top surface `owner` offers (None for no owner or none offered)."""
    if owner is None:
        return None
    tops = [s for s in builder.supports if s.owner is owner and s.kind == "top"]
    return tops[0] if tops else None


def _seat(builder: SceneBuilder, chair: Placed) -> Support:
    """A chair's seat as a surface to put a bag on (chairs offer none of their own)."""
    w, d, _ = chair.size
    local = np.array([[-w / 2 + 0.02, -d / 2 + 0.02], [w / 2 - 0.02, d / 2 - _SEAT_BACK_M - 0.02]])
    return _support_over(builder, chair, local, chair.z + _CHAIR_SEAT_M, 0.7, "seat")


def _floor_under(builder: SceneBuilder, table: Placed) -> Support:
    """The floor under a table, clear of its legs, as a place to put something."""
    w, d, h = table.size
    inset = _UNDER_TABLE_INSET_M
    local = np.array([[-w / 2 + inset, -d / 2 + inset], [w / 2 - inset, d / 2 - inset]])
    return _support_over(builder, table, local, 0.0, h - 0.1, "under")


def _support_over(
    builder: SceneBuilder, owner: Placed, local: np.ndarray, z: float, clearance: float, kind: str
) -> Support:
    """A world-space `Support` from a rectangle [[x0, y0], [x1, y1]] in the owner's frame."""
    c, s = math.cos(owner.yaw), math.sin(owner.yaw)
    corners = np.array([[x, y] for x in local[:, 0] for y in local[:, 1]])
    world = corners @ np.array([[c, s], [-s, c]]) + (owner.x, owner.y)
    rect = np.concatenate([world.min(0), world.max(0)])
    return Support(rect, z, clearance, kind, owner, owner.obj.room)


def _room_on_both_sides(
    builder: SceneBuilder, room: int, side: int, width: float, beside_m: float
) -> float:
    """A place along wall `side` for something `width` wide with `beside_m` free on both
    sides of it (its neighbours go there)."""
    a0, a1 = builder.wall_span(room, side)
    lo, hi = a0 + beside_m + width / 2, a1 - beside_m - width / 2
    return float(builder.rng.uniform(lo, hi)) if hi > lo else (a0 + a1) / 2


def _set_down(builder: SceneBuilder, category: str, support: Support) -> Placed | None:
    """Put a bag-sized thing on `support` turned like its owner (a bag on a seat has no room
    to lie askew), near the middle."""
    owner = support.owner
    r = support.rect
    middle = np.array([(r[0] + r[2]) / 2, (r[1] + r[3]) / 2])
    size = builder.sample_size(category)
    candidates = [
        (*(middle + builder.rng.normal(0.0, 0.03, 2) * (k > 0)), support.z + REST_GAP_M, yaw)
        for k in range(12)
        for yaw in [owner.yaw + math.radians(builder.rng.normal(0.0, 6.0))]
    ]
    return builder.place(category, owner.obj.room, candidates, size=size, gap=0.01, support=support)


def _sofa_corner(builder: SceneBuilder, room: int, side: int) -> Placed | None:
    """A sofa, a side table with a table lamp on one side, a chair on the other, a painting
    above it."""
    size = builder.sample_size("sofa")
    sofa = builder.against_wall(
        "sofa",
        room,
        side=side,
        along=_room_on_both_sides(builder, room, side, size[0], 0.8),
        size=size,
    )
    if sofa is None:
        return None
    sign = int(builder.rng.choice([-1, 1]))
    stand = builder.beside(sofa, "nightstand", sign, gap=0.05)
    top = _top(builder, stand)
    if top is not None:
        width, depth, tall = builder.sample_size("table lamp")
        side_m = min(
            width, depth, top.rect[2] - top.rect[0] - 0.02, top.rect[3] - top.rect[1] - 0.02
        )
        builder.on_support("table lamp", top, local=(0.0, 0.0), size=(side_m, side_m, tall))
    builder.beside(sofa, "chair", -sign, gap=float(builder.rng.uniform(0.1, 0.25)))
    builder.on_wall("painting", room, (1.2, 1.35), side=sofa.side, along=sofa.along_wall)
    return sofa


def _desk_corner(builder: SceneBuilder, room: int, side: int) -> Placed | None:
    """A desk with a chair at it; a mug and a book on it, sometimes a laptop and a lamp."""
    desk = builder.against_wall("desk", room, side=side)
    if desk is None:
        return None
    builder.in_front_of(desk, "chair", 0.05, turn=True)
    top = _top(builder, desk)
    if top is None:
        return desk
    if builder.rng.random() < 0.5:
        builder.on_support(
            "table lamp", top, local=(desk.size[0] / 2 - 0.2, desk.size[1] / 2 - 0.17)
        )
    for category in ("mug", "book"):
        builder.on_support(category, top)
    if builder.rng.random() < 0.5:
        builder.on_support("laptop", top)
    return desk


def _bookcase_corner(builder: SceneBuilder, room: int, side: int) -> None:
    """A bookcase with a mug on one of its middle levels, a floor lamp beside it and a
    cardboard box on the other side (books and ornaments come with `fill_shelves`)."""
    size = builder.sample_size("bookshelf")
    shelf = builder.against_wall(
        "bookshelf",
        room,
        side=side,
        along=_room_on_both_sides(builder, room, side, size[0], 0.7),
        size=size,
    )
    if shelf is None:
        return
    levels = sorted(
        (s for s in builder.supports if s.owner is shelf and s.kind == "shelf"),
        key=lambda s: s.z,
    )
    middle = [s for s in levels if 0.5 <= s.z <= 1.4] or levels
    if middle:
        builder.on_support("mug", middle[int(builder.rng.integers(len(middle)))])
    sign = int(builder.rng.choice([-1, 1]))
    builder.beside(shelf, "floor lamp", sign, gap=float(builder.rng.uniform(0.1, 0.3)))
    if builder.rng.random() < 0.6:
        builder.beside(shelf, "cardboard box", -sign, gap=float(builder.rng.uniform(0.1, 0.3)))


def _chairs_with_a_box(builder: SceneBuilder, room: int, side: int) -> None:
    """Two chairs with their backs to a wall about a metre apart, a cardboard box on the floor
    between them and a backpack on one of their seats."""
    a0, a1 = builder.wall_span(room, side)
    spacing = float(builder.rng.uniform(0.95, 1.25))
    middle = float(builder.rng.uniform(a0 + 0.4 + spacing / 2, a1 - 0.4 - spacing / 2))
    chairs = []
    for sign in (-1, 1):
        size = builder.sample_size("chair")
        chair = builder.against_wall(
            "chair", room, side=side, along=middle + sign * spacing / 2, size=size, tries=4
        )
        if chair is not None:
            chairs.append(chair)
    if len(chairs) == 2:
        size = builder.sample_size("cardboard box")
        chair_depth = float(np.mean([c.size[1] for c in chairs]))
        builder.against_wall(
            "cardboard box",
            room,
            side=side,
            along=float(np.mean([c.along_wall for c in chairs])),
            size=size,
            tries=3,
            wall_gap=max(0.01, 0.01 + chair_depth / 2 - size[1] / 2),
        )
    if chairs:
        chair = chairs[int(builder.rng.integers(len(chairs)))]
        _set_down(builder, "backpack", _seat(builder, chair))


def _dining_table(builder: SceneBuilder, room: int) -> None:
    """A dining table in the middle of the room (the walk goes round it), a mug on it (two in
    some rooms) and a bottle, bowl or book, a backpack on the floor under it."""
    x0, y0, x1, y1 = builder.inner_rect(room)
    middle = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
    yaw = 0.0 if x1 - x0 >= y1 - y0 else math.pi / 2  # its length along the room's
    candidates = [
        (*(middle + builder.rng.uniform(-0.15, 0.15, 2) * (k > 0)), REST_GAP_M, yaw)
        for k in range(8)
    ]
    table = builder.place("dining table", room, candidates)
    if table is None:
        return
    top = _top(builder, table)
    if top is not None:
        for _ in range(1 + (builder.rng.random() < 0.4)):
            builder.on_support("mug", top)
        extra = ("bottle", "bowl", "book")[int(builder.rng.integers(3))]
        builder.on_support(extra, top)
    bag = _set_down(builder, "backpack", _floor_under(builder, table))
    if bag is not None:
        bag.obj.support_id = 0  # it stands on the floor, under the table


def _extras(builder: SceneBuilder, room: int, desk: Placed | None) -> None:
    """Things that make the room less tidy: a plant, a bin by the desk, another painting."""
    builder.free_standing("potted plant", room, near_wall=True)
    if desk is not None and builder.rng.random() < 0.6:
        builder.beside(desk, "trash can", int(builder.rng.choice([-1, 1])))
    builder.on_wall("painting", room, (1.2, 1.6))
    if builder.rng.random() < 0.5:
        builder.on_wall("clock", room, (1.7, 1.9))
    if builder.rng.random() < 0.5:
        builder.free_standing("cardboard box", room, near_wall=True)


# --- the walk -------------------------------------------------------------------------------

WALK_CLEARANCE_M = 0.35
"""The walk keeps at least this far from furniture footprints and walls."""
OUTWARD_SHARE = 0.6
"""Share of the walk spent looking out at the walls (the rest looks in across the room)."""
_EYE_HEIGHT_M = 1.55
_OBSTACLE_TOP_M = 2.0  # what hangs higher does not block a walking person
_RAY_STEP_M = 0.05


def relation_walk(scene: Scene, n_frames: int, seed: int = 0) -> list[np.ndarray]:
    """`n_frames` camera-to-world poses (float64 [4, 4], OpenCV camera axes) of a walk round
    the middle of a one-room scene at eye height.

    The path is a loop halfway between what stands in the middle of the room and what stands
    along its walls, at least WALK_CLEARANCE_M from both. For the first OUTWARD_SHARE of the
    frames the camera looks out at the walls (scanning side to side, pitched down to see table
    tops), then it turns round and looks in across the room, past the middle, at the far side:
    every wall group is seen from near and from far, and the middle table from far enough to
    see under it. The walk starts at a point of the loop drawn from `seed`.
    """
    if n_frames <= 0:
        return []
    rng = np.random.default_rng([int(seed), 0x3A1C])
    centre, loop = _loop_around_the_middle(scene)
    closed = np.vstack([loop, loop[:1]])
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
    laps = 1.0 + (1.0 - OUTWARD_SHARE) / OUTWARD_SHARE  # a full lap outwards, then on
    start = rng.uniform(0.0, arc[-1])
    along = (start + np.linspace(0.0, laps * arc[-1], n_frames)) % arc[-1]
    xy = np.stack([np.interp(along, arc, closed[:, 0]), np.interp(along, arc, closed[:, 1])], 1)
    outward = np.arctan2(xy[:, 1] - centre[1], xy[:, 0] - centre[0])
    share = np.arange(n_frames) / max(n_frames - 1, 1)
    turn = np.clip((share - OUTWARD_SHARE) / 0.1, 0.0, 1.0)  # look in after the first lap
    phase = rng.uniform(0.0, 2 * math.pi, 2)
    scan = np.radians(35.0) * np.sin(2 * math.pi * share * 4.0 + phase[0])
    yaw = np.unwrap(outward) + math.pi * turn + scan * (1.0 - 0.5 * turn)
    pitch = -np.radians(24.0 + 8.0 * np.sin(2 * math.pi * share * 3.0 + phase[1]))
    return [
        _camera_pose(np.array([x, y, _EYE_HEIGHT_M]), a, b)
        for (x, y), a, b in zip(xy, yaw, pitch, strict=True)
    ]


def _camera_pose(position: np.ndarray, yaw: float, pitch: float) -> np.ndarray:
    """Camera-to-world [4, 4] (OpenCV axes: x right, y down, z forward) looking along yaw
    (radians from +x) pitched by `pitch` (negative: down)."""
    forward = np.array(
        [math.cos(pitch) * math.cos(yaw), math.cos(pitch) * math.sin(yaw), math.sin(pitch)]
    )
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2] = right, np.cross(forward, right), forward
    pose[:3, 3] = position
    return pose


def _loop_around_the_middle(scene: Scene, n_angles: int = 180) -> tuple[np.ndarray, np.ndarray]:
    """(centre [2], loop [n_angles, 2]): for each direction from the room's centre, the middle
    of the first free stretch past what stands in the middle, smoothed round the loop."""
    x0, y0, x1, y1 = scene.rooms[0].bounds
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
    boxes = np.array(
        [
            o.bbox[[0, 1, 3, 4]]
            for o in scene.objects
            if not o.is_background and o.bbox[2] < _OBSTACLE_TOP_M
        ]
    ).reshape(-1, 4)
    c = WALK_CLEARANCE_M
    steps = np.arange(0.0, max(x1 - x0, y1 - y0), _RAY_STEP_M)
    angles = np.linspace(0.0, 2 * math.pi, n_angles, endpoint=False)
    radius = np.zeros(n_angles)
    for k, angle in enumerate(angles):
        points = centre + steps[:, None] * (math.cos(angle), math.sin(angle))
        inside = (
            (points[:, 0] > x0 + c)
            & (points[:, 0] < x1 - c)
            & (points[:, 1] > y0 + c)
            & (points[:, 1] < y1 - c)
        )
        blocked = ~inside
        if len(boxes):
            blocked |= (
                (points[:, None, 0] > boxes[None, :, 0] - c)
                & (points[:, None, 0] < boxes[None, :, 2] + c)
                & (points[:, None, 1] > boxes[None, :, 1] - c)
                & (points[:, None, 1] < boxes[None, :, 3] + c)
            ).any(1)
        free = np.flatnonzero(~blocked)
        if not len(free):
            radius[k] = np.nan
            continue
        first = free[0]
        last = first + int(np.argmax(np.append(blocked[first:], True)))  # first blocked after
        radius[k] = steps[first] + (steps[last - 1] - steps[first]) / 2
    if np.isnan(radius).all():
        raise ValueError(f"scene {scene.name!r} has no free floor round its middle")
    radius = np.where(np.isnan(radius), np.nanmedian(radius), radius)
    kernel = np.ones(9) / 9
    smooth = np.convolve(np.concatenate([radius[-4:], radius, radius[:4]]), kernel, "valid")
    loop = centre + smooth[:, None] * np.stack([np.cos(angles), np.sin(angles)], 1)
    return centre, loop
