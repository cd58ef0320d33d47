"""A session's up axis in the stores (schema 6): set at creation, inferred in a keyframe's
commit, refused when it names no axis, and NULL for the sessions of a schema 5 store, on
real SQLite files and a real PostgreSQL database (conftest.py)."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest
from test_store import make_object, query, record

from app.store import KeyframeCommit, open_store, postgres, sqlite
from app.store.dialect import POSTGRES, SQLITE
from app.store.schema import statements


def test_a_set_up_comes_back_after_a_reopen(store, store_url):
    store.create_session(record("set", up="+y", up_source="set"))
    store.create_session(record("unset"))
    with open_store(store_url) as again:
        assert [(r.up, r.up_source) for r in again.list_sessions()] == [
            ("+y", "set"),
            (None, None),
        ]
        assert [(e.record.up, e.record.up_source) for e in again.list_stored()] == [
            ("+y", "set"),
            (None, None),
        ]


def test_an_inferred_up_lands_with_its_keyframe(store, store_url):
    store.create_session(record("s1"))
    store.commit_keyframe(
        KeyframeCommit("s1", 1, [make_object(1)], [], {"keyframes": 1}, 2, inferred_up="-z")
    )
    store.commit_keyframe(
        KeyframeCommit("s1", 2, [make_object(1, version=2)], [], {"keyframes": 2}, 2)
    )
    with open_store(store_url) as again:
        rec = again.load_session("s1")
        assert (rec.up, rec.up_source, rec.keyframes) == ("-z", "inferred", 2)


@pytest.mark.parametrize(
    "up, source", [("y", "set"), ("+Y", "set"), ("up", "set"), ("+z", None), ("+z", "default")]
)
def test_an_up_that_names_no_axis_or_source_is_refused(store, up, source):
    with pytest.raises(ValueError, match="up"):
        store.create_session(record("bad", up=up, up_source=source))
    assert store.list_sessions() == []


def test_an_inferred_up_that_names_no_axis_refuses_the_whole_commit(store):
    store.create_session(record("s1"))
    with pytest.raises(ValueError, match="up must be one of"):
        store.commit_keyframe(
            KeyframeCommit("s1", 1, [make_object(1)], [], {"keyframes": 1}, 2, inferred_up="z")
        )
    assert store.load_objects("s1") == [] and store.load_session("s1").up is None


# ---------------------------------------------------------------------- from schema 5
def make_version_5_store(store_url: str) -> None:
    """An empty store as a server at schema 5 made it, holding one session."""
    if store_url.startswith("sqlite:///"):
        path = Path(store_url.removeprefix("sqlite:///"))
        path.parent.mkdir(parents=True, exist_ok=True)
        with sqlite3.connect(path) as db:
            for statement in statements(SQLITE, to_version=5):
                db.execute(statement)
            db.execute("PRAGMA user_version = 5")
    else:
        import psycopg

        with psycopg.connect(store_url) as conn:
            for statement in (postgres._VERSION_TABLE, *statements(POSTGRES, to_version=5)):
                conn.execute(statement)
            conn.execute("INSERT INTO schema_version (version) VALUES (5)")
    query(
        store_url,
        "INSERT INTO sessions (session_id, name, mode, perception, knobs, token_hash, created_at,"
        " frames, keyframes, bytes_in, bytes_out, next_object_id, seq, delta_floor, last_used_at,"
        " sightings, epoch) VALUES ('old', 'old', 'semanticxr', 'detections', '{}', 'h', 1.0,"
        " 9, 3, 0, 0, 1, 2, 0, 5.0, 4, 7) RETURNING session_id",
    )


def schema_version(store_url: str) -> int:
    if store_url.startswith("sqlite:///"):
        return query(store_url, "PRAGMA user_version")[0][0]
    return query(store_url, "SELECT version FROM schema_version")[0][0]


def test_a_version_5_store_opens_with_its_sessions_on_the_default_up(store_url):
    assert sqlite.SCHEMA_VERSION == postgres.SCHEMA_VERSION == 7
    make_version_5_store(store_url)
    with open_store(store_url) as store:
        rec = store.load_session("old")
        assert (rec.up, rec.up_source) == (None, None)
        assert (rec.frames, rec.sightings, rec.epoch, store.load_delta_log("old").seq) == (
            9,
            4,
            7,
            2,
        )
        store.commit_keyframe(
            KeyframeCommit("old", 3, [], [], {"keyframes": 4}, 1, inferred_up="+y")
        )
        store.create_session(record("new", up="-x", up_source="set"))
    assert schema_version(store_url) == 7
    with open_store(store_url) as store:
        assert [(r.session_id, r.up, r.up_source) for r in store.list_sessions()] == [
            ("old", "+y", "inferred"),
            ("new", "-x", "set"),
        ]


def test_an_upgraded_sqlite_store_has_the_schema_a_new_one_has(tmp_path):
    make_version_5_store(f"sqlite:///{tmp_path / 'old.db'}")
    open_store(f"sqlite:///{tmp_path / 'old.db'}").close()
    open_store(f"sqlite:///{tmp_path / 'new.db'}").close()

    def schema(path: Path) -> list:
        with sqlite3.connect(path) as db:
            return db.execute(
                "SELECT type, name, sql FROM sqlite_master WHERE name != 'sqlite_sequence'"
                " ORDER BY name"
            ).fetchall()

    assert schema(tmp_path / "old.db") == schema(tmp_path / "new.db")
