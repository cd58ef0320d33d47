"""The device's keyframe pick: the shared selector's keyframes, and a frame showing a place
the server doubts (not one hidden behind something nearer) once one more keyframe could
settle it (from its t_ready on, or from a second viewpoint), at most every second frame."""

from __future__ import annotations

import numpy as np

from client_sim.keyframe_pick import (
    KeyframePick,
    doubted_place_in_view,
    doubted_place_in_view_apart,
)

INTRINSICS = (277.0, 277.0, 159.5, 119.5)
SIZE = (320, 240)
PLACE = np.array([[0.0, 0.0, 2.0, 0.1, 10.0]])
"""A place 2 m straight ahead of a camera at the origin looking along +z, ready at t 10 s."""


def _depth(metres: float) -> np.ndarray:
    return np.full((48, 64), metres, np.float32)  # the RGB size / 5


def _in_view(places, depth_m, pose=None, t=10.0) -> bool:
    pose = np.eye(4) if pose is None else pose
    return doubted_place_in_view(places, t, pose, INTRINSICS, SIZE, depth_m, 0.3, 4.0)


def test_a_doubted_place_in_view_with_the_wall_behind_it_visible_is_shown():
    assert _in_view(PLACE, _depth(3.0))  # seen through: the thing is gone
    assert _in_view(PLACE, _depth(1.95))  # its own surface: the thing is there


def test_a_place_is_not_shown_before_one_more_keyframe_could_settle_it():
    assert not _in_view(PLACE, _depth(3.0), t=9.8)


def test_a_place_behind_something_nearer_beyond_range_or_out_of_the_image_is_not():
    assert not _in_view(PLACE, _depth(1.0))  # something in front: occluded
    assert not _in_view(PLACE, _depth(0.0))  # no depth
    assert not _in_view(np.array([[0.0, 0.0, 5.0, 0.1, 0.0]]), _depth(6.0))  # too far
    assert not _in_view(np.array([[3.0, 0.0, 2.0, 0.1, 0.0]]), _depth(3.0))  # outside
    behind = np.eye(4)
    behind[:3, :3] = np.diag([-1.0, 1.0, -1.0])  # turned round
    assert not _in_view(PLACE, _depth(3.0), behind)
    assert not _in_view(np.zeros((0, 5)), _depth(3.0))


def test_the_pick_adds_frames_showing_a_doubted_place_at_most_every_second_frame():
    pick = KeyframePick(5, 0.3, 4.0, 0.5, 20.0)
    frame = (np.eye(4), INTRINSICS, SIZE, _depth(3.0))
    assert [seq for seq in range(11) if pick.pick(seq, 10 + seq / 5, *frame)] == [0, 5, 10]
    pick = KeyframePick(5, 0.3, 4.0, 0.5, 20.0, doubted=PLACE)
    picked = [seq for seq in range(11) if pick.pick(seq, 10 + seq / 5, *frame)]
    assert picked == [0, 2, 4, 5, 7, 9, 10] and pick.doubt_picks == 4
    pick = KeyframePick(5, 0.3, 4.0, 0.5, 20.0, doubted=PLACE)
    early = [seq for seq in range(11) if pick.pick(seq, 9 + seq / 5, *frame)]
    assert early == [0, 5, 7, 9, 10]  # ready from t 10 s, frame 5 on
    hidden = (np.eye(4), INTRINSICS, SIZE, _depth(1.0))
    pick = KeyframePick(5, 0.3, 4.0, 0.5, 20.0, doubted=PLACE)
    assert [seq for seq in range(11) if pick.pick(seq, 10 + seq / 5, *hidden)] == [0, 5, 10]


DOUBTED_FROM_HERE = np.array([[0.0, 0.0, 2.0, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]])
"""The same place, doubted by a view from the origin looking along +z."""


def _pose(x: float = 0.0, yaw_deg: float = 0.0) -> np.ndarray:
    """A camera at (x, 0, 0) turned yaw_deg about the vertical (y) axis."""
    pose = np.eye(4)
    a = np.radians(yaw_deg)
    pose[:3, :3] = [[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]]
    pose[0, 3] = x
    return pose


def _in_view_apart(places, pose, depth_m=None) -> bool:
    depth_m = _depth(3.0) if depth_m is None else depth_m
    return doubted_place_in_view_apart(places, pose, INTRINSICS, SIZE, depth_m, 0.3, 4.0, 0.5, 20.0)


def test_a_doubted_place_is_shown_from_a_second_viewpoint_only():
    assert not _in_view_apart(DOUBTED_FROM_HERE, _pose())  # where the doubt was seen from
    assert not _in_view_apart(DOUBTED_FROM_HERE, _pose(x=0.3, yaw_deg=-5.0))  # too near
    # 0.6 m aside, turned to keep the place in view
    assert _in_view_apart(DOUBTED_FROM_HERE, _pose(x=0.6, yaw_deg=-10.0))
    # a place 12 degrees off the doubting view's axis, from where that view stood: turned
    # 25 degrees (the place 13 degrees off the new axis, inside the image) or only 12
    towards = DOUBTED_FROM_HERE.copy()
    towards[0, 0] = -2.0 * np.tan(np.radians(12.0))
    assert _in_view_apart(towards, _pose(yaw_deg=-25.0))
    assert not _in_view_apart(towards, _pose(yaw_deg=-12.0))


def test_a_second_viewpoint_does_not_show_a_place_hidden_or_out_of_view():
    aside = _pose(x=0.6, yaw_deg=-10.0)
    assert not _in_view_apart(DOUBTED_FROM_HERE, aside, _depth(1.0))  # occluded
    assert not _in_view_apart(DOUBTED_FROM_HERE, _pose(x=0.6, yaw_deg=60.0))  # looks away
    assert not _in_view_apart(np.zeros((0, 10)), aside)


def test_the_pick_adds_frames_showing_a_doubted_place_from_a_second_viewpoint():
    """A walk sidesteps 0.1 m a frame, turning to keep the place in view: frames from 0.5 m
    on are picked (every second one), with no t_ready to wait for."""
    pick = KeyframePick(5, 0.3, 4.0, 0.5, 20.0, doubted_from=DOUBTED_FROM_HERE)

    def pose(seq):
        x = 0.1 * seq
        return _pose(x=x, yaw_deg=-np.degrees(np.arctan2(x, 2.0)))

    picked = [seq for seq in range(11) if pick.pick(seq, seq / 5, pose(seq), *FRAME_REST)]
    assert picked == [0, 5, 7, 9, 10] and pick.doubt_picks == 2


FRAME_REST = (INTRINSICS, SIZE, _depth(3.0))
