"""The living map in the stores (schema 4): removed objects kept as history, when and where
objects were seen, per-label evidence, the changes the map concluded, and the session's last
keyframe time and pose. Tests taking `store` or `store_url` run against each store
(conftest.py: real SQLite files and a real PostgreSQL database); the migration tests are
about SQLite files. Nothing is mocked."""

from __future__ import annotations

import math
import sqlite3
from collections import Counter

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_store import DIM, EXAMPLES, everything, fields, make_object, record, seeded

from app.mapping.object import MAX_STAYS, Change, MapObject, Stay
from app.store import CHANGE_KINDS, KeyframeCommit, Store, open_store
from app.store.dialect import SQLITE
from app.store.schema import statements
from app.store.sqlite import SCHEMA_VERSION, SqliteStore


def f32(*values: float) -> tuple[float, ...]:
    """Values a stay's place holds exactly (stays keep float32 places)."""
    return tuple(float(np.float32(v)) for v in values)


def living_object(oid: int, state: str = "present", n_stays: int = 2, seed: int = 0) -> MapObject:
    """A confirmed object with every field of the living map set (distinct per oid, seed)."""
    obj = make_object(oid, version=2, seed=seed)
    obj.state = state
    obj.first_seen_t = 100.0 + oid + 1 / 3  # float64 times are kept exactly
    obj.last_seen_t = 700.0 + oid + seed + 1 / 7
    rng = np.random.default_rng([oid, seed, 7])
    # Per-label sums for some labels only: "other" was counted before per-label evidence.
    obj.label_embeddings = {f"label-{oid}": rng.standard_normal(DIM).astype(np.float32)}
    obj.stays = [
        Stay(
            100.0 + 10 * i + 0.1,
            105.0 + 10 * i + 0.2,
            f32(*rng.standard_normal(3)),
            f32(*rng.standard_normal(6)),
        )
        for i in range(n_stays)
    ]
    return obj


def retired(obj: MapObject) -> MapObject:
    obj.state = "removed"
    return obj


def history(store: Store, sid: str = "s1") -> tuple:
    """What the living map adds to a store's observable content."""
    return (
        store.load_session(sid),
        [fields(o) for o in store.load_removed_objects(sid)],
        store.load_changes(sid),
    )


# ---------------------------------------------------------------------- migration
def test_a_version_3_store_migrates_and_loads_its_objects_as_present_without_history(tmp_path):
    path = tmp_path / "semanticxr.db"
    obj = make_object(1)
    with sqlite3.connect(path) as db:  # what a server at schema 3 wrote
        for statement in statements(SQLITE, to_version=3):
            db.execute(statement)
        db.execute("PRAGMA user_version = 3")
        db.execute(
            "INSERT INTO sessions (session_id, name, mode, perception, knobs, token_hash,"
            " created_at, frames, keyframes, bytes_in, bytes_out, next_object_id, seq,"
            " delta_floor, last_used_at) VALUES"
            " ('old', 'old', 'semanticxr', 'detections', '{}', 'h', 1.0, 9, 3, 0, 0, 6, 3, 0, 5.0)"
        )
        db.execute(
            "INSERT INTO objects (session_id, object_id, change_seq, version, n_obs,"
            " frames_seen, first_seen, last_seen, resolution_m, label_counts, n_points, points,"
            " embedding_dim, embedding_sum) VALUES ('old', 1, 3, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
            (
                obj.version,
                obj.n_obs,
                obj.frames_seen,
                obj.first_seen,
                obj.last_seen,
                obj.resolution_m,
                '{"label-1": 1, "other": 1}',
                len(obj.points),
                obj.points.astype("<f4").tobytes(),
                DIM,
                obj.embedding_sum.astype("<f4").tobytes(),
            ),
        )
        db.execute("INSERT INTO tombstones (session_id, object_id, seq) VALUES ('old', 5, 2)")

    with SqliteStore(path) as store:
        (loaded,) = store.load_objects("old")
        rec = store.load_session("old")
        assert [e.objects for e in store.list_stored()] == [1]
        assert store.load_delta_log("old").state()["upserted_at"] == {1: 3}
        assert store.load_delta_log("old").state()["removed_at"] == {5: 2}
        assert store.load_removed_objects("old") == [] and store.load_changes("old") == []

    assert fields(loaded) == fields(obj)
    assert (loaded.state, loaded.first_seen_t, loaded.last_seen_t) == ("present", None, None)
    assert loaded.stays == [] and loaded.label_embeddings == {}
    np.testing.assert_array_equal(loaded.embedding, obj.embedding)  # the all-label mean
    assert (rec.last_t, rec.last_pose, rec.frames, rec.last_used_at) == (None, None, 9, 5.0)
    with sqlite3.connect(path) as db:
        assert db.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION == 7


def test_a_new_store_has_the_schema_an_upgraded_one_has(tmp_path):
    """One path to each version: a new store is made at 1 and migrated."""
    SqliteStore(tmp_path / "new.db").close()
    with sqlite3.connect(tmp_path / "old.db") as db:
        for statement in statements(SQLITE, to_version=3):
            db.execute(statement)
        db.execute("PRAGMA user_version = 3")
    SqliteStore(tmp_path / "old.db").close()

    def schema(path) -> list:
        with sqlite3.connect(path) as db:
            return db.execute("SELECT type, name, sql FROM sqlite_master ORDER BY name").fetchall()

    assert schema(tmp_path / "new.db") == schema(tmp_path / "old.db")


# ---------------------------------------------------------------------- round trip
def test_every_field_of_the_living_map_round_trips_exactly(store_url):
    full_history = living_object(1, n_stays=MAX_STAYS)
    tie = living_object(2)
    tie.label_counts = Counter({"mug": 2, "cup": 2})  # a tie: the first seen wins, after too
    tie.label_embeddings = {"cup": np.ones(DIM, np.float32), "mug": np.full(DIM, 2, np.float32)}
    bare = make_object(3)  # an object as an older store or an import leaves it
    gone = retired(living_object(4))
    with open_store(store_url) as store:
        store.create_session(record("s1"))
        store.commit_keyframe(
            KeyframeCommit("s1", 1, [full_history, tie, bare, living_object(4)], [], {}, 5)
        )
        store.commit_keyframe(KeyframeCommit("s1", 2, [], [4], {}, 5, retired=[gone]))
    with open_store(store_url) as store:
        present = store.load_objects("s1")
        removed = store.load_removed_objects("s1")

    assert [fields(o) for o in present] == [fields(o) for o in (full_history, tie, bare)]
    assert [fields(o) for o in removed] == [fields(gone)]
    assert len(present[0].stays) == MAX_STAYS and present[1].label == "mug"
    np.testing.assert_array_equal(present[1].embedding, tie.embedding)  # the mug's mean
    assert present[0].label_embeddings.keys() == {"label-1"}  # "other" has no sum


def test_the_sessions_last_keyframe_time_and_pose_are_kept(store_url):
    pose = np.eye(4)
    pose[:3, 3] = (1.5, -0.25, 2.0)
    with open_store(store_url) as store:
        seeded(store)
        assert (store.load_session("s1").last_t, store.load_session("s1").last_pose) == (None, None)
        store.commit_keyframe(KeyframeCommit("s1", 3, [], [2], {}, 4, last_t=612.4, last_pose=pose))
        store.commit_keyframe(KeyframeCommit("s1", 3, [], [], {"frames": 99}, 4))  # not given: kept
        store.create_session(record("s2", last_t=-3.5, last_pose=list(range(16))))
    with open_store(store_url) as store:
        rec, listed = store.load_session("s1"), store.list_sessions()

    assert rec.last_t == 612.4 and rec.last_pose == pose.ravel().tolist()
    assert listed[0] == rec and listed[1] == record("s2", last_t=-3.5, last_pose=list(range(16)))


# ---------------------------------------------------------------------- removed objects
def test_a_retired_object_leaves_the_present_map_but_stays_as_history(store):
    seeded(store)  # objects 1 and 2 at seq 2, tombstone of 3
    store.commit_keyframe(
        KeyframeCommit("s1", 3, [], [2], {}, 4, retired=[retired(living_object(2))])
    )

    assert [o.id for o in store.load_objects("s1")] == [1]
    assert [(e.objects, e.seq) for e in store.list_stored()] == [(1, 3)]
    log = store.load_delta_log("s1").state()
    assert log["upserted_at"] == {1: 2} and log["removed_at"] == {2: 3, 3: 2}
    (kept,) = store.load_removed_objects("s1")
    assert fields(kept) == fields(retired(living_object(2)))
    assert fields(store.load_object("s1", 2)) == fields(kept)
    assert store.load_object("s1", 1).state == "present"
    assert store.load_object("s1", 3) is None  # removed without history: deleted
    assert store.load_object("s1", 99) is None

    store.trim_tombstones("s1", 3)  # the tombstone goes, the history stays
    assert store.load_delta_log("s1").state()["removed_at"] == {}
    assert [o.id for o in store.load_removed_objects("s1")] == [2]
    assert [o.id for o in store.load_objects("s1")] == [1]


def test_an_upsert_brings_a_removed_object_back_into_the_map(store):
    seeded(store)
    store.commit_keyframe(
        KeyframeCommit("s1", 3, [], [2], {}, 4, retired=[retired(living_object(2))])
    )
    store.commit_keyframe(KeyframeCommit("s1", 4, [living_object(2, seed=1)], [], {}, 4))
    assert [o.id for o in store.load_objects("s1")] == [1, 2]
    assert store.load_removed_objects("s1") == []
    assert 2 not in store.load_delta_log("s1").state()["removed_at"]


@pytest.mark.parametrize("call", ["load_removed_objects", "load_object", "load_changes"])
def test_history_of_an_unknown_session_is_a_key_error(store, call):
    args = {"load_object": ("nope", 1)}.get(call, ("nope",))
    with pytest.raises(KeyError, match="nope"):
        getattr(store, call)(*args)


def _unconfirmed_retired() -> MapObject:
    obj = retired(living_object(2))
    obj.confirmed = False
    return obj


def _too_many_stays() -> MapObject:
    obj = living_object(4)
    obj.stays = obj.stays * (MAX_STAYS // 2 + 1)
    return obj


def _stranger_label() -> MapObject:
    obj = living_object(4)
    obj.label_embeddings["never counted"] = np.ones(DIM, np.float32)
    return obj


def _short_label_sum() -> MapObject:
    obj = living_object(4)
    obj.label_embeddings["label-4"] = np.ones(DIM - 1, np.float32)
    return obj


def _nan_seen() -> MapObject:
    obj = living_object(4)
    obj.last_seen_t = math.nan
    return obj


def _nan_stay() -> MapObject:
    obj = living_object(4)
    obj.stays[0].t_to = math.inf
    return obj


GOOD_CHANGE = Change(4, "added", 12.0, "label-4", to_xyz=(1.0, 2.0, 3.0))


@pytest.mark.parametrize(
    ("upsert", "retire", "change", "pose"),
    [
        (living_object(4), _unconfirmed_retired(), GOOD_CHANGE, np.eye(4)),
        (living_object(4), living_object(2), GOOD_CHANGE, np.eye(4)),  # retired yet present
        (retired(living_object(4)), retired(living_object(2)), GOOD_CHANGE, np.eye(4)),
        (living_object(4), retired(living_object(1)), GOOD_CHANGE, np.eye(4)),  # not removed
        (_too_many_stays(), retired(living_object(2)), GOOD_CHANGE, np.eye(4)),
        (_stranger_label(), retired(living_object(2)), GOOD_CHANGE, np.eye(4)),
        (_short_label_sum(), retired(living_object(2)), GOOD_CHANGE, np.eye(4)),
        (_nan_seen(), retired(living_object(2)), GOOD_CHANGE, np.eye(4)),
        (_nan_stay(), retired(living_object(2)), GOOD_CHANGE, np.eye(4)),
        (living_object(4), retired(living_object(2)), Change(4, "gone", 1.0, "x"), np.eye(4)),
        (living_object(4), retired(living_object(2)), Change(4, "added", math.nan, "x"), None),
        (living_object(4), retired(living_object(2)), Change(4, "moved", 1, "x", (0, 0)), None),
        (living_object(4), retired(living_object(2)), Change(9, "added", 1.0, "x"), None),
        (living_object(4), retired(living_object(2)), GOOD_CHANGE, np.eye(3)),
    ],
    ids=[
        "retired-unconfirmed",
        "retired-present",
        "upsert-removed",
        "retired-not-in-removed",
        "too-many-stays",
        "label-sum-of-an-uncounted-label",
        "label-sum-of-another-dim",
        "nan-last-seen",
        "infinite-stay",
        "unknown-kind",
        "nan-change-time",
        "place-of-two-values",
        "change-id-not-below-next-id",
        "pose-3x3",
    ],
)
def test_a_refused_living_commit_changes_nothing(store, upsert, retire, change, pose):
    seeded(store)
    store.commit_keyframe(
        KeyframeCommit("s1", 3, [], [], {}, 5, changes=[Change(1, "moved", 1.0, "a")])
    )
    before = everything(store), history(store)
    with pytest.raises(ValueError):
        store.commit_keyframe(
            KeyframeCommit(
                "s1",
                4,
                [make_object(1, version=9), upsert],  # a good row first: a failure mid-transaction
                [2],
                {"frames": 99},
                5,
                retired=[retire],
                changes=[GOOD_CHANGE, change],
                retracted_added=[1],
                last_t=50.0,
                last_pose=pose,
            )
        )
    assert (everything(store), history(store)) == before

    store.commit_keyframe(
        KeyframeCommit(  # still usable
            "s1", 4, [living_object(4)], [2], {}, 5, retired=[retired(living_object(2))]
        )
    )
    assert [o.id for o in store.load_removed_objects("s1")] == [2]


def test_changes_need_a_newer_seq(store):
    seeded(store)
    with pytest.raises(ValueError, match="does not follow"):
        store.commit_keyframe(
            KeyframeCommit("s1", 2, [], [], {}, 4, changes=[Change(1, "moved", 1.0, "a")])
        )
    assert store.load_changes("s1") == []


# ---------------------------------------------------------------------- changes
def moved(oid: int, t: float) -> Change:
    return Change(oid, "moved", t, f"thing {oid}", from_xyz=(oid, 0.5, -1.0), to_xyz=(t, 0, 0))


def test_changes_come_back_in_arrival_order_with_their_commits_seq(store_url):
    committed = [
        [Change(1, "added", 10.0, "mug", to_xyz=(0.1, 0.2, 0.3)), moved(2, 10.0)],
        [Change(3, "removed", 4.0, "laptop", from_xyz=(1.0, 1.0, 1.0), seq=77)],  # t went back
        [moved(1, 30.0)],
    ]
    with open_store(store_url) as store:
        store.create_session(record("s1"))
        for seq, changes in enumerate(committed, 1):
            store.commit_keyframe(
                KeyframeCommit("s1", seq, [make_object(seq)], [], {}, 4, changes=changes)
            )
    with open_store(store_url) as store:
        loaded = store.load_changes("s1")

    expected = [
        Change(c.id, c.kind, c.t, c.label, c.from_xyz, c.to_xyz, seq)
        for seq, changes in enumerate(committed, 1)
        for c in changes
    ]
    assert loaded == expected
    assert loaded[0].to_json() == {"id": 1, "kind": "added", "t": 10.0, "label": "mug",
                                   "to": [0.1, 0.2, 0.3]}  # fmt: skip


def test_retracted_ids_keep_no_added_change(store):
    store.create_session(record("s1"))
    store.commit_keyframe(
        KeyframeCommit(
            "s1",
            1,
            [make_object(1), make_object(2)],
            [],
            {},
            3,
            changes=[Change(1, "added", 1.0, "mug"), Change(2, "added", 1.0, "cup"), moved(1, 1.5)],
        )
    )
    # Object 2 turns out to be object 1 seen again: merged, its id removed, no `added` left.
    store.commit_keyframe(
        KeyframeCommit("s1", 2, [make_object(1, version=2)], [2], {}, 3, retracted_added=[2, 1000])
    )
    assert [(c.id, c.kind) for c in store.load_changes("s1")] == [(1, "added"), (1, "moved")]
    # An `added` change in the retracting commit itself goes too.
    store.commit_keyframe(
        KeyframeCommit(
            "s1", 3, [], [1], {}, 3, changes=[Change(1, "added", 2.0, "mug")], retracted_added=[1]
        )
    )
    assert [(c.id, c.kind) for c in store.load_changes("s1")] == [(1, "moved")]


def test_a_removed_object_found_again_is_present_and_its_removal_retracted(store):
    store.create_session(record("s1"))
    store.commit_keyframe(KeyframeCommit("s1", 1, [make_object(1)], [], {}, 2))
    gone = make_object(1, version=2)
    gone.state = "removed"
    store.commit_keyframe(
        KeyframeCommit(
            "s1", 2, [], [1], {}, 2, retired=[gone], changes=[Change(1, "removed", 5.0, "mug")]
        )
    )
    assert [o.id for o in store.load_removed_objects("s1")] == [1]
    # found at a new place soon after: present again, the move replaces the removal
    store.commit_keyframe(
        KeyframeCommit(
            "s1",
            3,
            [make_object(1, version=3)],
            [],
            {},
            2,
            changes=[moved(1, 9.0)],
            retracted_removed=[1],
        )
    )
    assert [(c.id, c.kind) for c in store.load_changes("s1")] == [(1, "moved")]
    assert [o.id for o in store.load_objects("s1")] == [1]
    assert store.load_removed_objects("s1") == []
    assert store.load_delta_log("s1").since(2).upserts == [1]


SEVEN = [  # (commit seq, change): arrival order, with t going backwards at seq 4
    (1, Change(1, "added", 1.0, "a", to_xyz=(0, 0, 0))),
    (1, moved(2, 1.0)),
    (2, Change(3, "removed", 2.0, "c", from_xyz=(1, 1, 1))),
    (3, moved(1, 3.0)),
    (4, Change(4, "added", 0.5, "d")),
    (5, Change(2, "removed", 5.0, "b")),
    (5, moved(4, 5.0)),
]


@pytest.fixture
def seven_changes(store) -> Store:
    store.create_session(record("s1"))
    for seq in range(1, 6):
        changes = [c for s, c in SEVEN if s == seq]
        store.commit_keyframe(
            KeyframeCommit("s1", seq, [make_object(seq)], [], {}, 6, changes=changes)
        )
    return store


@pytest.mark.parametrize(
    ("query", "positions"),
    [
        ({}, [0, 1, 2, 3, 4, 5, 6]),
        ({"since_t": 2.0}, [2, 3, 5, 6]),  # inclusive
        ({"until_t": 2.0}, [0, 1, 2, 4]),  # inclusive
        ({"since_t": 1.0, "until_t": 3.0}, [0, 1, 2, 3]),
        ({"since_seq": 3}, [4, 5, 6]),  # exclusive: after seq 3
        ({"since_seq": 0}, [0, 1, 2, 3, 4, 5, 6]),
        ({"kinds": ["removed"]}, [2, 5]),
        ({"kinds": {"added", "moved"}}, [0, 1, 3, 4, 6]),
        ({"kinds": []}, []),
        ({"limit": 3}, [4, 5, 6]),  # the newest three, oldest first
        ({"limit": 0}, []),
        ({"limit": 100}, [0, 1, 2, 3, 4, 5, 6]),
        ({"kinds": ["moved"], "since_t": 1.0, "limit": 2}, [3, 6]),
        ({"since_seq": 1, "until_t": 2.0, "kinds": ["added", "removed"]}, [2, 4]),
    ],
)
def test_changes_are_filtered_by_time_seq_and_kind_and_limited_to_the_newest(
    seven_changes, query, positions
):
    loaded = seven_changes.load_changes("s1", **query)
    assert [(c.seq, c.id, c.kind, c.t) for c in loaded] == [
        (SEVEN[i][0], SEVEN[i][1].id, SEVEN[i][1].kind, SEVEN[i][1].t) for i in positions
    ]


@pytest.mark.parametrize(
    ("query", "named"),
    [
        ({"kinds": ["added", "vanished"]}, "vanished"),
        ({"since_t": math.nan}, "since_t"),
        ({"until_t": math.nan}, "until_t"),
        ({"limit": -1}, "limit"),
    ],
)
def test_a_bad_changes_filter_is_a_value_error_naming_it(seven_changes, query, named):
    with pytest.raises(ValueError, match=named):
        seven_changes.load_changes("s1", **query)


@settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    ts=st.lists(st.floats(-5, 5).map(lambda t: round(t, 1)), min_size=0, max_size=12),
    since_t=st.none() | st.floats(-5, 5),
    until_t=st.none() | st.floats(-5, 5),
    since_seq=st.none() | st.integers(-1, 13),
    kinds=st.none() | st.sets(st.sampled_from(CHANGE_KINDS)),
    limit=st.none() | st.integers(0, 13),
)
def test_load_changes_equals_filtering_the_committed_list(
    store, ts, since_t, until_t, since_seq, kinds, limit
):
    committed = [Change(i + 1, CHANGE_KINDS[i % 3], t, "x", seq=i + 1) for i, t in enumerate(ts)]
    sid = f"s{next(EXAMPLES)}"
    store.create_session(record(sid))
    for change in committed:
        store.commit_keyframe(KeyframeCommit(sid, change.seq, [], [], {}, 20, changes=[change]))
    loaded = store.load_changes(
        sid, since_t=since_t, until_t=until_t, since_seq=since_seq, kinds=kinds, limit=limit
    )
    kept = [
        c
        for c in committed
        if (since_t is None or c.t >= since_t)
        and (until_t is None or c.t <= until_t)
        and (since_seq is None or c.seq > since_seq)
        and (kinds is None or c.kind in kinds)
    ]
    assert loaded == (kept if limit is None else kept[max(0, len(kept) - limit) :])
