"""`RelationIndex.sync`: the index brought up to a map's objects by their versions, each
object's geometry computed only when its version is new to the index."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from relation_scene import block, table

from app.relations.index import ObjectGeometry, RelationIndex

Z_UP = np.array([0.0, 0.0, 1.0])
Y_UP = np.array([0.0, 1.0, 0.0])


@dataclass
class Thing:
    id: int
    label: str
    points: np.ndarray


class Geometry:
    """`sync`'s geometry function, counting whom it was asked for."""

    def __init__(self):
        self.asked: list[int] = []

    def __call__(self, thing: Thing) -> ObjectGeometry:
        self.asked.append(thing.id)
        return ObjectGeometry(thing.label, thing.points)


def room() -> dict[int, Thing]:
    return {
        1: Thing(1, "table", table(0.0, 0.0)),
        2: Thing(2, "mug", block(0.0, 0.0, 0.75, 0.08, 0.08, 0.1, seed=2)),
        3: Thing(3, "bag", block(2.0, 0.0, 0.0, 0.3, 0.2, 0.4, seed=3)),
    }


def test_a_first_sync_takes_every_object():
    things, geometry = room(), Geometry()
    index = RelationIndex()
    assert index.sync([(t, 1) for t in things.values()], Z_UP, geometry) == 3
    assert sorted(geometry.asked) == [1, 2, 3] and sorted(index.ids()) == [1, 2, 3]
    assert index.degree("on", 2, 1) > 0.9


def test_objects_of_a_version_held_cost_no_geometry():
    things, geometry = room(), Geometry()
    index = RelationIndex()
    index.sync([(t, 1) for t in things.values()], Z_UP, geometry)
    geometry.asked.clear()
    assert index.sync([(t, 1) for t in things.values()], Z_UP, geometry) == 0
    assert geometry.asked == []


def test_a_new_version_is_measured_again_and_a_missing_object_goes():
    things, geometry = room(), Geometry()
    index = RelationIndex()
    index.sync([(t, 1) for t in things.values()], Z_UP, geometry)
    geometry.asked.clear()
    things[2].points = block(2.0, 0.0, 0.4, 0.08, 0.08, 0.1, seed=2)  # onto the bag
    del things[1]
    objects = [(things[2], 2), (things[3], 1)]
    assert index.sync(objects, Z_UP, geometry) == 2  # one changed, one gone
    assert geometry.asked == [2]
    assert sorted(index.ids()) == [2, 3] and 1 not in index
    assert index.degree("on", 2, 3) > 0.9
    assert index.degree("on", 2, 1) == 0.0


def test_a_new_up_axis_starts_the_index_afresh():
    things, geometry = room(), Geometry()
    index = RelationIndex()
    index.sync([(t, 1) for t in things.values()], Z_UP, geometry)
    geometry.asked.clear()
    assert index.sync([(t, 1) for t in things.values()], Y_UP, geometry) == 3
    assert sorted(geometry.asked) == [1, 2, 3]
    assert np.array_equal(index.up, Y_UP)
