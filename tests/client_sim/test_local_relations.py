"""Questions about how things stand, answered by the device's local map as the server answers
them: the same points (app.mapping.held), the same `app.answering.ask`, relation bodies only for what a question touches, and what
it keeps counted in the map's memory."""

from __future__ import annotations

import asyncio
import gc
import tracemalloc
from dataclasses import replace

import numpy as np
import pytest
from device_room import NEGATIVES, QUESTIONS, ROOM, TO_Y_UP, VIEWER

from app.answering.label_knowledge import SERVED_LABEL_TEXTS, served_texts
from app.answering.relational import answer
from app.answering.things import MapThing, is_match
from app.config import Knobs
from app.mapping.held import held_points
from app.protocol import UpsertEntry, pack_delta
from app.relations.bodies import Body
from app.relations.grammar import parse
from app.relations.index import ObjectGeometry, RelationIndex
from client_sim.local_bodies import BODY_OVERHEAD_BYTES
from client_sim.local_map import BYTES_PER_MB, LocalMap
from client_sim.querying import LQ, QueryRouter

Y_UP = np.array([0.0, 1.0, 0.0])


@pytest.fixture(scope="module")
def label_embeddings(encoder):
    labels = sorted({label for label, _ in ROOM.values()})
    return dict(zip(labels, encoder.encode(labels), strict=True))


def upserts(room, label_embeddings, version: int = 1) -> list[UpsertEntry]:
    return [
        UpsertEntry(
            id=i,
            version=version,
            label=label,
            embedding=label_embeddings[label],
            points=points.astype(np.float32),
            bbox=(*points.min(axis=0).tolist(), *points.max(axis=0).tolist()),
            n_obs=3,
        )
        for i, (label, points) in room.items()
    ]


def local_map_of(room, label_embeddings, **knobs) -> LocalMap:
    local = LocalMap(dim=384, **knobs)
    local.apply_delta(pack_delta(1, upserts(room, label_embeddings), full=True))
    return local


def server_answer(room, label_embeddings, encoder, text, viewer, up=None, k=5):
    """What the server answers: its relation index over the points a device holds."""
    index = RelationIndex() if up is None else RelationIndex(up)
    index.update(
        {i: ObjectGeometry(label, held_points(points)) for i, (label, points) in room.items()}
    )
    things = [MapThing(i, label, label_embeddings[label]) for i, (label, _) in room.items()]
    return answer(parse(text), things, index, encoder, viewer, k)


def assert_same_answer(sq, lq, text):
    assert sq is not None and lq is not None, text
    assert lq[0].id == sq[0].id, (text, [h.id for h in sq], [h.id for h in lq])
    assert lq[0].relation.kind == sq[0].relation.kind, text
    assert lq[0].relation.anchors == sq[0].relation.anchors, text
    assert lq[0].relation.degree == pytest.approx(sq[0].relation.degree, abs=0.02), text
    assert is_match(lq) == is_match(sq), text


def test_the_local_map_holds_exactly_the_held_points(label_embeddings):
    local = local_map_of(ROOM, label_embeddings)
    for i, (_, points) in ROOM.items():
        np.testing.assert_array_equal(local.get(i)["points"], held_points(points))


def test_at_equal_settings_the_device_keeps_every_point_the_server_sends():
    cap = Knobs().max_object_points_client  # the server's default cap, 200
    device = LocalMap(dim=8)  # the device's default cap
    points = np.random.default_rng(0).uniform(0, 1, (cap, 3)).astype(np.float32)
    entry = UpsertEntry(
        id=1,
        version=1,
        label="box",
        embedding=np.full(8, 8**-0.5, np.float32),
        points=points,
        bbox=(0.0, 0.0, 0.0, 1.0, 1.0, 1.0),
        n_obs=1,
    )
    device.apply_delta(pack_delta(1, [entry], full=True))
    np.testing.assert_array_equal(device.get(1)["points"], held_points(points))


@pytest.mark.parametrize("text", QUESTIONS)
def test_a_relational_question_gets_the_servers_answer(label_embeddings, encoder, text):
    local = local_map_of(ROOM, label_embeddings)
    sq = server_answer(ROOM, label_embeddings, encoder, text, VIEWER)
    lq = local.relational_query(text, encoder, viewer=VIEWER)
    assert_same_answer(sq, lq, text)
    assert is_match(lq) == (text not in NEGATIVES), text


def test_the_copy_that_stands_in_the_relation_comes_first(label_embeddings, encoder):
    local = local_map_of(ROOM, label_embeddings)
    for text, expected, kind, anchor in [
        ("the mug on the shelf", 11, "on", 2),
        ("the bag on the sofa", 31, "on", 4),
        ("the bag under the table", 30, "under", 3),
        ("the lamp on the desk", 40, "on", 1),
    ]:
        best = local.relational_query(text, encoder)[0]
        assert (best.id, best.relation.kind) == (expected, kind), text
        assert best.relation.anchors == [(anchor, ROOM[anchor][0])], text


def test_a_y_up_map_answers_as_the_z_up_one(label_embeddings, encoder):
    y_up_room = {i: (label, points @ TO_Y_UP.T) for i, (label, points) in ROOM.items()}
    z_up = local_map_of(ROOM, label_embeddings)
    y_up = local_map_of(y_up_room, label_embeddings)
    for text in ["the mug on the desk", "the chair left of the sofa", "the highest mug"]:
        expected = z_up.relational_query(text, encoder, viewer=VIEWER)
        got = y_up.relational_query(text, encoder, viewer=TO_Y_UP @ VIEWER, up=Y_UP)
        assert [(h.id, h.relation.anchors) for h in got] == [
            (h.id, h.relation.anchors) for h in expected
        ], text
        sq = server_answer(y_up_room, label_embeddings, encoder, text, TO_Y_UP @ VIEWER, Y_UP)
        assert_same_answer(sq, got, text)


def test_plain_questions_and_missing_anchors_are_left_to_the_plain_query(label_embeddings, encoder):
    local = local_map_of(ROOM, label_embeddings)
    assert local.relational_query("where are my keys", encoder) is None
    assert local.relational_query("keys on a ring", encoder) is None
    assert local.relational_query("the lamp closest to me", encoder) is None  # nobody stands
    local.set_user_position(VIEWER)  # the device's own position places the asker
    assert local.relational_query("the lamp closest to me", encoder)[0].id == (
        local.relational_query("the lamp closest to me", encoder, viewer=VIEWER)[0].id
    )
    assert LocalMap(dim=384).relational_query("the mug on the desk", encoder) is None


def tiled(rooms: int) -> dict[int, tuple[str, np.ndarray]]:
    """`rooms` copies of ROOM side by side, 10 m apart; ids 100 * room + the ROOM id."""
    return {
        100 * r + i: (label, points + [10.0 * r, 0.0, 0.0])
        for r in range(rooms)
        for i, (label, points) in ROOM.items()
    }


def test_a_question_builds_bodies_only_for_what_it_touches(label_embeddings, encoder):
    floor = tiled(40)  # 600 objects, 40 copies of every mug, desk, lamp...
    local = local_map_of(floor, label_embeddings)
    local.set_user_position(VIEWER + [150.0, 0.0, 0.0])  # in room 15
    for text, expected in [("the mug on the desk", 10), ("the lamp closest to me", 1540)]:
        before = len(local._bodies)
        best = local.relational_query(text, encoder)[0]
        assert best.id == expected, text
        assert len(local._bodies) - before < 40, text  # anchors, their reach, the extremes


def test_kept_bodies_are_counted_and_dropped_when_their_object_changes_or_goes(
    label_embeddings, encoder
):
    local = local_map_of(ROOM, label_embeddings)
    empty = local.memory_bytes()
    local.relational_query("the mug on the desk", encoder)
    kept = local._bodies.sizes()
    assert 10 in kept and 1 in kept
    assert local.memory_bytes() > empty + sum(kept.values()) - 1
    moved = upserts({10: ROOM[10]}, label_embeddings, version=2)
    local.apply_delta(pack_delta(2, moved, removed=[1]))
    assert 10 not in local._bodies and 1 not in local._bodies
    assert local.memory_bytes() < empty + sum(kept.values())


def test_kept_bodies_stay_within_their_bound_and_the_budget(label_embeddings, encoder):
    floor = tiled(20)
    small_cache = local_map_of(floor, label_embeddings, relation_cache_mb=0.02)
    small_cache.set_user_position(VIEWER)
    for text in ["the biggest table", "the lamp closest to me", "the mug on the desk"]:
        small_cache.relational_query(text, encoder)
        assert small_cache._bodies.nbytes <= 0.02 * BYTES_PER_MB
    tight = local_map_of(floor, label_embeddings)
    budget_mb = (tight.memory_bytes() + 20_000) / BYTES_PER_MB
    tight.set_policy(budget_mb=budget_mb)
    assert len(tight) == len(floor)  # nothing evicted: the map fits
    tight.relational_query("the biggest table", encoder)
    assert tight.memory_bytes() <= budget_mb * BYTES_PER_MB
    assert tight.relational_query("the mug on the desk", encoder)[0].id == 10
    # a tighter budget drops the kept bodies before any object
    tight.set_policy(budget_mb=(tight.memory_bytes() - tight._bodies.nbytes) / BYTES_PER_MB)
    assert len(tight) == len(floor) and tight._bodies.nbytes == 0


def test_a_kept_body_costs_what_memory_bytes_counts():
    rng = np.random.default_rng(0)
    points = [held_points(rng.uniform(0, 1, (n, 3))) for n in [200] * 300 + [60] * 300]
    gc.collect()
    tracemalloc.start()
    try:
        start = tracemalloc.get_traced_memory()[0]
        bodies = [Body(p) for p in points]
        for body in bodies:
            _ = body.footprint.area
        gc.collect()
        traced = tracemalloc.get_traced_memory()[0] - start
    finally:
        tracemalloc.stop()
    counted = sum(b.local.nbytes + BODY_OVERHEAD_BYTES for b in bodies)
    assert 0.8 <= traced / counted <= 1.1


def test_the_router_answers_relational_questions_offline_with_their_relation(
    label_embeddings, encoder
):
    local = local_map_of(ROOM, label_embeddings)
    local.set_user_position(VIEWER)

    async def ask():
        link_down = QueryRouter(
            "http://127.0.0.1:9", "sid", None, local, encoder, rtt_ms=lambda: np.inf
        )
        async with link_down as router:
            return [
                await router.query(text, k=3)
                for text in ("the mug on the desk", "the mug under the sofa", "where is the sofa")
            ]

    found, nothing, plain = asyncio.run(ask())
    assert found.mode == LQ and found.match and found.results[0]["id"] == 10
    assert found.results[0]["relation"] == {
        "kind": "on",
        "anchors": [{"id": 1, "label": "desk"}],
        "degree": pytest.approx(1.0, abs=0.05),
    }
    assert set(found.results[0]) >= {"id", "label", "score", "relevance", "bbox", "centroid"}
    assert not nothing.match and nothing.results[0]["label"] == "mug"
    assert plain.results[0]["label"] == "sofa" and plain.results[0]["relation"] is None


def test_with_the_label_texts_the_server_sends_the_device_answers_as_the_server(encoder):
    # a label outside the shipped background: the server sends its WordNet texts with each
    # upsert, and the device rates the question's phrases against them as the server does
    room = {i: ("rucksack" if label == "bag" else label, p) for i, (label, p) in ROOM.items()}
    labels = sorted({label for label, _ in room.values()})
    embeddings = dict(zip(labels, encoder.encode(labels), strict=True))
    entries = [
        replace(entry, label_texts=served_texts(entry.label)) for entry in upserts(room, embeddings)
    ]
    assert any(entry.label_texts for entry in entries)
    local = LocalMap(dim=384)
    local.apply_delta(pack_delta(1, entries, full=True))
    assert local.label_texts()["rucksack"] == served_texts("rucksack")
    index = RelationIndex()
    index.update({i: ObjectGeometry(label, held_points(p)) for i, (label, p) in room.items()})
    things = [MapThing(i, label, embeddings[label]) for i, (label, _) in room.items()]
    for text in ["the rucksack on the sofa", "the backpack under the table", "the bag on the sofa"]:
        sq = answer(parse(text), things, index, encoder, VIEWER, 5, SERVED_LABEL_TEXTS)
        lq = local.relational_query(text, encoder, viewer=VIEWER)
        assert_same_answer(sq, lq, text)
        assert [h.relevance for h in lq] == [h.relevance for h in sq], text
