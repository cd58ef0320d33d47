"""The device's keyframe pick: the shared selector's keyframes, and a frame showing a place
the server doubts (not one hidden behind something nearer) once one more keyframe could
settle it, at most every second frame."""

from __future__ import annotations

import numpy as np

from client_sim.keyframe_pick import KeyframePick, doubted_place_in_view

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
    pick = KeyframePick(interval=5, min_depth_m=0.3, max_depth_m=4.0)
    frame = (np.eye(4), INTRINSICS, SIZE, _depth(3.0))
    assert [seq for seq in range(11) if pick.pick(seq, 10 + seq / 5, *frame)] == [0, 5, 10]
    pick = KeyframePick(interval=5, min_depth_m=0.3, max_depth_m=4.0, doubted=PLACE)
    picked = [seq for seq in range(11) if pick.pick(seq, 10 + seq / 5, *frame)]
    assert picked == [0, 2, 4, 5, 7, 9, 10] and pick.doubt_picks == 4
    pick = KeyframePick(interval=5, min_depth_m=0.3, max_depth_m=4.0, doubted=PLACE)
    early = [seq for seq in range(11) if pick.pick(seq, 9 + seq / 5, *frame)]
    assert early == [0, 5, 7, 9, 10]  # ready from t 10 s, frame 5 on
    hidden = (np.eye(4), INTRINSICS, SIZE, _depth(1.0))
    pick = KeyframePick(interval=5, min_depth_m=0.3, max_depth_m=4.0, doubted=PLACE)
    assert [seq for seq in range(11) if pick.pick(seq, 10 + seq / 5, *hidden)] == [0, 5, 10]
