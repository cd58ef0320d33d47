"""Relations measured when asked (`OnDemandRelations`, the device's local map) are the ones the
server's index keeps (`RelationIndex`), whatever the scene, the up axis or how much wider than
its points each prefilter box is (LQ = SQ: docs/evaluation.md "Relations")."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from relation_scene import TO_Y_UP, block, table

from app.relations.between import between_degrees
from app.relations.bodies import Body
from app.relations.index import ObjectGeometry, RelationIndex
from app.relations.on_demand import OnDemandRelations
from app.relations.pairwise import PAIRWISE_KINDS
from app.relations.viewpoint import viewpoint_degrees

Z_UP = np.array([0.0, 0.0, 1.0])
Y_UP = np.array([0.0, 1.0, 0.0])


@st.composite
def rooms(draw) -> dict[int, np.ndarray]:
    """A few tables with things on, under and beside them, ids not in order."""
    seed = draw(st.integers(0, 10_000))
    rng = np.random.default_rng(seed)
    things: dict[int, np.ndarray] = {}
    for t in range(draw(st.integers(1, 3))):
        x, y = 2.5 * t, rng.uniform(0, 1)
        things[100 - 10 * t] = table(x, y, 1.2, 0.8, 0.75, seed=seed + t, count=120)
        things[101 - 10 * t] = block(x + rng.uniform(0, 1), y + 0.2, 0.75, 0.1, 0.1, 0.1, seed)
        things[102 - 10 * t] = block(x + 0.3, y + 0.2, 0.0, 0.4, 0.3, 0.3, seed + 1)  # under
        things[103 - 10 * t] = block(x + 1.3, y + rng.uniform(0, 0.5), 0.0, 0.4, 0.4, 0.9, seed)
    return things


def both(things: dict[int, np.ndarray], up=Z_UP, margin_m: float = 0.0):
    index = RelationIndex(up)
    index.update({i: ObjectGeometry("thing", p) for i, p in things.items()})
    ids = np.array(list(things), np.int64)
    bodies = {i: Body(p, up) for i, p in things.items()}
    lo = np.array([p.min(axis=0) for p in things.values()]) - margin_m
    hi = np.array([p.max(axis=0) for p in things.values()]) + margin_m
    on_demand = OnDemandRelations(ids, lo, hi, lambda wanted: [bodies[i] for i in wanted], up=up)
    return index, on_demand, ids


@settings(max_examples=20, deadline=None)
@given(things=rooms(), margin_m=st.sampled_from([0.0, 0.001, 0.3]), y_up=st.booleans())
def test_measured_when_asked_equals_kept_up_to_date(things, margin_m, y_up):
    up = Y_UP if y_up else Z_UP
    if y_up:
        things = {i: p @ TO_Y_UP.T for i, p in things.items()}
    index, on_demand, ids = both(things, up, margin_m)
    for kind in PAIRWISE_KINDS:
        for anchor in ids.tolist():
            np.testing.assert_array_equal(
                on_demand.degrees(kind, anchor, ids), index.degrees(kind, anchor, ids), kind
            )
    np.testing.assert_array_equal(on_demand.centroids(ids), index.centroids(ids))


def test_kept_degrees_are_the_pairwise_functions_and_many_at_once_the_single_ones():
    things = {
        1: table(0.0, 0.0, 1.2, 0.8, 0.75, seed=1, count=120),
        2: block(0.4, 0.3, 0.75, 0.1, 0.1, 0.1, seed=2),
        3: block(1.5, 0.2, 0.0, 0.4, 0.4, 0.9, seed=3),
        4: block(-1.0, 0.2, 0.0, 0.3, 0.3, 0.3, seed=4),
    }
    index, _, ids = both(things)
    assert index.degrees("on", 1, ids).tolist() == [0.0, 1.0, 0.0, 0.0]
    assert index.degrees("near", 1, [1, 99]).tolist() == [0.0, 0.0]  # itself, unknown
    centroids = index.centroids(ids)
    viewer = np.array([0.5, -3.0, 1.6])
    many = viewpoint_degrees("left_of", centroids, centroids[0], viewer)
    assert many[2] == 0.0 and many[3] == 1.0  # seen from the south: 3 is right, 4 left
    assert between_degrees(centroids, centroids[3], centroids[2])[0] > 0.5  # the table
