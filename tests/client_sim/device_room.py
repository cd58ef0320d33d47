"""A room for relational questions asked of the device's local map and of the server alike
(LQ = SQ: docs/evaluation.md "Relations"): duplicate categories in distinct relations, every
object at most 200 points (the client cap, so the server sends them all and the device keeps
them all). Z-up, metres; shapes from tests/relation_scene.py."""

from __future__ import annotations

import numpy as np
from relation_scene import TO_Y_UP, block, chair, map_export, table

ROOM: dict[int, tuple[str, np.ndarray]] = {
    1: ("desk", table(0.0, 0.0, w=1.2, d=0.6, seed=1, count=200)),
    2: ("shelf", block(3.0, 0.0, 0.0, 0.8, 0.3, 1.2, seed=2)),
    3: ("table", table(0.0, 3.0, seed=3, count=200)),
    4: ("sofa", block(5.0, 3.0, 0.0, 2.0, 0.9, 0.8, seed=4, count=200)),
    10: ("mug", block(0.5, 0.2, 0.75, 0.08, 0.08, 0.1, seed=10, count=60)),  # on the desk
    11: ("mug", block(3.3, 0.1, 1.2, 0.08, 0.08, 0.1, seed=11, count=60)),  # on the shelf
    12: ("mug", block(1.0, 3.4, 0.75, 0.08, 0.08, 0.1, seed=12, count=60)),  # on the table
    20: ("chair", chair(0.3, -0.65, seed=20)),  # at the desk
    21: ("chair", chair(4.4, 3.2, seed=21)),  # next to the sofa
    30: ("bag", block(0.5, 3.2, 0.0, 0.4, 0.3, 0.3, seed=30)),  # under the table
    31: ("bag", block(5.5, 3.2, 0.8, 0.35, 0.25, 0.3, seed=31)),  # on the sofa
    40: ("lamp", block(0.9, 0.1, 0.75, 0.15, 0.15, 0.4, seed=40, count=80)),  # on the desk
    41: ("lamp", block(7.3, 3.2, 0.0, 0.3, 0.3, 1.6, seed=41)),  # a floor lamp by the sofa
    50: ("book", block(0.3, 3.5, 0.75, 0.2, 0.25, 0.04, seed=50, count=80)),  # on the table
    51: ("book", block(3.5, 0.05, 1.2, 0.2, 0.25, 0.04, seed=51, count=80)),  # on the shelf
    60: ("box", block(0.5, 1.7, 0.0, 0.3, 0.3, 0.3, seed=60, count=80)),  # between desk and table
}

VIEWER = np.array([2.5, 1.5, 1.6])
"""Where the asker stands: between the desk, the shelf and the table, facing the sofa."""

QUESTIONS = [
    "the mug on the desk",
    "the mug on the shelf",
    "mug sitting on the table",
    "which chair is next to the sofa",
    "what is under the table",
    "the bag on the sofa",
    "the bag under the table",
    "the lamp on the desk",
    "the book on the table",
    "the lamp closest to me",
    "the mug closest to me",
    "the lamp farthest from me",
    "the highest mug",
    "the biggest table",
    "the chair left of the sofa",
    "the mug in front of the table",
    "what is between the desk and the table",
    "the mug near me",
    "the chair closest to the sofa",
    "the mug under the sofa",
    "the bag on the desk",
    "the bag on the floor",
    "the mug on the floor",
]
"""Relational questions, a few of them satisfied by nothing (NEGATIVES)."""
NEGATIVES = {
    "the mug under the sofa",
    "the bag on the desk",
    "the mug near me",
    "the mug on the floor",
}
"""The questions nothing in ROOM satisfies (`match` false): no mug within reach of VIEWER."""


def room_export(y_up: bool = False) -> dict:
    """ROOM as an import (`map_export`): Z-up, or with `y_up` turned into a Y-up frame
    (TO_Y_UP) with the session's up set to "+y"."""
    if y_up:
        return map_export(ROOM, "device room", turn=TO_Y_UP, up="+y", up_source="set")
    return map_export(ROOM, "device room")
