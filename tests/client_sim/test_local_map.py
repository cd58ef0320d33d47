"""The device's sparse local map: deltas in, local queries out, within a memory budget."""

from __future__ import annotations

import asyncio
import gc
import json
import math
import sys
import tracemalloc
import zlib
from collections import Counter
from collections.abc import Sequence

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.codecs import float16_vector_to_bytes
from app.mapping.deltas import Delta, DeltaLog
from app.mapping.held import POINT_LEVELS, dequantise_points, quantise_points
from app.mapping.object import MapObject
from app.mapping.publish import delta_message
from app.protocol import ChangeEntry, UpsertEntry, pack_delta
from client_sim.local_map import BYTES_PER_MB, DeltaError, LocalMap
from client_sim.local_scan import exact_scores
from client_sim.querying import QueryAnswer, QueryRouter
from world.categories import CATEGORIES

DIM = 32  # small embeddings keep the tests fast; the map is dimension-agnostic
FEW = settings(max_examples=40, deadline=None)

# Tolerances of the 8-bit storage (client_sim/local_map.py):
# - a point is within step / 2 per axis of the received float16 one, step = box side / 255
#   (3.9 mm for a 2 m object), plus float32 rounding of `lo + offset * step`;
# - a score is an exact cosine of the int8 direction, within 0.01 of the float32 cosine.
SCORE_TOLERANCE = 0.01


def assert_points_within_step(held: dict, sent: np.ndarray) -> None:
    """`held` (a `get()` result) has the points `sent` (float [N, 3]), row for row, each
    within half a quantisation step per axis."""
    sent32 = np.asarray(sent, np.float32)
    step = np.asarray(held["points_step"], np.float32)
    assert held["points"].shape == sent32.shape and held["points"].dtype == np.float32
    assert np.all(np.abs(held["points"] - sent32) <= step / 2 + 1e-6)


def unit_vector(seed: int, dim: int = DIM) -> np.ndarray:
    """A random unit float64 [dim], the same for the same seed."""
    vector = np.random.default_rng(seed).standard_normal(dim)
    return vector / np.linalg.norm(vector)


def upsert(
    oid: int,
    version: int = 1,
    label: str = "chair",
    center_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
    n_points: int = 20,
    embedding: np.ndarray | None = None,
    last_seen_t: float | None = None,
) -> UpsertEntry:
    """An `upserts[]` entry: n_points points (float16, as sent) in a 0.4 m cube around
    center_m; last_seen_t None: as an older server sends it (no living-map fields)."""
    rng = np.random.default_rng(oid * 1000 + version)
    points = np.asarray(center_m) + rng.uniform(-0.2, 0.2, (n_points, 3))
    bbox = [*points.min(axis=0), *points.max(axis=0)] if n_points else [*center_m, *center_m]
    return UpsertEntry(
        id=oid,
        version=version,
        label=label,
        embedding=unit_vector(oid) if embedding is None else embedding,
        points=points.reshape(-1, 3).astype(np.float16),
        bbox=tuple(float(v) for v in bbox),
        n_obs=3,
        first_seen_t=None if last_seen_t is None else 0.0,
        last_seen_t=last_seen_t,
    )


def delta(
    seq: int, upserts: Sequence[UpsertEntry] = (), removed: Sequence[int] = (), full: bool = False
) -> dict:
    """A v1 `delta` message as msgpack would unpack it."""
    return pack_delta(seq, upserts, removed, full)


def local_map(**kwargs) -> LocalMap:
    return LocalMap(dim=DIM, **kwargs)


def state(m: LocalMap) -> tuple:
    """Everything observable about a map, to check that a refused delta changed nothing."""
    objects = [m.get(oid) for oid in m.ids()]
    return (
        m.seq,
        m.snapshot(),
        m.memory_bytes(),
        m.evicted,
        [(o["bbox"], o["centroid"], o["points"].tobytes(), o["n_obs"]) for o in objects],
        [hit.id for hit in m.query_embedding(unit_vector(3), k=10)],
    )


def bytes_of_objects(count: int, n_points: int = 20) -> int:
    """memory_bytes of a map holding exactly `count` objects of `n_points` points."""
    m = local_map()
    m.apply_delta(delta(1, [upsert(i, n_points=n_points) for i in range(count)]))
    return m.memory_bytes()


def budget_mb_for(count: int, n_points: int = 20) -> float:
    """A budget that holds `count` such objects but not one more."""
    one_more = bytes_of_objects(count + 1, n_points) - bytes_of_objects(count, n_points)
    return (bytes_of_objects(count, n_points) + one_more // 2) / BYTES_PER_MB


# --- applying deltas --------------------------------------------------------------------------


def test_upserts_and_removals_give_the_servers_snapshot():
    m = local_map()
    m.apply_delta(delta(1, [upsert(1, label="sofa"), upsert(2, label="mug"), upsert(3)]))
    m.apply_delta(delta(2, [upsert(2, version=2, label="cup"), upsert(4, label="keys")], [1]))

    assert m.snapshot() == {2: (2, "cup"), 3: (1, "chair"), 4: (1, "keys")}
    assert m.seq == 2
    assert len(m) == 3 and m.ids() == [2, 3, 4]
    assert 2 in m and 1 not in m


def test_an_upsert_older_than_the_held_version_is_ignored():
    m = local_map()
    m.apply_delta(delta(1, [upsert(7, version=5, label="lamp")]))
    m.apply_delta(delta(2, [upsert(7, version=4, label="stale lamp")]))

    assert m.snapshot() == {7: (5, "lamp")}
    assert m.seq == 2


def test_a_newer_version_replaces_geometry_and_embedding():
    m = local_map()
    m.apply_delta(delta(1, [upsert(7, center_m=(0, 0, 0), embedding=unit_vector(100))]))
    m.apply_delta(delta(2, [upsert(7, version=2, center_m=(5, 0, 0), embedding=unit_vector(200))]))

    assert m.get(7)["centroid"] == pytest.approx([5, 0, 0], abs=0.1)
    assert m.query_embedding(unit_vector(200), k=1)[0].score == pytest.approx(1.0, abs=1e-3)


def test_held_ids_are_found_by_id_after_rows_move():
    m = local_map()
    m.apply_delta(delta(1, [upsert(oid, label=f"l{oid}") for oid in (50, 7, 30, 9, 41)]))
    m.apply_delta(delta(2, [upsert(3, label="l3")], removed=[7]))  # row 1 gets another id

    assert m.ids() == [3, 9, 30, 41, 50]
    assert [m.get(oid)["label"] for oid in m.ids()] == ["l3", "l9", "l30", "l41", "l50"]
    assert 9 in m and 7 not in m and "9" not in m
    with pytest.raises(KeyError):
        m.get(7)


def test_an_out_of_order_seq_raises_and_leaves_the_map_unchanged():
    m = local_map()
    m.apply_delta(delta(5, [upsert(1), upsert(2)]))
    before = state(m)

    with pytest.raises(DeltaError, match="seq"):
        m.apply_delta(delta(4, [upsert(3)], [1]))

    assert state(m) == before


def test_a_redelivered_delta_with_the_same_seq_is_applied_idempotently():
    m = local_map()
    message = delta(3, [upsert(1), upsert(2)], [9])
    m.apply_delta(message)
    before = state(m)

    m.apply_delta(message)

    assert state(m)[:3] == before[:3]


def _malformed(mutate) -> dict:
    """A delta with one valid upsert, then one broken by `mutate(message, second_upsert)`."""
    message = delta(10, [upsert(20), upsert(21)], [1])
    mutate(message, message["upserts"][1])
    return message


def _set(key, value):
    return lambda message, item: item.__setitem__(key, value)


def _set_top(key, value):
    return lambda message, item: message.__setitem__(key, value)


def _drop(key):
    return lambda message, item: item.pop(key)


MALFORMED = {
    "unknown type": _set_top("type", "frame"),
    "missing type": lambda message, item: message.pop("type"),
    "missing seq": lambda message, item: message.pop("seq"),
    "seq not an int": _set_top("seq", "10"),
    "seq a bool": _set_top("seq", True),
    "negative seq": _set_top("seq", -1),
    "full not a bool": _set_top("full", 0),
    "missing upserts": lambda message, item: message.pop("upserts"),
    "upserts not a list": _set_top("upserts", {"id": 1}),
    "upsert not a map": lambda message, item: message["upserts"].append([1, 2]),
    "removed not a list": _set_top("removed", 3),
    "removed holds a string": _set_top("removed", ["3"]),
    "missing id": _drop("id"),
    "missing embedding": _drop("embedding"),
    "missing points": _drop("points"),
    "missing bbox": _drop("bbox"),
    "missing n_obs": _drop("n_obs"),
    "id a float": _set("id", 21.0),
    "negative version": _set("version", -2),
    "label not a string": _set("label", 5),
    "embedding too short": _set("embedding", b"\x00" * (2 * DIM - 2)),
    "embedding of another dim": _set("embedding", float16_vector_to_bytes(unit_vector(1, 2 * DIM))),
    "embedding not bytes": _set("embedding", "abc"),
    "NaN embedding": _set("embedding", np.full(DIM, np.nan, "<f2").tobytes()),
    "points not a multiple of 6 bytes": _set("points", b"\x00" * 13),
    "inf in points": _set("points", np.array([[0, np.inf, 0]], "<f2").tobytes()),
    "bbox of 5 numbers": _set("bbox", [0.0, 0.0, 0.0, 1.0, 1.0]),
    "NaN in bbox": _set("bbox", [0.0, float("nan"), 0.0, 1.0, 1.0, 1.0]),
    "bbox corners swapped": _set("bbox", [1.0, 1.0, 1.0, 0.0, 0.0, 0.0]),
    "bbox not a list": _set("bbox", "0 0 0 1 1 1"),
    "duplicate id": _set("id", 20),
    "id both upserted and removed": _set_top("removed", [21]),
}


@pytest.mark.parametrize("mutate", MALFORMED.values(), ids=MALFORMED.keys())
def test_a_malformed_delta_raises_and_leaves_the_map_unchanged(mutate):
    m = local_map()
    m.apply_delta(delta(5, [upsert(1), upsert(2, label="mug")]))
    before = state(m)

    with pytest.raises(DeltaError):
        m.apply_delta(_malformed(mutate))

    assert state(m) == before


def test_a_message_that_is_not_a_map_raises_delta_error():
    with pytest.raises(DeltaError):
        local_map().apply_delta([("type", "delta")])  # type: ignore[arg-type]


def test_a_full_snapshot_replaces_the_whole_map():
    m = local_map()
    m.apply_delta(delta(1, [upsert(1), upsert(2), upsert(3)]))
    m.apply_delta(delta(9, [upsert(2, version=3, label="mug"), upsert(8)], full=True))

    assert m.snapshot() == {2: (3, "mug"), 8: (1, "chair")}
    assert m.seq == 9


def test_a_full_snapshot_is_accepted_even_with_an_older_seq():
    # A full snapshot is authoritative (e.g. the server restarted and its seq went back).
    m = local_map()
    m.apply_delta(delta(50, [upsert(1)]))
    m.apply_delta(delta(3, [upsert(2)], full=True))

    assert m.snapshot() == {2: (1, "chair")}
    assert m.seq == 3


def test_removing_an_unknown_id_is_not_an_error():
    m = local_map()
    m.apply_delta(delta(1, [upsert(1)]))
    m.apply_delta(delta(2, removed=[404, 1]))

    assert m.snapshot() == {}
    assert m.seq == 2


def test_a_server_built_delta_applies_after_a_msgpack_round_trip():
    rng = np.random.default_rng(0)
    objects = {}
    for oid, label in ((3, "sofa"), (4, "keys")):
        obj = MapObject(id=oid, version=2, n_obs=5, confirmed=True, resolution_m=0.02)
        obj.set_points(rng.uniform(0, 2, (500, 3)).astype(np.float32), 0.02)
        obj.embedding_sum = unit_vector(oid).astype(np.float32) * 5
        obj.label_counts = Counter({label: 5})
        objects[oid] = obj
    message = delta_message(Delta(seq=7, full=False, upserts=[3, 4], removed=[1]), objects, 200)
    wire = msgpack.unpackb(msgpack.packb(message, use_bin_type=True), raw=False)

    m = local_map(max_points_per_object=200)
    m.apply_delta(wire)

    assert m.snapshot() == {3: (2, "sofa"), 4: (2, "keys")}
    assert len(m.get(4)["points"]) <= 200
    assert m.get(4)["bbox"] == pytest.approx(list(objects[4].bbox), abs=1e-3)
    assert m.query_embedding(unit_vector(4), k=1)[0].id == 4


# --- the living map: moves, removals, last seen ------------------------------------------------


def test_a_moved_object_keeps_its_id_and_only_its_new_points():
    m = local_map()
    m.apply_delta(delta(1, [upsert(5, label="mug", center_m=(0, 0, 0)), upsert(6, label="sofa")]))
    moved = upsert(5, version=2, label="mug", center_m=(3, 1, 0), last_seen_t=612.4)

    m.apply_delta(delta(2, [moved]))

    held = m.get(5)
    assert m.ids() == [5, 6] and held["version"] == 2
    assert_points_within_step(held, moved.points)  # the old place's points are gone
    assert held["bbox"] == pytest.approx(list(moved.bbox), abs=1e-6)
    assert held["centroid"] == pytest.approx([3, 1, 0], abs=0.1)
    assert m.query_embedding(unit_vector(5), k=1)[0].centroid == held["centroid"]


def test_a_removed_object_leaves_the_map_and_the_answers():
    m = local_map()
    m.apply_delta(delta(1, [upsert(5, label="laptop", last_seen_t=10.0), upsert(6)]))

    m.apply_delta(delta(2, removed=[5]))

    assert 5 not in m and m.ids() == [6]
    assert [hit.id for hit in m.query_embedding(unit_vector(5), k=5)] == [6]


def test_last_seen_t_is_kept_per_object_at_full_precision_and_follows_each_upsert():
    first_s, later_s = 12.123456789, 612.987654321  # not float32 numbers: float64 is kept
    m = local_map()
    m.apply_delta(delta(1, [upsert(1, last_seen_t=first_s), upsert(2, last_seen_t=3.5)]))
    assert m.get(1)["last_seen_t"] == first_s

    m.apply_delta(delta(2, [upsert(1, version=2, last_seen_t=later_s)]))

    assert m.get(1)["last_seen_t"] == later_s and m.get(2)["last_seen_t"] == 3.5
    hits = {hit.id: hit for hit in m.query_embedding(unit_vector(1), k=2)}
    assert (hits[1].last_seen_t, hits[2].last_seen_t) == (later_s, 3.5)


def test_a_stale_upsert_does_not_move_last_seen_t():
    m = local_map()
    m.apply_delta(delta(1, [upsert(1, version=3, last_seen_t=50.0)]))

    m.apply_delta(delta(2, [upsert(1, version=2, last_seen_t=40.0)]))

    assert m.get(1)["last_seen_t"] == 50.0


def test_last_seen_t_follows_its_object_when_rows_move_and_columns_grow():
    m = local_map()
    m.apply_delta(delta(1, [upsert(i, last_seen_t=100.0 + i) for i in range(40)]))
    m.apply_delta(delta(2, [upsert(i, last_seen_t=100.0 + i) for i in range(40, 400)], [0, 7]))
    m.apply_delta(delta(3, removed=list(range(1, 300))))  # compacted in one pass

    assert m.ids() == list(range(300, 400))
    assert all(m.get(oid)["last_seen_t"] == 100.0 + oid for oid in m.ids())


def test_a_delta_from_a_server_without_the_living_map_fields_applies():
    m = local_map()
    old_server = delta(1, [upsert(1), upsert(2)])
    assert "last_seen_t" not in old_server["upserts"][0] and "changes" not in old_server

    m.apply_delta(old_server)

    assert m.snapshot() == {1: (1, "chair"), 2: (1, "chair")}
    assert np.isnan(m._store.columns["last_seen_t"][: len(m)]).all()  # stored as NaN ...
    assert m.get(1)["last_seen_t"] is None  # ... answered as None
    assert m.query_embedding(unit_vector(1), k=1)[0].last_seen_t is None


def test_the_changes_of_a_delta_are_accepted_and_change_nothing_by_themselves():
    m = local_map()
    m.apply_delta(delta(1, [upsert(1, last_seen_t=1.0)]))
    message = delta(2)
    message["changes"] = [ChangeEntry(1, "removed", 5.0, "chair", from_xyz=(1, 2, 0)).pack()]

    m.apply_delta(message)

    assert m.seq == 2 and m.ids() == [1]  # what leaves is what `removed` lists


def test_after_an_outage_the_resumed_delta_catches_up_on_moves_and_removals():
    """Two subscribers of one server: one applies every delta, the other misses those of an
    outage (a move, a removal, an addition) and resumes from its seq with what the server
    sends then: the delta since that seq, coalesced (app.mapping.publish), with its changes."""
    rng = np.random.default_rng(4)
    log, objects = DeltaLog(), {}

    def place(oid: int, label: str, center_m: tuple, t: float) -> list[int]:
        obj = objects.get(oid) or MapObject(id=oid, confirmed=True, n_obs=1, first_seen_t=t)
        obj.version += 1
        obj.last_seen_t = t
        obj.set_points(np.asarray(center_m) + rng.uniform(-0.1, 0.1, (300, 3)), 0.02)
        obj.embedding_sum = unit_vector(oid).astype(np.float32)
        obj.label_counts = Counter({label: 1})
        objects[oid] = obj
        return [oid]

    def commit(upserted: Sequence[int] = (), removed: Sequence[int] = ()) -> dict:
        for oid in removed:
            objects.pop(oid)
        seq = log.commit(upserted, removed)
        return delta_message(log.since(seq - 1), objects, 200)

    always, resumed = local_map(), local_map()
    before = [
        commit(place(1, "mug", (0, 0, 0), 1.0) + place(2, "laptop", (1, 0, 0), 1.0)),
        commit(place(3, "backpack", (2, 0, 0), 2.0)),
    ]
    during = [
        commit(place(1, "mug", (4, 2, 0), 600.2)),  # moved: same id, new place
        commit(removed=[2]),  # taken away
        commit(place(4, "box", (2, 1, 0), 601.0)),  # added
        commit(place(3, "backpack", (2, 0, 0), 601.4)),  # seen again where it was
    ]
    for message in before:
        always.apply_delta(message)
        resumed.apply_delta(message)
    for message in during:
        always.apply_delta(message)

    catch_up = delta_message(log.since(resumed.seq), objects, 200)
    catch_up["changes"] = [
        ChangeEntry(1, "moved", 600.2, "mug", (0, 0, 0), (4, 2, 0)).pack(),
        ChangeEntry(2, "removed", 600.6, "laptop", from_xyz=(1, 0, 0)).pack(),
        ChangeEntry(4, "added", 601.0, "box", to_xyz=(2, 1, 0)).pack(),
    ]
    assert not catch_up["full"] and catch_up["removed"] == [2]
    resumed.apply_delta(msgpack.unpackb(msgpack.packb(catch_up, use_bin_type=True), raw=False))

    assert resumed.seq == always.seq and resumed.snapshot() == always.snapshot()
    assert resumed.ids() == [1, 3, 4]
    for oid in resumed.ids():
        mine, theirs = resumed.get(oid), always.get(oid)
        assert np.array_equal(mine["points"], theirs["points"])
        assert mine["last_seen_t"] == theirs["last_seen_t"] == objects[oid].last_seen_t
    assert resumed.get(1)["centroid"] == pytest.approx([4, 2, 0], abs=0.1)


# --- queries ----------------------------------------------------------------------------------


def test_a_query_returns_the_matching_object_first_and_scores_best_first():
    m = local_map()
    m.apply_delta(delta(1, [upsert(i, label=f"thing {i}") for i in range(50)]))
    target = unit_vector(17)

    hits = m.query_embedding(target, k=5)

    assert [hit.id for hit in hits][0] == 17 and hits[0].label == "thing 17"
    assert hits[0].score == pytest.approx(1.0, abs=1e-3)
    assert [hit.score for hit in hits] == sorted((hit.score for hit in hits), reverse=True)
    assert len(hits) == 5
    assert hits[0].centroid == pytest.approx(m.get(17)["centroid"])


def test_a_query_scores_are_cosines_whatever_the_query_length():
    m = local_map()
    m.apply_delta(delta(1, [upsert(1, embedding=unit_vector(1)), upsert(2)]))

    [hit] = m.query_embedding(3.5 * unit_vector(1), k=1)

    assert hit.id == 1 and hit.score == pytest.approx(1.0, abs=1e-3)


def test_a_query_for_more_objects_than_held_returns_all_held():
    m = local_map()
    m.apply_delta(delta(1, [upsert(1), upsert(2)]))

    assert len(m.query_embedding(unit_vector(1), k=10)) == 2
    assert local_map().query_embedding(unit_vector(1)) == []


def test_a_query_of_the_wrong_dimension_is_refused():
    with pytest.raises(ValueError):
        local_map().query_embedding(np.ones(DIM + 1))


def test_8_bit_embeddings_rank_the_paraphrase_queries_as_float32_does(encoder):
    """One object per category of the synthetic world, embedded from its name (float16 on the
    wire, int8 in the map); every paraphrase query's top-1 equals the float32 ranking's, and
    the scores are within SCORE_TOLERANCE of the float32 cosines."""
    names = sorted(CATEGORIES)
    embeddings = np.asarray(encoder.encode(names), np.float32)
    m = LocalMap(dim=encoder.dim)
    m.apply_delta(
        delta(1, [upsert(i, label=name, embedding=embeddings[i]) for i, name in enumerate(names)])
    )
    queries = [text for name in names for text in CATEGORIES[name].paraphrases]
    unit = embeddings / np.linalg.norm(embeddings, axis=1, keepdims=True)

    for text in queries:
        query = np.asarray(encoder.encode_query(text), np.float32)
        query /= np.linalg.norm(query)
        float32_scores = unit @ query
        hits = m.query_embedding(query, k=3)
        assert hits[0].id == int(np.argmax(float32_scores)), text
        for hit in hits:
            assert hit.score == pytest.approx(float32_scores[hit.id], abs=SCORE_TOLERANCE)
    assert len(queries) > 100


def test_a_query_ranks_exactly_by_the_stored_cosines_with_ties_broken_by_id():
    m = LocalMap(dim=384)
    rng = np.random.default_rng(2)
    vectors = rng.standard_normal((300, 384))
    vectors[100:140] = vectors[7]  # 41 objects share one embedding (one label's text)
    m.apply_delta(delta(1, [upsert(i, embedding=vectors[i]) for i in range(300)]))
    query = vectors[7] + 0.3 * rng.standard_normal(384)

    hits = m.query_embedding(query, k=12)

    rows = np.array([m._store.row(oid) for oid in range(300)])
    unit = (query / np.linalg.norm(query)).astype(np.float32)
    exact = exact_scores(m._store.columns["embedding"], m._store.columns["scale"], rows, unit)
    expected = sorted(range(300), key=lambda oid: (-exact[oid], oid))[:12]
    assert [hit.id for hit in hits] == expected == [7, *range(100, 111)]


def test_a_dimension_the_int8_kernel_does_not_take_is_scored_exactly():
    m = LocalMap(dim=5)
    vectors = np.random.default_rng(3).standard_normal((50, 5))
    m.apply_delta(delta(1, [upsert(i, embedding=vectors[i]) for i in range(50)]))
    unit = vectors / np.linalg.norm(vectors, axis=1, keepdims=True)

    hits = m.query_embedding(vectors[9], k=4)

    assert hits[0].id == 9 and hits[0].score == pytest.approx(1.0, abs=1e-3)
    assert [hit.id for hit in hits] == list(np.argsort(-(unit @ unit[9]))[:4])


def test_a_text_query_finds_the_object_with_that_label(encoder):
    labels = ["sofa", "keys", "coffee mug", "floor lamp", "bookshelf"]
    embeddings = encoder.encode(labels)
    m = LocalMap(dim=encoder.dim)
    m.apply_delta(
        delta(
            1, [upsert(i, label=label, embedding=embeddings[i]) for i, label in enumerate(labels)]
        )
    )

    hits = m.query_embedding(encoder.encode_query("where did I leave my keys?"), k=3)

    assert hits[0].label == "keys"


# --- local answers (client_sim/querying.py) ---------------------------------------------------


class WordEncoder:
    """A text encoder for tests: each text's own random unit vector (no model to load)."""

    model_id, dim = "word-vectors", DIM

    def encode(self, texts: Sequence[str]) -> np.ndarray:
        return np.stack([self.encode_query(text) for text in texts]).astype(np.float32)

    def encode_query(self, text: str) -> np.ndarray:
        return unit_vector(zlib.crc32(text.encode())).astype(np.float32)


def answer(local: LocalMap, rtt_ms: float, server_hits: list[dict] | None = None) -> QueryAnswer:
    """The router's answer to "mug" at this RTT; SQ gets a JSON query answer of `server_hits`
    and parses it as from a server (no server runs)."""
    encoder = WordEncoder()
    router = QueryRouter("http://127.0.0.1:9", "sid", None, local, encoder, rtt_ms=lambda: rtt_ms)
    body = {"text": "mug", "match": True, "results": server_hits or [], "latency_ms": 1.0}

    async def call(method: str, url: str, **kwargs) -> dict:
        assert url.endswith("/query"), url
        return json.loads(json.dumps(body))

    router.api._call = call  # type: ignore[method-assign]
    return asyncio.run(router.query("mug", k=2))


def test_local_and_server_answers_carry_the_same_last_seen_t():
    mug = MapObject(id=3, version=4, n_obs=5, confirmed=True, first_seen_t=2.0)
    mug.last_seen_t = 612.987654321
    mug.set_points(np.random.default_rng(0).uniform(0, 0.1, (50, 3)).astype(np.float32), 0.02)
    mug.embedding_sum = WordEncoder().encode_query("mug")
    mug.label_counts = Counter({"mug": 5})
    local = local_map()
    wire = delta_message(Delta(seq=1, full=True, upserts=[3], removed=[]), {3: mug}, 200)
    local.apply_delta(msgpack.unpackb(msgpack.packb(wire, use_bin_type=True), raw=False))
    server_hit = {  # a QueryHit as the server answers it (app/protocol/rest.py)
        "id": 3, "label": "mug", "score": 1.0, "relevance": 1.0, "bbox": list(mug.bbox),
        "centroid": mug.points.mean(axis=0).tolist(), "last_seen_t": mug.last_seen_t,
        "state": "present",
    }  # fmt: skip

    offline, online = answer(local, math.inf), answer(local, 1.0, [server_hit])

    assert (offline.mode, online.mode) == ("LQ", "SQ")
    assert offline.results[0]["id"] == online.results[0]["id"] == 3
    for key in ("last_seen_t", "state"):
        assert offline.results[0][key] == online.results[0][key], key
    assert offline.results[0]["last_seen_t"] == 612.987654321


def test_answers_from_and_about_an_older_server_say_none_for_last_seen_t():
    local = local_map()
    old = upsert(3, label="mug", embedding=WordEncoder().encode_query("mug"))
    local.apply_delta(delta(1, [old]))
    server_hit = {  # an older server's QueryHit: no living-map fields
        "id": 3, "label": "mug", "score": 1.0, "relevance": 1.0, "bbox": list(old.bbox),
        "centroid": [0.0, 0.0, 0.0],
    }  # fmt: skip

    offline, online = answer(local, math.inf), answer(local, 1.0, [server_hit])

    assert offline.results[0]["last_seen_t"] is None and online.results[0]["last_seen_t"] is None
    assert offline.results[0]["state"] == online.results[0]["state"] == "present"


# --- points -----------------------------------------------------------------------------------


def test_points_over_the_cap_are_subsampled_from_the_received_ones_deterministically():
    sent = upsert(1, n_points=500)
    first, second = local_map(max_points_per_object=64), local_map(max_points_per_object=64)
    first.apply_delta(delta(1, [sent]))
    second.apply_delta(delta(1, [sent]))

    held = first.get(1)
    assert held["points"].shape == (64, 3) and held["points"].dtype == np.float32
    # each held point is one of the sent ones, within half a quantisation step per axis
    gap = np.abs(held["points"][:, None, :] - sent.points.astype(np.float32)[None])
    assert np.all((gap <= np.asarray(held["points_step"]) / 2 + 1e-6).all(axis=2).any(axis=1))
    np.testing.assert_array_equal(held["points"], second.get(1)["points"])


def test_points_under_the_cap_are_kept_in_order_within_half_a_step():
    sent = upsert(1, n_points=30)
    m = local_map(max_points_per_object=64)
    m.apply_delta(delta(1, [sent]))

    held = m.get(1)
    assert_points_within_step(held, sent.points)
    box = sent.points.astype(np.float32).max(axis=0) - sent.points.astype(np.float32).min(axis=0)
    assert held["points_step"] == pytest.approx(box / POINT_LEVELS, rel=1e-5)


def test_points_of_a_2_m_object_are_stored_within_4_mm_in_one_byte_per_coordinate():
    rng = np.random.default_rng(5)
    points = (np.array([30.0, -12.0, 1.0]) + rng.uniform(0, 2, (200, 3))).astype(np.float16)
    data, lo, step = quantise_points(points)

    restored = dequantise_points(data, lo, step)

    assert len(data) == 200 * 3
    assert np.all(step <= 2 / POINT_LEVELS)
    assert np.abs(restored - points.astype(np.float32)).max() <= 1 / POINT_LEVELS + 1e-5


def test_flat_and_empty_point_sets_round_trip():
    flat = np.array([[1, 2, 3], [1, 2, 5], [1, 2, 4]], np.float16)
    np.testing.assert_allclose(dequantise_points(*quantise_points(flat)), flat, atol=2 / 255)
    assert dequantise_points(*quantise_points(np.zeros((0, 3), np.float16))).shape == (0, 3)
    m = local_map()
    m.apply_delta(delta(1, [upsert(1, n_points=0), upsert(2, n_points=1)]))
    assert m.get(1)["points"].shape == (0, 3)
    assert_points_within_step(m.get(2), upsert(2, n_points=1).points)


def test_lowering_the_point_cap_at_run_time_recaps_held_objects():
    m = local_map(max_points_per_object=100)
    m.apply_delta(delta(1, [upsert(1, n_points=100), upsert(2, n_points=10)]))
    before = m.memory_bytes()

    m.set_policy(max_points_per_object=25)

    assert [len(m.get(oid)["points"]) for oid in (1, 2)] == [25, 10]
    assert m.memory_bytes() == before - 75 * 3  # one byte a coordinate


def test_the_centroid_is_the_mean_of_the_received_points():
    sent = upsert(1, center_m=(2, 3, 4), n_points=300)
    m = local_map(max_points_per_object=10)
    m.apply_delta(delta(1, [sent]))

    received = sent.points.astype(np.float64)
    assert m.get(1)["centroid"] == pytest.approx(received.mean(axis=0), abs=1e-4)


# --- memory -----------------------------------------------------------------------------------


def test_memory_grows_linearly_with_the_number_of_objects():
    one, two = bytes_of_objects(200), bytes_of_objects(400)

    assert two == pytest.approx(2 * one, rel=0.01)


def test_reupserting_the_same_objects_does_not_grow_memory():
    m = local_map()
    m.apply_delta(delta(1, [upsert(i) for i in range(100)]))
    first = m.memory_bytes()
    for version in range(2, 30):
        m.apply_delta(delta(version, [upsert(i, version=version) for i in range(100)]))

    assert m.memory_bytes() == first


def test_memory_follows_the_objects_down_after_removals():
    m = local_map()
    m.apply_delta(delta(1, [upsert(i) for i in range(400)]))
    m.apply_delta(delta(2, removed=list(range(350))))

    assert m.memory_bytes() <= 1.2 * bytes_of_objects(50)


def test_an_object_at_the_device_defaults_takes_the_compact_columns():
    """200 points and a 384-d embedding: int8 embedding + float32 scale, 3 bytes a point;
    within 64 MB for 50k objects (1,280 bytes each), row slack included."""
    m = LocalMap(dim=384, max_points_per_object=200)
    m.apply_delta(
        delta(1, [upsert(i, n_points=200, embedding=unit_vector(i, 384)) for i in range(2000)])
    )
    per_object = m.memory_bytes() / 2000
    capacity = m._store.columns["id"].shape[0]

    assert m._store.columns["embedding"].nbytes == capacity * 384  # one byte a dimension
    assert m._store.points_nbytes == 2000 * (200 * 3 + sys.getsizeof(b""))  # bytes and header
    assert per_object <= 64 * BYTES_PER_MB / 50_000


def test_memory_bytes_matches_what_the_allocator_sees():
    messages = [delta(1, [upsert(10_000 + i, n_points=200) for i in range(2000)])]
    warm = local_map()  # first use imports and caches; keep that out of the measurement
    warm.apply_delta(delta(1, [upsert(1)]))
    warm.query_embedding(unit_vector(1))
    gc.collect()
    tracemalloc.start()
    try:
        m = local_map()
        start = tracemalloc.get_traced_memory()[0]
        m.apply_delta(messages[0])
        gc.collect()
        held = tracemalloc.get_traced_memory()[0] - start
    finally:
        tracemalloc.stop()

    assert m.memory_bytes() == pytest.approx(held, rel=0.1)


# --- budget and eviction ----------------------------------------------------------------------


def test_the_farthest_objects_from_the_user_are_evicted_first():
    m = local_map(budget_mb=budget_mb_for(4))
    m.set_user_position([0, 0, 0])
    m.apply_delta(delta(1, [upsert(i, center_m=(float(i), 0, 0)) for i in range(1, 11)]))

    assert m.ids() == [1, 2, 3, 4]
    assert m.evicted == 6


def test_objects_within_the_distance_threshold_are_kept_before_farther_ones():
    m = local_map(budget_mb=budget_mb_for(3), distance_threshold_m=2.5)
    m.set_user_position([0, 0, 0])
    near = [upsert(i, center_m=(float(i), 0, 0)) for i in (1, 2)]
    far = [upsert(i, center_m=(float(i), 0, 0)) for i in (10, 20, 30)]
    m.apply_delta(delta(1, near + far))

    assert m.ids() == [1, 2, 10]


def test_priority_class_objects_are_kept_before_nearby_ones():
    m = local_map(budget_mb=budget_mb_for(3), priority_classes=["Keys"], distance_threshold_m=5)
    m.set_user_position([0, 0, 0])
    nearby = [upsert(i, center_m=(float(i), 0, 0)) for i in (1, 2, 3)]
    keys = [upsert(i, label="keys", center_m=(100.0 + i, 0, 0)) for i in (50, 60)]
    m.apply_delta(delta(1, nearby + keys))

    assert m.ids() == [1, 50, 60]


def test_protected_objects_are_evicted_farthest_first_when_they_alone_exceed_the_budget():
    m = local_map(budget_mb=budget_mb_for(2), priority_classes=["keys"])
    m.set_user_position([0, 0, 0])
    m.apply_delta(delta(1, [upsert(i, label="keys", center_m=(float(i), 0, 0)) for i in (3, 1, 2)]))

    assert m.ids() == [1, 2]


def test_without_a_user_position_the_least_recently_updated_are_evicted_first():
    m = local_map(budget_mb=budget_mb_for(3))
    m.apply_delta(delta(1, [upsert(1), upsert(2), upsert(3)]))
    m.apply_delta(delta(2, [upsert(1, version=2)]))  # 1 is now the freshest
    m.apply_delta(delta(3, [upsert(4)]))

    assert m.ids() == [1, 3, 4]


def test_lowering_the_budget_at_run_time_evicts_at_once():
    m = local_map()
    m.set_user_position([0, 0, 0])
    m.apply_delta(delta(1, [upsert(i, center_m=(float(i), 0, 0)) for i in range(1, 9)]))

    m.set_policy(budget_mb=budget_mb_for(2))

    assert m.ids() == [1, 2]
    assert m.memory_bytes() <= budget_mb_for(2) * BYTES_PER_MB


def test_a_budget_too_small_for_one_object_empties_the_map_without_hanging():
    m = local_map(budget_mb=0.0005)  # one such object takes ~900 bytes
    m.apply_delta(delta(1, [upsert(1, n_points=200)]))

    assert len(m) == 0 and m.evicted == 1
    assert m.memory_bytes() <= 0.0005 * BYTES_PER_MB


# --- property: random delta streams ----------------------------------------------------------

LABELS = ["chair", "keys", "mug"]
upsert_specs = st.tuples(
    st.integers(0, 60), st.integers(0, 40), st.sampled_from(LABELS), st.integers(0, 5)
)
streams = st.lists(
    st.tuples(
        st.lists(upsert_specs, max_size=25, unique_by=lambda spec: spec[0]),
        st.lists(st.integers(0, 60), max_size=50, unique=True),
    ),
    min_size=1,
    max_size=8,
)


@FEW
@given(
    stream=streams,
    budget_mb=st.floats(0.001, 0.03),
    priority=st.lists(st.sampled_from(LABELS), max_size=2),
    user_position=st.none() | st.tuples(*[st.floats(-5, 5)] * 3),
    threshold_m=st.none() | st.floats(0, 5),
)
def test_the_budget_is_never_exceeded_and_held_objects_match_the_server(
    stream, budget_mb, priority, user_position, threshold_m
):
    m = local_map(
        max_points_per_object=24,
        budget_mb=budget_mb,
        priority_classes=priority,
        distance_threshold_m=threshold_m,
    )
    m.set_user_position(user_position)
    server: dict[int, tuple[int, str]] = {}
    for seq, (specs, removed) in enumerate(stream, start=1):
        upserted_ids = {spec[0] for spec in specs}
        removed = [oid for oid in removed if oid not in upserted_ids]
        ups = []
        for oid, n_points, label, x in specs:
            version = server.get(oid, (0, ""))[0] + 1  # a server's versions only grow
            server[oid] = (version, label)
            ups.append(upsert(oid, version, label, (float(x), 0.0, 0.0), n_points))
        for oid in removed:
            server.pop(oid, None)

        m.apply_delta(delta(seq, ups, removed))

        assert m.memory_bytes() <= budget_mb * BYTES_PER_MB
        held = m.snapshot()
        assert all(server[oid] == entry for oid, entry in held.items())
        assert all(len(m.get(oid)["points"]) <= 24 for oid in held)


@FEW
@given(
    stream=st.lists(
        st.tuples(
            st.lists(st.tuples(st.integers(0, 60), st.integers(0, 4)), max_size=30),
            st.lists(st.integers(0, 60), max_size=50, unique=True),
        ),
        min_size=1,
        max_size=8,
    )
)
def test_without_budget_pressure_the_map_equals_the_server_and_finds_every_object(stream):
    m = local_map()
    expected: dict[int, tuple[int, str]] = {}
    for seq, (specs, removed) in enumerate(stream, start=1):
        specs = list({oid: version for oid, version in specs}.items())  # one entry per id
        removed = [oid for oid in removed if oid not in dict(specs)]
        for oid, version in specs:
            if oid not in expected or version >= expected[oid][0]:
                expected[oid] = (version, f"label {oid} v{version}")
        for oid in removed:
            expected.pop(oid, None)

        m.apply_delta(
            delta(
                seq,
                [upsert(oid, version, f"label {oid} v{version}") for oid, version in specs],
                removed,
            )
        )

        assert m.snapshot() == expected
    for oid in expected:
        assert m.query_embedding(unit_vector(oid), k=1)[0].id == oid
