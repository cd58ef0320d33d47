"""The stores: what the server acknowledged comes back after a close, a reopen or a kill -9.

Tests taking `store` or `store_url` run against each store (conftest.py): real SQLite files
under a temporary directory, and a real PostgreSQL database; nothing is mocked. The rest are
about the SQLite file itself.
"""

from __future__ import annotations

import itertools
import queue
import signal
import sqlite3
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from app.mapping.deltas import DeltaLog
from app.mapping.object import Change, MapObject
from app.server.settings import ServerSettings
from app.store import (
    KeyframeCommit,
    SessionRecord,
    Store,
    StoreError,
    StoreURLError,
    StoreVersionError,
    open_store,
    sqlite_url,
)
from app.store.sqlite import SCHEMA_VERSION, SqliteStore

REPO_ROOT = Path(__file__).resolve().parents[3]
DIM = 16


def make_object(oid: int, version: int = 1, n_points: int = 50, seed: int = 0) -> MapObject:
    """A confirmed object whose every field is distinct and derived from (oid, version, seed)."""
    rng = np.random.default_rng([oid, version, seed])
    obj = MapObject(
        id=oid,
        embedding_sum=rng.standard_normal(DIM).astype(np.float32),
        label_counts=Counter({f"label-{oid}": version, "other": 1}),
        n_obs=version + 2,
        frames_seen=version + 1,
        first_seen=oid,
        last_seen=oid + version,
        version=version,
        confirmed=True,
    )
    obj.set_points(rng.standard_normal((n_points, 3)).astype(np.float32), 0.025 * (1 + oid % 3))
    return obj


def fields(obj: MapObject) -> tuple:
    """Everything persisted about an object, arrays compared bit for bit (dtype included)."""
    emb = obj.embedding_sum
    by_label = sorted(
        (label, v.dtype.str, v.tobytes()) for label, v in obj.label_embeddings.items()
    )
    return (
        obj.id,
        obj.version,
        obj.n_obs,
        obj.frames_seen,
        obj.first_seen,
        obj.last_seen,
        obj.confirmed,
        obj.resolution_m,
        list(obj.label_counts.items()),
        obj.points.dtype.str,
        obj.points.shape,
        obj.points.tobytes(),
        None if emb is None else (emb.dtype.str, emb.shape, emb.tobytes()),
        by_label,
        obj.first_seen_t,
        obj.last_seen_t,
        obj.state,
        obj.stays,
    )


def record(sid: str = "s1", **changes) -> SessionRecord:
    values = dict(
        session_id=sid,
        name=f"name of {sid}",
        mode="semanticxr",
        knobs={"max_object_points_server": 2000, "skip_mapping_set": ["wall"], "x": None},
        token_hash="sha256:abc",
        created_at=1_700_000_000.25,
    )
    values.update(changes)
    return SessionRecord(**values)


def query(store_url: str, statement: str) -> list[tuple]:
    """The rows of one SQL statement run on the store's own database (SQLite or PostgreSQL)."""
    if store_url.startswith("sqlite:///"):
        with sqlite3.connect(store_url.removeprefix("sqlite:///")) as db:
            return db.execute(statement).fetchall()
    import psycopg

    with psycopg.connect(store_url) as conn:
        return conn.execute(statement).fetchall()


EXAMPLES = itertools.count()
"""Hypothesis examples share a test's store: each takes a session id of its own."""


def seeded(store: Store, sid: str = "s1") -> None:
    """A session at seq 2: objects 1 and 2 (seq 1, then 1 changed at 2), tombstone of 3."""
    store.create_session(record(sid))
    store.commit_keyframe(
        KeyframeCommit(sid, 1, [make_object(1), make_object(2), make_object(3)], [], {}, 4)
    )
    store.commit_keyframe(
        KeyframeCommit(sid, 2, [make_object(1, version=2)], [3], {"keyframes": 2}, 4)
    )


def everything(store: Store) -> tuple:
    """The whole observable content of a store."""
    sessions = store.list_sessions()
    return (
        sessions,
        {s.session_id: [fields(o) for o in store.load_objects(s.session_id)] for s in sessions},
        {s.session_id: store.load_delta_log(s.session_id).state() for s in sessions},
    )


# ---------------------------------------------------------------------- sessions
def test_sessions_round_trip_with_their_knobs_and_counters(store):
    store.create_session(record("b", created_at=2.0))
    store.create_session(record("a", created_at=1.0, frames=7, bytes_in=123, next_object_id=9))
    assert store.list_sessions() == [
        record("a", created_at=1.0, frames=7, bytes_in=123, next_object_id=9),
        record("b", created_at=2.0),
    ]

    store.update_session("b", name="renamed", knobs={"min_observations": 5})
    store.update_session("b", counters={"frames": 10, "keyframes": 2, "bytes_out": 99})
    assert store.list_sessions()[1] == record(
        "b",
        created_at=2.0,
        name="renamed",
        knobs={"min_observations": 5},
        frames=10,
        keyframes=2,
        bytes_out=99,
    )


def test_sessions_made_at_one_time_are_listed_by_id_in_code_point_order(store):
    """As SQLite compares text (byte by byte): never by a database's locale."""
    ids = ["b", "B", "_x", "a-1", "a1", "é", "Z"]
    for sid in ids:
        store.create_session(record(sid, created_at=7.0))
    assert [rec.session_id for rec in store.list_sessions()] == sorted(ids)
    assert [e.record.session_id for e in store.list_stored()] == sorted(ids)


def test_a_new_session_counts_as_used_when_it_was_created(store):
    store.create_session(record("s1", created_at=5.0))
    assert store.load_session("s1").last_used_at == 5.0


def test_the_last_use_is_saved_with_counters_and_with_keyframes(store):
    seeded(store)
    store.update_session("s1", last_used_at=1_800_000_000.5)
    assert store.load_session("s1").last_used_at == 1_800_000_000.5
    store.commit_keyframe(
        KeyframeCommit("s1", 3, [make_object(2, version=2)], [], {}, 4, last_used_at=1.9e9)
    )
    assert store.load_session("s1").last_used_at == 1.9e9
    store.commit_keyframe(KeyframeCommit("s1", 3, [], [], {"frames": 9}, 4))  # not given: kept
    assert store.load_session("s1").last_used_at == 1.9e9


def test_sessions_idle_since_a_time_are_found_from_their_rows(store):
    for sid, used in (("old", 100.0), ("recent", 300.0), ("older", 50.0)):
        store.create_session(record(sid, last_used_at=used))
    assert store.idle_sessions(200.0) == ["older", "old"]
    assert store.idle_sessions(50.0) == []


def test_stored_sessions_are_listed_and_counted_with_their_map_sizes(store):
    seeded(store, "s1")  # objects 1 and 2 at seq 2
    store.create_session(record("s2", created_at=1_800_000_000.0))
    assert store.count_sessions() == 2
    listed = store.list_stored()
    assert [(e.record, e.objects, e.seq) for e in listed] == [
        (store.load_session("s1"), 2, 2),
        (store.load_session("s2"), 0, 0),
    ]


def test_a_duplicate_session_id_is_a_value_error(store):
    store.create_session(record("s1"))
    with pytest.raises(ValueError, match="already exists"):
        store.create_session(record("s1", name="other"))
    assert store.list_sessions() == [record("s1")]


def test_an_unknown_counter_is_refused_and_changes_nothing(store):
    store.create_session(record("s1"))
    with pytest.raises(ValueError, match="unknown counters"):
        store.update_session("s1", name="new", counters={"frames": 1, "seq": 5})
    assert store.list_sessions() == [record("s1")]


@pytest.mark.parametrize(
    "call",
    [
        lambda s: s.update_session("nope", name="x"),
        lambda s: s.commit_keyframe(KeyframeCommit("nope", 1, [], [], {}, 1)),
        lambda s: s.load_objects("nope"),
        lambda s: s.load_delta_log("nope"),
        lambda s: s.trim_tombstones("nope", 0),
    ],
    ids=["update", "commit", "load_objects", "load_delta_log", "trim"],
)
def test_an_unknown_session_is_a_key_error(store, call):
    with pytest.raises(KeyError, match="nope"):
        call(store)


# ---------------------------------------------------------------------- objects
def test_objects_round_trip_exactly(store):
    store.create_session(record("s1"))
    special = make_object(1, version=3, n_points=4)
    special.set_points(np.array([[-0.0, 1e-40, 3.4e38]] * 4, np.float32), 0.1)  # sign, subnormal
    tie_first_seen = make_object(2)
    tie_first_seen.label_counts = Counter({"mug": 2, "cup": 2})  # a tie: the first seen wins
    no_embedding = make_object(3, n_points=0)
    no_embedding.embedding_sum = None
    objects = [special, tie_first_seen, no_embedding, make_object(4, n_points=2000)]
    store.commit_keyframe(KeyframeCommit("s1", 1, objects, [], {}, 5))

    loaded = store.load_objects("s1")

    assert [fields(o) for o in loaded] == [fields(o) for o in objects]
    assert loaded[1].label == "mug"
    for obj in loaded:
        assert obj.points.flags.writeable and obj.points.flags.c_contiguous
        np.testing.assert_array_equal(obj.bbox, objects[obj.id - 1].bbox)


def test_an_upsert_replaces_the_object_and_clears_its_tombstone(store):
    seeded(store)
    store.commit_keyframe(KeyframeCommit("s1", 3, [make_object(3, version=5)], [], {}, 4))
    assert [(o.id, o.version) for o in store.load_objects("s1")] == [(1, 2), (2, 1), (3, 5)]
    assert store.load_delta_log("s1").state()["removed_at"] == {}


def test_an_id_both_upserted_and_removed_in_one_commit_ends_up_removed(store):
    seeded(store)
    store.commit_keyframe(KeyframeCommit("s1", 3, [make_object(1, version=3)], [1], {}, 4))
    log = store.load_delta_log("s1")
    assert [o.id for o in store.load_objects("s1")] == [2]
    assert log.state()["removed_at"] == {1: 3, 3: 2}


def test_a_keyframe_that_changed_nothing_keeps_the_seq_and_stores_its_counters(store):
    seeded(store)
    store.commit_keyframe(KeyframeCommit("s1", 2, [], [], {"frames": 50, "keyframes": 10}, 4))
    assert store.load_delta_log("s1").seq == 2
    assert (store.list_sessions()[0].frames, store.list_sessions()[0].keyframes) == (50, 10)


def _bad_points() -> MapObject:
    obj = make_object(5)
    obj.points = np.array([["a", "b", "c"]], dtype=object)  # not convertible to float32
    return obj


def _flat_points() -> MapObject:
    obj = make_object(5)
    obj.points = np.zeros((4, 2), np.float32)
    return obj


def _unconfirmed() -> MapObject:
    obj = make_object(5)
    obj.confirmed = False
    return obj


@pytest.mark.parametrize(
    ("seq", "last_object", "next_object_id"),
    [
        (3, _bad_points, 6),
        (3, _flat_points, 6),
        (3, _unconfirmed, 6),
        (1, lambda: make_object(5), 6),  # seq going backwards
        (2, lambda: make_object(5), 6),  # changes without a new seq
        (3, lambda: make_object(5), 5),  # id 5 is not below next_object_id
    ],
    ids=[
        "unconvertible-points",
        "points-not-Nx3",
        "unconfirmed",
        "older-seq",
        "same-seq",
        "id-reuse",
    ],
)
def test_a_refused_commit_leaves_the_store_exactly_as_before(
    store, seq, last_object, next_object_id
):
    seeded(store)
    before = everything(store)
    # Good rows come first, so a failure on the last object happens mid-transaction.
    upserts = [make_object(1, version=9), make_object(4), last_object()]
    with pytest.raises(ValueError):
        store.commit_keyframe(
            KeyframeCommit("s1", seq, upserts, [2], {"frames": 99, "keyframes": 3}, next_object_id)
        )
    assert everything(store) == before

    store.commit_keyframe(
        KeyframeCommit("s1", 3, upserts[:2], [2], {"keyframes": 3}, 6)
    )  # still usable
    assert [o.id for o in store.load_objects("s1")] == [1, 4]


def test_deleting_a_session_removes_its_objects_tombstones_and_changes(store, store_url):
    seeded(store, "gone")
    seeded(store, "kept")
    store.commit_keyframe(
        KeyframeCommit("gone", 3, [], [1], {}, 4, changes=[Change(1, "removed", 9.0, "x")])
    )
    kept_before = everything(store)[1]["kept"]

    store.delete_session("gone")
    store.delete_session("gone")  # idempotent

    assert [s.session_id for s in store.list_sessions()] == ["kept"]
    assert everything(store)[1]["kept"] == kept_before
    for table in ("objects", "tombstones", "changes"):
        count = query(store_url, f"SELECT count(*) FROM {table} WHERE session_id = 'gone'")
        assert count == [(0,)], table
    store.create_session(record("gone"))
    assert store.load_objects("gone") == []
    assert store.load_delta_log("gone").state() == DeltaLog().state()


# ---------------------------------------------------------------------- the delta log
def test_trimming_tombstones_raises_the_floor_past_the_dropped_ones(store):
    store.create_session(record("s1"))
    for seq in range(1, 6):  # object 10 + seq created at seq, removed at seq + 1
        removed = [9 + seq] if seq > 1 else []
        store.commit_keyframe(KeyframeCommit("s1", seq, [make_object(10 + seq)], removed, {}, 20))
    assert store.load_delta_log("s1").state()["removed_at"] == {11: 2, 12: 3, 13: 4, 14: 5}

    store.trim_tombstones("s1", floor=3)

    log = store.load_delta_log("s1")
    assert log.floor == 3 and log.state()["removed_at"] == {13: 4, 14: 5}
    assert log.since(2).full
    assert (log.since(3).full, log.since(3).removed, log.since(3).upserts) == (
        False,
        [13, 14],
        [15],
    )
    store.trim_tombstones("s1", floor=2)  # below the stored floor: nothing changes
    assert store.load_delta_log("s1").state() == log.state()
    with pytest.raises(ValueError, match="beyond the stored seq"):
        store.trim_tombstones("s1", floor=6)
    assert store.load_delta_log("s1").state() == log.state()


def test_reopening_keeps_everything_and_the_same_deltas(store_url):
    with open_store(store_url) as store:
        seeded(store, "s1")
        seeded(store, "s2")
        store.commit_keyframe(
            KeyframeCommit("s2", 3, [make_object(2, version=7)], [1], {"bytes_in": 5}, 4)
        )
        before = everything(store)
        log_before = store.load_delta_log("s2")

    with open_store(store_url) as store:
        assert everything(store) == before
        log_after = store.load_delta_log("s2")
    for since in [None, *range(-1, log_before.seq + 2)]:
        assert log_after.since(since) == log_before.since(since), since


# ---------------------------------------------------------------------- the file
def test_the_database_is_created_in_wal_mode_with_its_parent_dirs(tmp_path):
    path = tmp_path / "a" / "b" / "semanticxr.db"
    SqliteStore(path).close()
    with sqlite3.connect(path) as db:
        assert db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
        assert db.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION


def back_to_version_6(db: sqlite3.Connection) -> None:
    """Undo migration 6 -> 7 (the session's text tower)."""
    for column in ("tower_sha256", "text_tower"):  # tower_sha256's check names text_tower
        db.execute(f"ALTER TABLE sessions DROP COLUMN {column}")
    db.execute("PRAGMA user_version = 6")


def back_to_version_5(db: sqlite3.Connection) -> None:
    """Undo migration 5 -> 6 (the session's up axis) and after."""
    back_to_version_6(db)
    for column in ("up_source", "up"):  # up_source's check names up: it goes first
        db.execute(f"ALTER TABLE sessions DROP COLUMN {column}")
    db.execute("PRAGMA user_version = 5")


def back_to_version_4(db: sqlite3.Connection) -> None:
    """Undo migrations 4 -> 5 (map shards) and after on a store holding no owners or acks."""
    back_to_version_5(db)
    for table in ("done_acks", "shards"):
        db.execute(f"DROP TABLE {table}")
    db.execute("DROP INDEX sessions_by_owner")
    for column in ("sightings", "owner", "epoch", "lease_until"):
        db.execute(f"ALTER TABLE sessions DROP COLUMN {column}")
    db.execute("PRAGMA user_version = 4")


def back_to_version_3(db: sqlite3.Connection) -> None:
    """Undo migrations 3 -> 4 (the living map) and after on a store holding no history."""
    back_to_version_4(db)
    db.execute("DROP TABLE changes")
    db.execute("DROP INDEX objects_by_state")
    for column in ("state", "first_seen_t", "last_seen_t", "stays", "label_embeddings"):
        db.execute(f"ALTER TABLE objects DROP COLUMN {column}")
    for column in ("last_t", "last_pose"):
        db.execute(f"ALTER TABLE sessions DROP COLUMN {column}")
    db.execute("PRAGMA user_version = 3")


def test_a_version_1_store_opens_with_its_sessions_on_the_detections_backend(tmp_path):
    path = tmp_path / "semanticxr.db"
    with SqliteStore(path) as store:
        seeded(store)
        before = everything(store)
    with sqlite3.connect(path) as db:  # what a server before the perception column wrote
        back_to_version_3(db)
        db.execute("DROP INDEX sessions_by_last_use")
        db.execute("ALTER TABLE sessions DROP COLUMN last_used_at")
        db.execute("ALTER TABLE sessions DROP COLUMN perception")
        db.execute("PRAGMA user_version = 1")
    with SqliteStore(path) as store:
        assert everything(store)[1:] == before[1:]
        assert [s.perception for s in store.list_sessions()] == ["detections"]
        store.create_session(record("s2", perception="models"))
    with SqliteStore(path) as store:
        assert [s.perception for s in store.list_sessions()] == ["detections", "models"]
    with sqlite3.connect(path) as db:
        assert db.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION == 7


def test_a_version_2_store_counts_its_sessions_as_used_at_the_upgrade(tmp_path):
    """Retention never deletes a session for lack of a date: sessions stored before the
    last-use column count as used when the store is upgraded."""
    path = tmp_path / "semanticxr.db"
    with SqliteStore(path) as store:
        seeded(store)
        before = everything(store)
    with sqlite3.connect(path) as db:  # what a server before the last-use column wrote
        back_to_version_3(db)
        db.execute("DROP INDEX sessions_by_last_use")
        db.execute("ALTER TABLE sessions DROP COLUMN last_used_at")
        db.execute("PRAGMA user_version = 2")
    upgrade_started = time.time()
    with SqliteStore(path) as store:
        (rec,) = store.list_sessions()
        assert upgrade_started - 1 <= rec.last_used_at <= time.time() + 1
        assert everything(store)[1:] == before[1:]
        assert store.idle_sessions(upgrade_started - 1) == []


def test_a_newer_schema_version_is_refused_with_a_clear_error(tmp_path):
    path = tmp_path / "semanticxr.db"
    SqliteStore(path).close()
    with sqlite3.connect(path) as db:
        db.execute(f"PRAGMA user_version = {SCHEMA_VERSION + 1}")
    with pytest.raises(StoreVersionError, match="newer than this SemanticXR"):
        SqliteStore(path)


def test_an_unrelated_sqlite_database_is_refused(tmp_path):
    path = tmp_path / "other.db"
    with sqlite3.connect(path) as db:
        db.execute("CREATE TABLE notes (text TEXT)")
    with pytest.raises(StoreError, match="not a SemanticXR store"):
        SqliteStore(path)


# ---------------------------------------------------------------------- the URL
@pytest.mark.parametrize("absolute", [False, True])
def test_open_store_opens_sqlite_urls_with_relative_and_absolute_paths(
    tmp_path, monkeypatch, absolute
):
    monkeypatch.chdir(tmp_path)
    path = (tmp_path if absolute else Path(".")) / "d" / "x.sqlite3"
    url = sqlite_url(path)
    assert url == ("sqlite:////" if absolute else "sqlite:///") + str(path).lstrip("/")
    with open_store(url) as store:
        assert isinstance(store, SqliteStore)
        store.create_session(record("s1"))
    with SqliteStore(tmp_path / "d" / "x.sqlite3") as store:
        assert store.list_sessions() == [record("s1")]


@pytest.mark.parametrize(
    ("url", "named"),
    [
        ("mysql://db/semanticxr", "unknown scheme 'mysql'"),
        ("data/semanticxr.sqlite3", "must be a URL such as sqlite:///"),
        ("sqlite://data.db", "sqlite:///<relative path>"),
        ("sqlite:///", "sqlite:///<relative path>"),
        ("sqlite:///data/", "names a folder"),
    ],
)
def test_a_url_the_server_cannot_open_is_refused_naming_the_setting(tmp_path, url, named):
    with pytest.raises(StoreURLError, match="--store") as err:
        open_store(url)
    assert named in str(err.value)
    assert list(tmp_path.iterdir()) == []


def test_the_default_store_is_the_file_earlier_servers_wrote(tmp_path):
    """Existing data dirs (and Docker volumes) open unchanged."""
    data_dir = tmp_path / "data"
    with SqliteStore(data_dir / "semanticxr.sqlite3") as store:
        seeded(store)
        before = everything(store)
    url = ServerSettings(data_dir=str(data_dir)).store_url
    assert url == f"sqlite:///{data_dir}/semanticxr.sqlite3"
    with open_store(url) as store:
        assert everything(store) == before


def test_a_closed_store_says_so(store_url):
    store = open_store(store_url)
    store.close()
    store.close()
    with pytest.raises(StoreError, match="closed"):
        store.list_sessions()


def test_threads_can_commit_to_their_sessions_concurrently(store):
    sids = [f"t{i}" for i in range(4)]
    for sid in sids:
        store.create_session(record(sid))
    errors: list[BaseException] = []

    def work(sid: str) -> None:
        try:
            for seq in range(1, 21):
                store.commit_keyframe(
                    KeyframeCommit(sid, seq, [make_object(seq)], [], {"keyframes": seq}, 21)
                )
        except BaseException as exc:  # surfaced by the assertion below
            errors.append(exc)

    threads = [threading.Thread(target=work, args=(sid,)) for sid in sids]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=30)
    assert errors == [] and not any(t.is_alive() for t in threads)
    for sid in sids:
        assert len(store.load_objects(sid)) == 20 and store.load_delta_log(sid).seq == 20


# ---------------------------------------------------------------------- kill -9
# One source for the workload: the child runs it, the parent recomputes what it must find.
CRASH_WORKLOAD = """
from collections import Counter

import numpy as np

from app.mapping.object import MapObject


def keyframe_changes(k):
    '''Keyframe k creates object k, changes object 1 and removes object k - 4.'''
    return sorted({1, k}), ([k - 4] if k - 4 > 1 else [])


def object_at(oid, version):
    rng = np.random.default_rng([oid, version])
    obj = MapObject(id=oid, embedding_sum=rng.standard_normal(384).astype(np.float32),
                    label_counts=Counter({f"label-{oid}": version}), n_obs=version,
                    frames_seen=version, first_seen=oid, last_seen=version, version=version,
                    confirmed=True)
    obj.set_points(rng.standard_normal((2000, 3)).astype(np.float32), 0.025)
    return obj
"""

CRASH_CHILD = (
    CRASH_WORKLOAD
    + """
import sys

from app.store import KeyframeCommit, SessionRecord, open_store

store = open_store(sys.argv[1])
store.create_session(SessionRecord("crash", "crash", "semanticxr", {}, "hash", 0.0))
for k in range(1, 1_000_000):
    upserted, removed = keyframe_changes(k)
    store.commit_keyframe(KeyframeCommit("crash", k, [object_at(i, k if i == 1 else i) for i in upserted],
                                         removed, {"frames": 5 * k, "keyframes": k}, k + 1))
    print(f"committed {k}", flush=True)
"""
)


def _read_lines(stream, lines: queue.Queue) -> None:
    for line in stream:
        lines.put(line.strip())
    lines.put(None)  # EOF


def test_every_acknowledged_keyframe_survives_kill_9(store_url):
    child = subprocess.Popen(
        [sys.executable, "-c", CRASH_CHILD, store_url],
        cwd=REPO_ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    lines: queue.Queue = queue.Queue()
    reader = threading.Thread(target=_read_lines, args=(child.stdout, lines), daemon=True)
    reader.start()
    printed: list[str] = []
    try:
        while len(printed) < 25:  # kill it mid-stream, while it is still committing
            line = lines.get(timeout=20)
            assert line is not None, f"the child exited early: {child.stderr.read()}"
            printed.append(line)
        child.send_signal(signal.SIGKILL)
        assert child.wait(timeout=10) == -signal.SIGKILL
        reader.join(timeout=10)
        while (line := lines.get(timeout=1)) is not None:  # what it printed before dying
            printed.append(line)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait(timeout=10)
        child.stdout.close()
        child.stderr.close()
    last_acked = int(printed[-1].removeprefix("committed "))
    assert printed == [f"committed {k}" for k in range(1, last_acked + 1)]

    workload: dict = {}
    exec(CRASH_WORKLOAD, workload)
    with open_store(store_url) as store:
        log = store.load_delta_log("crash")
        objects = store.load_objects("crash")
        (session,) = store.list_sessions()
    # At most one commit can have returned without its line printed.
    assert last_acked <= log.seq <= last_acked + 1
    expected_log = DeltaLog()
    expected_live: set[int] = set()
    for k in range(1, log.seq + 1):
        upserted, removed = workload["keyframe_changes"](k)
        expected_log.commit(upserted, removed)
        expected_live = (expected_live | set(upserted)) - set(removed)
    assert log.state() == expected_log.state()
    assert [fields(o) for o in objects] == [
        fields(workload["object_at"](i, log.seq if i == 1 else i)) for i in sorted(expected_live)
    ]
    assert (session.keyframes, session.frames, session.next_object_id) == (
        log.seq,
        5 * log.seq,
        log.seq + 1,
    )


# ---------------------------------------------------------------------- against the model
commits = st.lists(
    st.tuples(st.sets(st.integers(1, 10), max_size=4), st.sets(st.integers(1, 10), max_size=3)),
    max_size=15,
)


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(history=commits, max_tombstones=st.sampled_from([3, 100_000]))
def test_the_stored_delta_log_equals_an_in_memory_one_fed_the_same_commits(
    store_url, history, max_tombstones
):
    """Fed the same commits, and trimmed whenever the in-memory log raises its floor (as the
    server does), the store reloads to the same log."""
    model = DeltaLog(max_tombstones=max_tombstones)
    sid = f"s{next(EXAMPLES)}"
    with open_store(store_url) as store:
        store.create_session(record(sid))
        for n, (upserted, removed) in enumerate(history, 1):
            seq = model.commit(upserted, removed)
            objects = [make_object(i, version=seq, n_points=3) for i in sorted(upserted)]
            store.commit_keyframe(
                KeyframeCommit(sid, seq, objects, sorted(removed), {"keyframes": n}, 11)
            )
            store.trim_tombstones(sid, model.floor)
    with open_store(store_url) as store:  # what a restarted server would load
        log = store.load_delta_log(sid)
        objects = store.load_objects(sid)

    assert (log.seq, log.floor) == (model.seq, model.floor)
    assert log.state() == model.state()
    for since in [None, *range(-1, model.seq + 2)]:
        assert log.since(since) == model.since(since), since
    assert [o.id for o in objects] == model.live_ids()
    upserted_at = model.state()["upserted_at"]
    assert all(o.version == upserted_at[o.id] for o in objects)
