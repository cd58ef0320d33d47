"""Writes the store fixtures of this folder with the store code on PYTHONPATH; run once,
with the code whose stores the fixtures stand for (they were written by the store of commit
7072f07, before the SQL of both stores was written once):

    PYTHONPATH=<that checkout> python tests/data/store/write_fixtures.py

- v6.sqlite3: a store written through `SqliteStore` (schema 6), v6.sqlite3.json what it
  read back (`store_snapshot.snapshot`);
- v1.sqlite3: a store at schema 1 (its tables as `SqliteStore` creates them, rows written
  directly), v1.sqlite3.json what `SqliteStore` read back after migrating a copy of it;
- v6.postgres.sql, v4.postgres.sql: the same for PostgreSQL (`pg_dump --column-inserts`
  of a store written through `PostgresStore`, and of one at schema 4, its first), with
  what `PostgresStore` read back (after migrating a restored copy, for v4).
A PostgreSQL cluster is started as the tests start it (tests/pg.py).
"""

from __future__ import annotations

import json
import os
import shutil
import sqlite3
import subprocess
import sys
import tempfile
from collections import Counter
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
TESTS = HERE.parents[1]
sys.path[:0] = [str(TESTS), str(TESTS / "app" / "store")]

from pg import PG_PASSWORD, start_cluster  # noqa: E402
from store_snapshot import DONE_KEYS, snapshot  # noqa: E402

from app.mapping.object import Change, MapObject, Stay  # noqa: E402
from app.store import SessionRecord, open_store, postgres, rows, sqlite, sqlite_url  # noqa: E402

DIM = 8


def make_object(oid: int, version: int = 1, state: str = "present", n_points: int = 6):
    rng = np.random.default_rng([oid, version])
    obj = MapObject(
        id=oid,
        embedding_sum=rng.standard_normal(DIM).astype(np.float32),
        label_counts=Counter({f"label-{oid}": version + 1, "chair": 1}),
        n_obs=version + 2,
        frames_seen=version + 1,
        first_seen=oid,
        last_seen=oid + version,
        version=version,
        confirmed=True,
        label_embeddings={f"label-{oid}": rng.standard_normal(DIM).astype(np.float32)},
        first_seen_t=0.5 * oid,
        last_seen_t=0.5 * oid + version,
        state=state,
        stays=[Stay(1.0 * oid, 2.0 * oid, (oid, 0.5, -1.0), (oid - 1, 0, -2, oid + 1, 1, 0))],
    )
    obj.set_points(rng.standard_normal((n_points, 3)).astype(np.float32), 0.025 * oid)
    return obj


def record(sid: str, **changes) -> SessionRecord:
    values = dict(
        session_id=sid,
        name=f"the {sid}",
        mode="semanticxr",
        knobs={"max_object_points_server": 2000, "skip_mapping_set": ["wall"], "x": None},
        token_hash=f"sha256:{sid}",
        created_at=1_700_000_000.25,
        perception="detections",
    )
    values.update(changes)
    return SessionRecord(**values)


POSE = np.arange(16, dtype=np.float32).reshape(4, 4) / 7


def write_store(store) -> None:
    """Three sessions through the store's API: a living map with history, a session whose
    up was inferred, an empty one; two shards."""
    store.create_session(record("kitchen", up="+y", up_source="set", created_at=1_700_000_001.5))
    store.create_session(record("hall", name="Halle – Flur ✓", perception="depth"))
    store.create_session(record("empty", created_at=1_600_000_000.0, frames=3))
    store.commit_keyframe(
        "kitchen", 1, [make_object(i) for i in (1, 2, 3, 4)], [],
        {"frames": 10, "keyframes": 1, "bytes_in": 1000, "bytes_out": 200}, 5,
        changes=[Change(i, "added", 1.0 + i, f"label-{i}", None, (i, 0.5, -1.0)) for i in (1, 2, 3, 4)],
        last_t=1.5, last_pose=POSE, done=("left", 1, b"ack-1"),
    )  # fmt: skip
    epoch = store.claim_session("kitchen", "shard-a", 30.0, now=1_750_000_000.0)
    store.commit_keyframe(
        "kitchen", 2, [make_object(1, version=2)], [3, 4],
        {"frames": 20, "keyframes": 2, "sightings": 4}, 5, 1_750_000_010.0,
        retired=[make_object(4, version=2, state="removed")],
        changes=[
            Change(1, "moved", 6.0, "label-1", (1, 0.5, -1.0), (1.5, 0.5, -1.0)),
            Change(4, "removed", 6.5, "label-4", (4, 0.5, -1.0), None),
        ],
        last_t=6.5, last_pose=POSE.T, epoch=epoch, done=("left", 2, b"ack-2"),
    )  # fmt: skip
    store.commit_keyframe(
        "kitchen", 3, [make_object(5)], [], {"frames": 25, "keyframes": 3}, 6,
        changes=[Change(5, "added", 9.0, "label-5", None, (5, 0.5, -1.0))],
        retracted_added=[2], epoch=epoch, done=("right", 7, b"\x00ack-7\xff"),
    )  # fmt: skip
    store.commit_keyframe("hall", 1, [make_object(1)], [], {"frames": 2}, 2, inferred_up="-z")
    store.heartbeat_shard("shard-a", "http://10.0.0.1:8000", now=1_750_000_020.0)
    store.heartbeat_shard("shard-b", "http://10.0.0.2:8000", now=1_750_000_021.0)


def write_json(path: Path, value: dict) -> None:
    path.write_text(json.dumps(value, indent=1, ensure_ascii=False) + "\n")


def old_session_rows():
    """(sessions row at schema 1, objects rows at schema 1, tombstones) for the v1 store."""
    objects = [make_object(i) for i in (1, 2)]
    session = ("old", "an old session", "semanticxr", rows.to_json({"x": 1}), "sha256:old",
               1_650_000_000.5, 7, 2, 700, 70, 4, 2, 1)  # fmt: skip
    object_rows = [
        ("old", seq, *rows.object_to_row(obj)[:12])
        for seq, obj in zip((1, 2), objects, strict=True)
    ]
    return session, object_rows, [("old", 3, 2)]


def write_sqlite(folder: Path) -> None:
    path = folder / "v6.sqlite3"
    path.unlink(missing_ok=True)
    with open_store(sqlite_url(path)) as store:
        write_store(store)
        write_json(folder / "v6.sqlite3.json", snapshot(store))
    # Fold the WAL in: the fixture is the one file.
    with sqlite3.connect(path) as db:
        db.execute("PRAGMA journal_mode=DELETE")
    assert not Path(f"{path}-wal").exists()

    v1 = folder / "v1.sqlite3"
    v1.unlink(missing_ok=True)
    session, object_rows, tombstones = old_session_rows()
    with sqlite3.connect(v1) as db:
        for statement in sqlite._SCHEMA:
            db.execute(statement)
        db.execute("INSERT INTO sessions VALUES (" + ", ".join("?" * 13) + ")", session)
        db.executemany("INSERT INTO objects VALUES (" + ", ".join("?" * 14) + ")", object_rows)
        db.executemany("INSERT INTO tombstones VALUES (?, ?, ?)", tombstones)
        db.execute("PRAGMA user_version = 1")
    db.close()
    with tempfile.TemporaryDirectory() as tmp:
        copy = Path(tmp) / "v1.sqlite3"
        shutil.copy(v1, copy)
        with open_store(sqlite_url(copy)) as store:
            write_json(folder / "v1.sqlite3.json", snapshot(store))


def pg_dump(cluster, database: str) -> str:
    env = {**os.environ, "PGPASSWORD": PG_PASSWORD}
    done = subprocess.run(
        [str(cluster.bin_dir / "pg_dump"), "--column-inserts", "--no-owner", "--no-privileges",
         "-h", "127.0.0.1", "-p", str(cluster.port), "-U", "postgres", database],
        env=env, capture_output=True, text=True, check=True,
    )  # fmt: skip
    # Without psql's meta-commands (\restrict ...): the dump is plain SQL any client runs.
    return "".join(line for line in done.stdout.splitlines(True) if not line.startswith("\\"))


def restore(url: str, dump: str) -> None:
    import psycopg

    with psycopg.connect(url, autocommit=True) as conn:
        conn.execute(dump)


def write_postgres(folder: Path) -> None:
    import psycopg

    cluster = start_cluster()
    try:
        name = cluster.create_database("v6")
        with open_store(cluster.url(name)) as store:
            write_store(store)
            write_json(folder / "v6.postgres.sql.json", snapshot(store))
        (folder / "v6.postgres.sql").write_text(pg_dump(cluster, name))

        name = cluster.create_database("v4")
        session, object_rows, tombstones = old_session_rows()
        with psycopg.connect(cluster.url(name), autocommit=True) as conn:
            for statement in postgres._SCHEMA:
                conn.execute(statement)
            conn.execute("INSERT INTO schema_version (version) VALUES (4)")
            conn.execute(
                "INSERT INTO sessions (session_id, name, mode, knobs, token_hash, created_at,"
                " frames, keyframes, bytes_in, bytes_out, next_object_id, seq, delta_floor,"
                " perception, last_used_at, last_t, last_pose)"
                " VALUES (" + ", ".join(["%s"] * 17) + ")",
                (*session, "depth", 1_650_000_100.0, 3.5, rows.pose_to_blob(POSE)),
            )
            objects = [make_object(1), make_object(2, state="removed")]
            for seq, obj in zip((1, 2), objects, strict=True):
                conn.execute(
                    f"INSERT INTO objects (session_id, change_seq, {rows.OBJECT_COLUMNS})"
                    " VALUES (" + ", ".join(["%s"] * 19) + ")",
                    ("old", seq, *rows.object_to_row(obj)),
                )
            conn.execute("INSERT INTO tombstones VALUES ('old', 3, 2), ('old', 2, 2)")
            conn.execute(
                f"INSERT INTO changes (session_id, {rows.CHANGE_COLUMNS})"
                " VALUES ('old', 1, 'added', 1.0, 'label-1', NULL, NULL, NULL, 1, 2, 3, 1),"
                " ('old', 2, 'removed', 2.0, 'label-2', 4, 5, 6, NULL, NULL, NULL, 2)"
            )
        (folder / "v4.postgres.sql").write_text(pg_dump(cluster, name))
        copy = cluster.create_database("v4_copy")
        restore(cluster.url(copy), (folder / "v4.postgres.sql").read_text())
        with open_store(cluster.url(copy)) as store:
            write_json(folder / "v4.postgres.sql.json", snapshot(store))
    finally:
        cluster.remove()


if __name__ == "__main__":
    assert DONE_KEYS
    write_sqlite(HERE)
    write_postgres(HERE)
    print("written:", *sorted(p.name for p in HERE.iterdir() if p.suffix != ".py"))
