"""The living map's test room: labelled rectangles facing the camera (tests/analytic_world.py)
in front of a wall, walked twice ten minutes apart with the room changed in between (a mug
moved, a book taken away, a box set in front of the bin, a plant added). Shared by the
server's, the client's, the CLI's and the dashboard's tests of the living map."""

from __future__ import annotations

from analytic_world import Rect
from devices import frame_message

KNOBS = {
    "keyframe_interval": 1,
    "min_observations": 2,
    "min_mapping_bbox_area": 100,
    "local_map_update_frequency": 1,
    "cleanup_interval": 1000,
}
WALL = Rect(9, "whiteboard", -3.0, -2.0, 3.0, 2.0, 3.0)
MUG = Rect(1, "mug", -0.5, -0.2, -0.3, 0.0, 2.0)
MUG_MOVED = Rect(1, "mug", 0.5, 0.3, 0.7, 0.5, 2.0)
BOOK = Rect(2, "book", 0.2, -0.5, 0.5, -0.3, 2.0)
BIN = Rect(3, "trash can", -0.5, 0.3, -0.2, 0.6, 2.0)
BOX = Rect(4, "cardboard box", -0.65, 0.15, -0.05, 0.75, 1.6)
"""Set in front of the bin in the second walk: it hides it completely."""
PLANT = Rect(5, "potted plant", 0.0, -0.1, 0.25, 0.2, 2.0)
BEFORE = [WALL, MUG, BOOK, BIN]
AFTER = [WALL, MUG_MOVED, BIN, BOX, PLANT]  # the mug moved, the book taken, two things new
WALK_2_T = 600.0


def frame(rects, seq: int, t: float, cam_x: float) -> dict:
    """One v1 frame of the room at device time `t`, the camera at (cam_x, 0, 0)."""
    return frame_message(rects, seq, cam_xy=(cam_x, 0.0), t=t)


def walk(rects, t0: float, n: int = 7) -> list[dict]:
    """n frames a second apart on the device clock, the camera sliding 3 cm a frame."""
    return [frame(rects, seq=i, t=t0 + i, cam_x=0.03 * i) for i in range(n)]
