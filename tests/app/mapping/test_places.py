"""Places in words: what a point rests on or stands near, and which way is up."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.mapping import places
from app.mapping.object import MapObject
from app.mapping.places import (
    UP_STABLE_KEYFRAMES,
    Landmarks,
    Place,
    UpInference,
    describe_place,
    describe_places,
    infer_up,
    up_name,
    up_vector,
)

Z_UP = np.array([0.0, 0.0, 1.0])


def landmarks(*boxes: tuple[str, list[float]]) -> Landmarks:
    """Landmarks with ids 1.. in the order given: (label, [x0, y0, z0, x1, y1, z1])."""
    return Landmarks(
        ids=np.arange(1, len(boxes) + 1),
        labels=tuple(label for label, _ in boxes),
        boxes=np.array([box for _, box in boxes], np.float64).reshape(-1, 6),
    )


# A Z-up room: a dining table, a book on it, a sofa, a wall, a small cup on the floor.
ROOM = landmarks(
    ("dining table", [0.0, 0.0, 0.0, 1.6, 0.9, 0.75]),
    ("book", [0.2, 0.2, 0.75, 0.45, 0.4, 0.79]),
    ("sofa", [3.0, 0.0, 0.0, 5.0, 0.9, 0.8]),
    ("wall", [-1.0, 2.0, 0.0, 6.0, 2.1, 2.5]),
    ("cup", [2.0, 0.5, 0.0, 2.08, 0.58, 0.1]),
)


def test_a_mug_on_the_table_is_on_the_table():
    assert describe_place([1.0, 0.5, 0.8], ROOM, Z_UP) == Place("on", 1, "dining table")


def test_a_thing_on_a_book_on_the_table_is_on_the_table_the_largest_footprint():
    assert describe_place([0.3, 0.3, 0.85], ROOM, Z_UP) == Place("on", 1, "dining table")


def test_a_thing_under_the_table_is_not_on_it_but_near_it():
    assert describe_place([0.8, 0.5, 0.1], ROOM, Z_UP) == Place("near", 1, "dining table")


def test_high_above_a_surface_is_not_on_it():
    place = describe_place([1.0, 0.5, 0.75 + 0.5], ROOM, Z_UP)
    assert place == Place("near", 1, "dining table")


def test_beside_the_sofa_is_near_the_sofa():
    assert describe_place([2.6, 0.4, 0.3], ROOM, Z_UP) == Place("near", 3, "sofa")


def test_small_things_are_never_landmarks_to_stand_near():
    # next to the cup (8 cm) but 0.6 m from the table: near the table
    assert describe_place([2.2, 0.5, 0.05], ROOM, Z_UP) == Place("near", 1, "dining table")


def test_far_from_everything_is_nowhere():
    assert describe_place([20.0, 20.0, 0.5], ROOM, Z_UP) is None
    assert describe_place([1.0, 0.5, 0.8], landmarks(), Z_UP) is None


def test_a_thing_is_never_described_by_itself():
    # inside the table's box: nothing else is near enough
    assert describe_place([0.8, 0.45, 0.4], ROOM, Z_UP, exclude=1) is None
    # on the book on the table: without the table, on the book
    assert describe_place([0.3, 0.3, 0.85], ROOM, Z_UP, exclude=1) == Place("on", 2, "book")


def test_map_objects_are_described_by_their_boxes():
    rng = np.random.default_rng(0)
    table = MapObject(
        id=7,
        points=rng.uniform([0, 0, 0], [1.6, 0.9, 0.75], (200, 3)).astype(np.float32),
        label_counts=Counter({"dining table": 3}),
    )
    assert describe_place([0.8, 0.45, 0.8], [table]) == Place("on", 7, "dining table")


def test_up_is_the_camera_up_snapped_to_an_axis():
    identity = np.eye(4)  # OpenCV camera: y down, so up is -y
    np.testing.assert_array_equal(infer_up(identity), [0.0, -1.0, 0.0])
    # a Z-up world: the camera looks along +x, its y (down) along -z, pitched 30° down
    pitch = np.deg2rad(30)
    look_down = np.eye(4)
    forward = np.array([np.cos(pitch), 0.0, -np.sin(pitch)])
    down = np.array([-np.sin(pitch), 0.0, -np.cos(pitch)])
    look_down[:3, :3] = np.stack([np.cross(down, forward), down, forward], axis=1)
    np.testing.assert_array_equal(infer_up(look_down), [0.0, 0.0, 1.0])
    np.testing.assert_array_equal(infer_up(np.stack([identity] * 3)), [0.0, -1.0, 0.0])


def look(forward, world_up) -> np.ndarray:
    """A camera-to-world pose (OpenCV camera) looking along `forward`, level with `world_up`."""
    forward = np.asarray(forward, np.float64) / np.linalg.norm(forward)
    right = np.cross(forward, world_up)
    right /= np.linalg.norm(right)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2] = right, np.cross(forward, right), forward
    return pose


def headset(n: int, up=(0.0, 1.0, 0.0), seed: int = 0) -> list[np.ndarray]:
    """`n` poses looking about a room whose up is `up`, pitched 35° down to 10° up."""
    rng = np.random.default_rng(seed)
    up = np.asarray(up, np.float64)
    across = np.roll(np.abs(up), 1)  # a horizontal axis
    other = np.cross(up, across)
    poses = []
    for _ in range(n):
        yaw, pitch = rng.uniform(0, 2 * np.pi), np.radians(rng.uniform(-35, 10))
        horizontal = np.cos(yaw) * across + np.sin(yaw) * other
        poses.append(look(np.cos(pitch) * horizontal + np.sin(pitch) * up, up))
    return poses


def settle(inference: UpInference, poses) -> list[str | None]:
    return [inference.observe(pose) for pose in poses]


def test_axis_names_and_vectors_go_both_ways():
    for name in ("+x", "-x", "+y", "-y", "+z", "-z"):
        assert up_name(up_vector(name)) == name
    assert up_name([0.2, -0.9, 0.3]) == "-y"
    for bad in ("y", "+Y", "up", "", "+w", None):
        with pytest.raises(ValueError, match="up must be one of"):
            up_vector(bad)


@pytest.mark.parametrize("up", ["+y", "-y", "+z", "-z", "+x", "-x"])
def test_up_settles_after_enough_agreeing_keyframes(up):
    inference = UpInference()
    said = settle(inference, headset(UP_STABLE_KEYFRAMES + 3, up_vector(up)))
    assert said == [None] * (UP_STABLE_KEYFRAMES - 1) + [up] * 4
    assert inference.settled == up


def test_our_synthetic_walk_settles_z_up():
    from world.rooms import make_scene
    from world.trajectory import walk_trajectory

    inference = UpInference()
    said = settle(inference, walk_trajectory(make_scene("apartment", 0), 40, seed=1))
    assert said.index("+z") == UP_STABLE_KEYFRAMES - 1 and said[-1] == "+z"


def test_a_few_tilted_poses_neither_settle_nor_break_the_streak():
    # looking straight down at the floor of a Y-up room: up points along the floor (+x)
    at_the_floor = look([0.0, -1.0, 0.0], [1.0, 0.0, 0.0])
    assert up_name(-at_the_floor[:3, 1]) == "+x"
    inference = UpInference()
    assert settle(inference, [at_the_floor] * 3) == [None] * 3  # fewer than stable
    said = settle(inference, headset(6 * UP_STABLE_KEYFRAMES))
    assert "+x" not in said and said[-1] == "+y"
    # a tilted pose once the mean holds a few keeps the streak: settled on time
    steady = UpInference()
    poses = headset(UP_STABLE_KEYFRAMES + 2, seed=3)
    poses[5:5] = [at_the_floor]
    assert settle(steady, poses).index("+y") == UP_STABLE_KEYFRAMES - 1
    # settled, nothing flips it
    assert settle(steady, [at_the_floor] * 10 * UP_STABLE_KEYFRAMES)[-1] == "+y"
    assert steady.settled == "+y"


def test_cameras_that_disagree_settle_nothing():
    inference = UpInference()
    spread = [look([1.0, 0.0, 0.0], up) for up in ([0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1])]
    assert settle(inference, spread * 10) == [None] * 40
    assert inference.candidate is None and inference.count == 40


# --- properties --------------------------------------------------------------------------

# Multiples of 1/64 m: sums and differences are exact, so a translation changes no
# comparison (a property of the geometry, not of rounding).
coordinate = st.integers(-192, 192).map(lambda n: n / 64)
size = st.integers(1, 128).map(lambda n: n / 64)


@st.composite
def scenes(draw) -> tuple[Landmarks, np.ndarray]:
    n = draw(st.integers(0, 8))
    boxes = []
    for _ in range(n):
        corner = [draw(coordinate) for _ in range(3)]
        sides = [draw(size) for _ in range(3)]
        boxes.append(
            (
                draw(st.sampled_from(["table", "sofa", "mug"])),
                corner + [c + s for c, s in zip(corner, sides, strict=True)],
            )
        )
    point = np.array([draw(coordinate) for _ in range(3)])
    if boxes and draw(st.booleans()):  # half the time just above a box: "on" gets tested too
        x0, y0, _, x1, y1, z1 = draw(st.sampled_from(boxes))[1]
        point = np.array([(x0 + x1) / 2, (y0 + y1) / 2, z1 + draw(st.integers(0, 24)) / 64])
    return landmarks(*boxes), point


@settings(max_examples=200, deadline=None)
@given(scene=scenes(), shift=st.tuples(coordinate, coordinate, coordinate))
def test_the_place_is_the_same_after_moving_everything_together(scene, shift):
    marks, point = scene
    shift = np.array(shift)
    moved = Landmarks(marks.ids, marks.labels, marks.boxes + np.tile(shift, 2))
    assert describe_place(point + shift, moved, Z_UP) == describe_place(point, marks, Z_UP)


@settings(max_examples=200, deadline=None)
@given(scene=scenes())
def test_a_z_up_room_seen_y_up_has_the_same_places(scene):
    # (x, y, z) Z-up -> (x, z, -y) Y-up: the same room in an XR runtime's frame
    marks, point = scene

    def to_y_up(xyz: np.ndarray) -> np.ndarray:
        return np.stack([xyz[..., 0], xyz[..., 2], -xyz[..., 1]], axis=-1)

    lo, hi = to_y_up(marks.boxes[:, :3]), to_y_up(marks.boxes[:, 3:])
    y_up = Landmarks(marks.ids, marks.labels, np.hstack([np.minimum(lo, hi), np.maximum(lo, hi)]))
    expected = describe_place(point, marks, Z_UP)
    assert describe_place(to_y_up(point), y_up, np.array([0.0, 1.0, 0.0])) == expected


@settings(max_examples=200, deadline=None)
@given(scene=scenes(), excluded=st.integers(1, 8))
def test_an_answer_is_never_the_excluded_object_and_near_is_large_and_close(scene, excluded):
    marks, point = scene
    place = describe_place(point, marks, Z_UP, exclude=excluded)
    if place is None:
        return
    assert place.id != excluded
    if place.relation == "near":
        lo, hi = marks.boxes[place.id - 1, :3], marks.boxes[place.id - 1, 3:]
        assert np.linalg.norm(np.maximum(np.maximum(lo - point, point - hi), 0)) <= 1.5
        sides = hi - lo
        assert np.prod(sides) >= 0.03 or sides.max() >= 0.5


def test_many_points_at_once_are_described_as_each_alone(monkeypatch):
    monkeypatch.setattr(places, "BATCH_ELEMENTS", 7)  # a few points per batch
    rng = np.random.default_rng(1)
    on_things = [[1.0, 0.5, 0.8], [0.3, 0.3, 0.85], [4.0, 0.5, 0.9], [2.04, 0.54, 0.2]]
    points = np.vstack([rng.uniform([-1, -1, 0], [6, 3, 1.5], (36, 3)), on_things])
    exclude = rng.integers(1, 6, 40)
    alone = [
        describe_place(p, ROOM, Z_UP, exclude=int(e)) for p, e in zip(points, exclude, strict=True)
    ]
    assert describe_places(points, ROOM, Z_UP, exclude) == alone
    assert {p.relation for p in alone if p} == {"on", "near"} and None in alone


@pytest.mark.parametrize("up", [[0, 0, 1], [0, 0, -1], [0, 1, 0], [-1, 0, 0]])
def test_upside_down_worlds_rest_things_on_their_own_up(up):
    # a 1 m slab and a point 0.1 m beyond its face along `up`: on it
    up = np.array(up, np.float64)
    slab = np.where(up == 0, 1.0, 0.2)  # half-extents: 1 m across, 0.2 m thick
    marks = landmarks(("table", [*(-slab), *slab]))
    assert describe_place(up * 0.3, marks, up) == Place("on", 1, "table")
    assert describe_place(-up * 0.3, marks, up) == Place("near", 1, "table")
