"""Places read from the map's points: a few stray points that blow a box up do not make it
the place of everything."""

from __future__ import annotations

from collections import Counter

import numpy as np

from app.mapping.object import MapObject
from app.mapping.places import Place, describe_place

RNG = np.random.default_rng(0)


def _object(oid: int, label: str, points: np.ndarray) -> MapObject:
    return MapObject(id=oid, points=points.astype(np.float32), label_counts=Counter({label: 3}))


def _surface(x0, y0, x1, y1, z, n) -> np.ndarray:
    return np.stack([RNG.uniform(x0, x1, n), RNG.uniform(y0, y1, n), np.full(n, z)], 1)


TABLE = _object(1, "dining table", _surface(0.0, 0.0, 1.6, 0.9, 0.75, 400))
# A rug under and around the table, with two strays of the table top in its cloud: its box
# reaches the table top and its footprint is the largest.
RUG = _object(
    2,
    "rug",
    np.concatenate(
        [_surface(-1.0, -1.0, 2.6, 1.9, 0.01, 400), [[0.9, 0.4, 0.76], [1.1, 0.5, 0.75]]]
    ),
)


def test_a_mug_on_the_table_is_on_the_table_not_on_an_inflated_rug():
    assert describe_place([1.0, 0.45, 0.8], [TABLE, RUG]) == Place("on", 1, "dining table")


def test_the_rugs_box_alone_would_have_swallowed_the_mug():
    """What the boxes say: the rug's box holds the table top, and its footprint wins."""
    from app.mapping.places import Landmarks

    boxes = Landmarks.of([TABLE, RUG])
    boxes_only = Landmarks(boxes.ids, ["dining table", "rug"], boxes.boxes)
    assert describe_place([1.0, 0.45, 0.8], boxes_only) == Place("on", 2, "rug")


def test_a_thing_on_the_floor_beside_the_table_is_on_the_rug():
    assert describe_place([2.2, 1.5, 0.05], [TABLE, RUG]) == Place("on", 2, "rug")


def test_near_is_the_distance_to_the_nearest_point_not_to_a_blown_up_box():
    """A sofa whose box a stray stretches towards the point is not near it for that."""
    sofa_body = _surface(3.0, 0.0, 5.0, 0.9, 0.45, 300)
    stray = np.array([[7.9, 0.4, 0.45]])
    sofa = _object(3, "sofa", np.concatenate([sofa_body, stray]))
    assert describe_place([9.0, 0.4, 0.45], [sofa]) is None
