"""A session's text tower in the stores (schema 7): minilm or static with the SHA-256 of the
tower file it was created with, kept across a reopen and listed, refused when it names no
tower or a static one without its hash (by the code and by the database itself), and
"minilm" for the sessions of a schema 6 store, on real SQLite files and a real PostgreSQL
database (conftest.py)."""

from __future__ import annotations

import hashlib
import sqlite3
from pathlib import Path

import pytest
from test_store import make_object, query, record

from app.store import KeyframeCommit, open_store, postgres, sqlite
from app.store.dialect import POSTGRES, SQLITE
from app.store.schema import statements

SHA = hashlib.sha256(b"a tower").hexdigest()


def test_a_static_session_keeps_its_towers_hash_across_a_reopen(store, store_url):
    store.create_session(record("static", text_tower="static", tower_sha256=SHA))
    store.create_session(record("plain"))
    store.commit_keyframe(KeyframeCommit("static", 1, [make_object(1)], [], {"keyframes": 1}, 2))
    with open_store(store_url) as again:
        assert [(r.text_tower, r.tower_sha256) for r in again.list_sessions()] == [
            ("minilm", None),  # "plain" before "static": same created_at, then by id
            ("static", SHA),
        ]
        assert [(e.record.text_tower, e.record.tower_sha256) for e in again.list_stored()] == [
            ("minilm", None),
            ("static", SHA),
        ]
        rec = again.load_session("static")
        assert (rec.text_tower, rec.tower_sha256, rec.keyframes) == ("static", SHA, 1)


@pytest.mark.parametrize(
    "tower, sha, message",
    [
        ("clip", None, "text_tower must be one of minilm, static"),
        ("static", None, "needs its file's sha256"),
        ("static", SHA.upper(), "needs its file's sha256"),
        ("static", SHA[:63], "needs its file's sha256"),
        ("minilm", SHA, "only for a static text tower"),
    ],
)
def test_a_tower_that_names_no_tower_or_no_hash_is_refused(store, tower, sha, message):
    with pytest.raises(ValueError, match=message):
        store.create_session(record("bad", text_tower=tower, tower_sha256=sha))
    assert store.list_sessions() == []


@pytest.mark.parametrize(
    "values", ["'clip', NULL", "'static', NULL", f"'minilm', '{SHA}'", "'static', 'short'"]
)
def test_the_database_itself_refuses_a_row_without_a_coherent_tower(store, store_url, values):
    """What another writer (or a hand-edited row) could put there is refused by the checks."""
    with pytest.raises(Exception, match="(?i)check"):
        query(
            store_url,
            "INSERT INTO sessions (session_id, name, mode, perception, knobs, token_hash,"
            " created_at, frames, keyframes, bytes_in, bytes_out, next_object_id, seq,"
            " delta_floor, last_used_at, sightings, epoch, text_tower, tower_sha256) VALUES"
            f" ('x', 'x', 'semanticxr', 'detections', '{{}}', 'h', 1.0, 0, 0, 0, 0, 1, 0, 0,"
            f" 1.0, 0, 0, {values}) RETURNING session_id",
        )


# ---------------------------------------------------------------------- from schema 6
def make_version_6_store(store_url: str) -> None:
    """An empty store as a server at schema 6 made it, holding one session."""
    if store_url.startswith("sqlite:///"):
        path = Path(store_url.removeprefix("sqlite:///"))
        path.parent.mkdir(parents=True, exist_ok=True)
        with sqlite3.connect(path) as db:
            for statement in statements(SQLITE, to_version=6):
                db.execute(statement)
            db.execute("PRAGMA user_version = 6")
    else:
        import psycopg

        with psycopg.connect(store_url) as conn:
            for statement in (postgres._VERSION_TABLE, *statements(POSTGRES, to_version=6)):
                conn.execute(statement)
            conn.execute("INSERT INTO schema_version (version) VALUES (6)")
    query(
        store_url,
        "INSERT INTO sessions (session_id, name, mode, perception, knobs, token_hash, created_at,"
        " frames, keyframes, bytes_in, bytes_out, next_object_id, seq, delta_floor, last_used_at,"
        " sightings, epoch, up, up_source) VALUES ('old', 'old', 'semanticxr', 'detections',"
        " '{}', 'h', 1.0, 9, 3, 0, 0, 1, 2, 0, 5.0, 4, 7, '+y', 'set') RETURNING session_id",
    )


def schema_version(store_url: str) -> int:
    if store_url.startswith("sqlite:///"):
        return query(store_url, "PRAGMA user_version")[0][0]
    return query(store_url, "SELECT version FROM schema_version")[0][0]


def test_a_version_6_store_opens_with_its_sessions_on_minilm(store_url):
    assert sqlite.SCHEMA_VERSION == postgres.SCHEMA_VERSION == 7
    make_version_6_store(store_url)
    with open_store(store_url) as store:
        rec = store.load_session("old")
        assert (rec.text_tower, rec.tower_sha256) == ("minilm", None)
        assert (rec.up, rec.up_source, rec.frames, rec.sightings, rec.epoch) == (
            "+y",
            "set",
            9,
            4,
            7,
        )
        store.create_session(record("new", text_tower="static", tower_sha256=SHA))
    assert schema_version(store_url) == 7
    with open_store(store_url) as store:
        assert [(r.session_id, r.text_tower, r.tower_sha256) for r in store.list_sessions()] == [
            ("old", "minilm", None),
            ("new", "static", SHA),
        ]


def test_an_upgraded_sqlite_store_has_the_schema_a_new_one_has(tmp_path):
    make_version_6_store(f"sqlite:///{tmp_path / 'old.db'}")
    open_store(f"sqlite:///{tmp_path / 'old.db'}").close()
    open_store(f"sqlite:///{tmp_path / 'new.db'}").close()

    def schema(path: Path) -> list:
        with sqlite3.connect(path) as db:
            return db.execute(
                "SELECT type, name, sql FROM sqlite_master WHERE name != 'sqlite_sequence'"
                " ORDER BY name"
            ).fetchall()

    assert schema(tmp_path / "old.db") == schema(tmp_path / "new.db")
