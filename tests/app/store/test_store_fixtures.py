"""Stores written by earlier code open, migrate and read back the same.

The fixtures in tests/data/store/ were written by the store code before its SQL was written
once for both databases (tests/data/store/write_fixtures.py says how): a SQLite file and a
PostgreSQL dump at schema 6, a SQLite file at schema 1 and a PostgreSQL dump at schema 4
(the first each database had), each with what that code read back from it. Each migrates
to today's schema (7: the sessions' text tower, minilm for all of theirs).
"""

from __future__ import annotations

import json
import re
import shutil
import sqlite3
import time
from pathlib import Path

import psycopg
from store_snapshot import snapshot

from app.store import open_store, sqlite_url
from app.store.postgres import PostgresStore
from app.store.sqlite import SCHEMA_VERSION, SqliteStore

FIXTURES = Path(__file__).resolve().parents[2] / "data" / "store"


def expected(name: str) -> dict:
    """What the earlier code read back from fixture `name`, as today's code reads it: the
    columns that came after the fixture with the values its rows get (schema 7: every
    session's text tower is minilm)."""
    shot = json.loads((FIXTURES / f"{name}.json").read_text())
    for session in shot["sessions"]:
        for key in ("record", "loaded_record"):
            session[key] = {"text_tower": "minilm", "tower_sha256": None, **session[key]}
    return shot


def without_last_use(shot: dict) -> dict:
    """The snapshot with each session's last use taken out (set to the upgrade's time by the
    migration to schema 3)."""
    for session in shot["sessions"]:
        session["record"]["last_used_at"] = session["loaded_record"]["last_used_at"] = None
    return shot


def restore(url: str, name: str) -> None:
    with psycopg.connect(url, autocommit=True) as conn:
        conn.execute((FIXTURES / name).read_text())


# ---------------------------------------------------------------------- schema as text
def sqlite_schema(path: Path) -> list[tuple]:
    """Every table and index with its SQL (comments and spacing aside), and the version."""
    with sqlite3.connect(path) as db:
        rows = db.execute("SELECT type, name, sql FROM sqlite_master ORDER BY name").fetchall()
        version = db.execute("PRAGMA user_version").fetchone()[0]
    db.close()
    return [(kind, name, _tokens(sql)) for kind, name, sql in rows] + [("version", version)]


def _tokens(sql: str | None) -> str | None:
    if sql is None:
        return None
    sql = re.sub(r"--[^\n]*", "", sql)
    sql = re.sub(r"\s+", " ", sql)
    return re.sub(r"\s*([(),])\s*", r"\1", sql).strip()


def postgres_schema(url: str) -> dict:
    """Columns (type, null, default, collation, storage, identity, order), constraints,
    indexes and the version of the store's tables."""
    with psycopg.connect(url) as conn:
        columns = conn.execute(
            "SELECT c.relname, a.attnum, a.attname, format_type(a.atttypid, a.atttypmod),"
            " a.attnotnull, pg_get_expr(d.adbin, d.adrelid), co.collname, a.attstorage,"
            " a.attidentity"
            " FROM pg_attribute a JOIN pg_class c ON c.oid = a.attrelid"
            " JOIN pg_namespace n ON n.oid = c.relnamespace"
            " LEFT JOIN pg_attrdef d ON d.adrelid = a.attrelid AND d.adnum = a.attnum"
            " LEFT JOIN pg_collation co ON co.oid = a.attcollation AND a.attcollation <> 100"
            " WHERE n.nspname = current_schema() AND c.relkind = 'r' AND a.attnum > 0"
            " AND NOT a.attisdropped ORDER BY 1, 2"
        ).fetchall()
        constraints = conn.execute(
            "SELECT c.relname, k.conname, k.contype, pg_get_constraintdef(k.oid)"
            " FROM pg_constraint k JOIN pg_class c ON c.oid = k.conrelid"
            " JOIN pg_namespace n ON n.oid = c.relnamespace"
            " WHERE n.nspname = current_schema() ORDER BY 1, 2"
        ).fetchall()
        indexes = conn.execute(
            "SELECT tablename, indexname, indexdef FROM pg_indexes"
            " WHERE schemaname = current_schema() ORDER BY 1, 2"
        ).fetchall()
        version = conn.execute("SELECT version FROM schema_version").fetchall()
    return {"columns": columns, "constraints": constraints, "indexes": indexes, "version": version}


# ---------------------------------------------------------------------- SQLite
def test_a_sqlite_store_of_schema_6_opens_and_reads_the_same(tmp_path):
    path = tmp_path / "v6.sqlite3"
    shutil.copy(FIXTURES / "v6.sqlite3", path)
    with SqliteStore(path) as store:
        assert snapshot(store) == expected("v6.sqlite3")
    new = tmp_path / "new.sqlite3"
    SqliteStore(new).close()
    assert sqlite_schema(path) == sqlite_schema(new)


def test_a_sqlite_store_of_schema_1_migrates_and_reads_the_same(tmp_path):
    path = tmp_path / "v1.sqlite3"
    shutil.copy(FIXTURES / "v1.sqlite3", path)
    opened_at = time.time()
    with SqliteStore(path) as store:
        shot = snapshot(store)
    (record,) = [session["record"] for session in shot["sessions"]]
    assert opened_at - 1 <= record["last_used_at"] <= time.time() + 1  # the upgrade's time
    assert without_last_use(shot) == without_last_use(expected("v1.sqlite3"))
    assert sqlite_schema(path)[-1] == ("version", SCHEMA_VERSION)


def test_a_new_sqlite_store_has_the_schema_earlier_code_made(tmp_path):
    fixture = tmp_path / "v6.sqlite3"
    shutil.copy(FIXTURES / "v6.sqlite3", fixture)
    migrated = tmp_path / "v1.sqlite3"
    shutil.copy(FIXTURES / "v1.sqlite3", migrated)
    SqliteStore(migrated).close()
    SqliteStore(fixture).close()
    new = tmp_path / "new.sqlite3"
    with open_store(sqlite_url(new)):
        pass
    assert sqlite_schema(new) == sqlite_schema(fixture) == sqlite_schema(migrated)


# ---------------------------------------------------------------------- PostgreSQL
def test_a_postgres_store_of_schema_6_opens_and_reads_the_same(fresh_pg_url):
    restore(fresh_pg_url, "v6.postgres.sql")
    with PostgresStore(fresh_pg_url) as store:
        assert snapshot(store) == expected("v6.postgres.sql")
    assert postgres_schema(fresh_pg_url)["version"] == [(SCHEMA_VERSION,)]


def test_a_postgres_store_of_schema_4_migrates_and_reads_the_same(fresh_pg_url):
    restore(fresh_pg_url, "v4.postgres.sql")
    with PostgresStore(fresh_pg_url) as store:
        assert snapshot(store) == expected("v4.postgres.sql")
    assert postgres_schema(fresh_pg_url)["version"] == [(SCHEMA_VERSION,)]


def test_a_new_postgres_store_has_the_schema_earlier_code_made(pg_cluster):
    urls = {kind: pg_cluster.url(pg_cluster.create_database(kind)) for kind in ("v6", "v4", "new")}
    restore(urls["v6"], "v6.postgres.sql")
    restore(urls["v4"], "v4.postgres.sql")
    for url in urls.values():
        PostgresStore(url).close()
    schemas = {kind: postgres_schema(url) for kind, url in urls.items()}
    assert schemas["new"] == schemas["v6"] == schemas["v4"]


def test_both_stores_read_the_same_from_the_fixtures_they_wrote():
    assert expected("v6.postgres.sql") == expected("v6.sqlite3")
