"""Deltas on the updates socket: pack -> msgpack -> parse gives the same message back, and
every malformed variant is one DeltaError naming the field."""

from __future__ import annotations

from dataclasses import replace

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from app.errors import InputError
from app.protocol import (
    MAX_UPSERTS_PER_DELTA,
    ChangeEntry,
    DeltaError,
    DeltaMessage,
    UpsertEntry,
    pack_delta,
    parse_delta,
)

FEW = settings(max_examples=60, deadline=None)
DIM = 8
ids = st.integers(0, 2**63 - 1)
float16s = st.floats(-1000, 1000, width=16)


@st.composite
def upserts(draw, oid):
    lo = draw(st.lists(st.floats(-100, 100, width=32), min_size=3, max_size=3))
    size = draw(st.lists(st.floats(0, 10, width=32), min_size=3, max_size=3))
    return UpsertEntry(
        id=oid,
        version=draw(ids),
        label=draw(st.text(max_size=20)),
        embedding=draw(hnp.arrays(np.float16, DIM, elements=float16s)),
        points=draw(
            hnp.arrays(np.float16, st.tuples(st.integers(0, 6), st.just(3)), elements=float16s)
        ),
        bbox=(*lo, *(a + b for a, b in zip(lo, size, strict=True))),
        n_obs=draw(st.integers(0, 10**6)),
        first_seen_t=draw(st.none() | st.floats(-1e9, 1e9)),
        last_seen_t=draw(st.none() | st.floats(-1e9, 1e9)),
    )


points3 = st.none() | st.tuples(*[st.floats(-1000, 1000, width=32)] * 3)


@st.composite
def change_entries(draw):
    return ChangeEntry(
        id=draw(ids),
        kind=draw(st.sampled_from(["added", "moved", "removed"])),
        t=draw(st.floats(-1e9, 1e9)),
        label=draw(st.text(max_size=20)),
        from_xyz=draw(points3),
        to_xyz=draw(points3),
    )


@st.composite
def deltas(draw):
    object_ids = draw(st.lists(ids, unique=True, max_size=5))
    split = draw(st.integers(0, len(object_ids)))
    pose = None
    if draw(st.booleans()):
        pose = draw(hnp.arrays(np.float32, (4, 4), elements=st.floats(-10, 10, width=32)))
    return DeltaMessage(
        seq=draw(ids),
        full=draw(st.booleans()),
        upserts=[draw(upserts(oid)) for oid in object_ids[:split]],
        removed=object_ids[split:],
        device_pose=pose,
        changes=draw(st.lists(change_entries(), max_size=4)),
    )


def wire(message: dict) -> dict:
    return msgpack.unpackb(msgpack.packb(message, use_bin_type=True), raw=False)


@FEW
@given(delta=deltas())
def test_a_delta_survives_pack_msgpack_parse(delta):
    assert parse_delta(wire(delta.pack()), dim=DIM) == delta
    assert parse_delta(wire(delta.pack())) == delta  # dim from the upserts themselves


def test_pack_delta_is_the_message_of_its_parts():
    entry = UpsertEntry(1, 2, "mug", np.ones(DIM), np.zeros((2, 3)), (0, 0, 0, 1, 1, 1), 3)
    message = pack_delta(5, [entry], [9], full=False)
    assert list(message) == ["type", "seq", "full", "upserts", "removed"]
    assert list(message["upserts"][0]) == [
        "id",
        "version",
        "label",
        "embedding",
        "points",
        "bbox",
        "n_obs",
    ]
    assert message["upserts"][0]["embedding"] == np.ones(DIM, "<f2").tobytes()
    assert DeltaError.__mro__[1] is InputError


def _valid() -> dict:
    entries = [
        UpsertEntry(i, 1, "mug", np.ones(DIM), np.zeros((2, 3)), (0, 0, 0, 1, 1, 1), 3)
        for i in (20, 21)
    ]
    return wire(pack_delta(10, entries, [1]))


def _top(key, value):
    def mutate(message):
        if value is KeyError:
            del message[key]
        else:
            message[key] = value

    return mutate


def _second(key, value):
    def mutate(message):
        if value is KeyError:
            del message["upserts"][1][key]
        else:
            message["upserts"][1][key] = value

    return mutate


MALFORMED = [
    ("type", _top("type", "frame")),
    ("type", _top("type", KeyError)),
    ("seq", _top("seq", KeyError)),
    ("seq", _top("seq", "10")),
    ("seq", _top("seq", True)),
    ("seq", _top("seq", -1)),
    ("full", _top("full", 0)),
    ("upserts", _top("upserts", KeyError)),
    ("upserts", _top("upserts", {"id": 1})),
    ("upserts", _top("upserts", [{}] * (MAX_UPSERTS_PER_DELTA + 1))),
    ("removed", _top("removed", 3)),
    ("removed[0]", _top("removed", ["3"])),
    ("upserts[2]", lambda m: m["upserts"].append([1, 2])),
    ("upserts[1]", _second("id", KeyError)),
    ("upserts[1]", _second("embedding", KeyError)),
    ("upserts[1].id", _second("id", 21.0)),
    ("upserts[1].version", _second("version", -2)),
    ("upserts[1].n_obs", _second("n_obs", None)),
    ("upserts[1].label", _second("label", 5)),
    ("upserts[1].embedding", _second("embedding", b"\x00" * (2 * DIM - 2))),
    ("upserts[1].embedding", _second("embedding", b"\x00" * 3)),
    ("upserts[1].embedding", _second("embedding", "abc")),
    ("upserts[1].embedding", _second("embedding", np.full(DIM, np.nan, "<f2").tobytes())),
    ("upserts[1].points", _second("points", b"\x00" * 13)),
    ("upserts[1].points", _second("points", np.array([[0, np.inf, 0]], "<f2").tobytes())),
    ("upserts[1].bbox", _second("bbox", [0.0, 0.0, 0.0, 1.0, 1.0])),
    ("upserts[1].bbox", _second("bbox", [0.0, float("nan"), 0.0, 1.0, 1.0, 1.0])),
    ("upserts[1].bbox", _second("bbox", [0.0, 0.0, 0.0, 1e39, 1.0, 1.0])),
    ("upserts[1].bbox", _second("bbox", [1.0, 1.0, 1.0, 0.0, 0.0, 0.0])),
    ("upserts[1].bbox", _second("bbox", "0 0 0 1 1 1")),
    ("upserts", _second("id", 20)),
    ("removed", _top("removed", [21])),
    ("device_pose", _top("device_pose", b"\x00" * 10)),
    ("device_pose", _top("device_pose", np.full(16, np.nan, "<f4").tobytes())),
    ("upserts[1].last_seen_t", _second("last_seen_t", float("nan"))),
    ("upserts[1].first_seen_t", _second("first_seen_t", "yesterday")),
    ("changes", _top("changes", {"id": 1})),
    ("changes", _top("changes", [{}] * 33)),
    ("changes[0]", _top("changes", [{"id": 1, "kind": "moved", "t": 1.0}])),
    ("changes[0].kind", _top("changes", [{"id": 1, "kind": "teleported", "t": 1, "label": ""}])),
    ("changes[0].t", _top("changes", [{"id": 1, "kind": "moved", "t": None, "label": ""}])),
    (
        "changes[0].from",
        _top("changes", [{"id": 1, "kind": "moved", "t": 1, "label": "", "from": [1, 2]}]),
    ),
    ("changes[0].id", _top("changes", [{"id": -1, "kind": "added", "t": 1, "label": ""}])),
]


@pytest.mark.parametrize(
    ("field", "mutate"), MALFORMED, ids=[f"{f}-{i}" for i, (f, _) in enumerate(MALFORMED)]
)
def test_a_malformed_delta_raises_one_delta_error_naming_the_field(field, mutate):
    message = _valid()
    mutate(message)
    with pytest.raises(DeltaError) as err:
        parse_delta(message, dim=DIM)
    assert err.value.field == field, str(err.value)
    assert str(err.value).startswith(f"{field}: ")


def test_a_message_that_is_not_a_map_is_refused():
    with pytest.raises(DeltaError, match="^message: "):
        parse_delta([("type", "delta")])


def test_embeddings_of_two_dimensions_in_one_delta_are_refused_without_a_dim():
    message = _valid()
    message["upserts"][1]["embedding"] = np.ones(DIM + 2, "<f2").tobytes()
    with pytest.raises(DeltaError, match=r"^upserts\[1\].embedding: "):
        parse_delta(message)


def test_an_upserts_label_texts_cross_the_wire_and_an_old_upsert_has_none():
    entry = UpsertEntry(
        id=1,
        version=1,
        label="rucksack",
        embedding=np.full(8, 8**-0.5, np.float32),
        points=np.zeros((2, 3), np.float32),
        bbox=(0.0, 0.0, 0.0, 1.0, 1.0, 1.0),
        n_obs=1,
    )
    with_texts = replace(entry, label_texts=("rucksack", "backpack", "bag"))
    wire = msgpack.unpackb(msgpack.packb(pack_delta(1, [with_texts, replace(entry, id=2)])))
    got = parse_delta(wire, 8).upserts
    assert got[0].label_texts == ("rucksack", "backpack", "bag")
    assert got[1].label_texts is None and "label_texts" not in wire["upserts"][1]


@pytest.mark.parametrize("bad", ["backpack", [1, 2], ["x" * 201], ["a"] * 17])
def test_malformed_label_texts_are_refused_by_name(bad):
    entry = UpsertEntry(1, 1, "bag", np.full(8, 8**-0.5, np.float32), np.zeros((1, 3)), (0,) * 6, 1)
    message = pack_delta(1, [entry])
    message["upserts"][0]["label_texts"] = bad
    with pytest.raises(DeltaError, match="label_texts"):
        parse_delta(message, 8)
