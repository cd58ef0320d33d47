"""What only the PostgreSQL store has: its URLs, its schema in a shared database, a server
that stops and restarts under it, and a real SemanticXR server keeping its sessions in it.

The behaviour both stores share is tested against each in test_store.py and
test_store_living.py. These tests use the test session's throwaway cluster (tests/pg.py) and
skip, saying why, where PostgreSQL cannot be found (the URL checks need no server).
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections.abc import Callable

import httpx
import msgpack
import psycopg
import pytest
import websockets
from analytic_world import KITCHEN
from devices import TIMEOUT_S, frame_message
from pg import PG_PASSWORD
from test_store import everything, make_object, query, record, seeded

from app.server.settings import ServerSettings, SettingsError
from app.store import (
    KeyframeCommit,
    StoreError,
    StoreUnavailableError,
    StoreURLError,
    StoreVersionError,
    open_store,
    postgres,
    redact_url,
    sqlite,
)
from app.store.postgres import PostgresStore

CONNECT_TIMEOUT_S = 2
"""The tests' connect_timeout (libpq's smallest): how long a call may wait for a server."""
MARGIN_S = 3.0
"""Time a refused call may take beyond CONNECT_TIMEOUT_S on a loaded machine."""
RECOVERY_S = 20.0


def with_timeout(url: str) -> str:
    return f"{url}?connect_timeout={CONNECT_TIMEOUT_S}"


def execute(url: str, statement: str) -> None:
    """Run one statement on the database at `url`, outside any store."""
    with psycopg.connect(url, autocommit=True) as conn:
        conn.execute(statement)


def first_success(call: Callable[[], object], timeout_s: float = RECOVERY_S) -> object:
    """`call()` again until it does not raise StoreUnavailableError (each try waits at most
    the connect timeout: no sleep needed); AssertionError after `timeout_s`."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return call()
        except StoreUnavailableError:
            if time.monotonic() > deadline:
                raise AssertionError(f"still unavailable after {timeout_s:g} s") from None


# ---------------------------------------------------------------------- URLs
@pytest.mark.parametrize(
    ("url", "named"),
    [
        ("postgresql://semanticxr:s3cret@db:notaport/maps", "must be a number from 1 to 65535"),
        ("postgres://semanticxr:s3cret@db:99999/maps", "must be a number from 1 to 65535"),
        ("postgresql://semanticxr:s3cret@db/maps?colour=blue", 'query parameter: "colour"'),
        ("postgresql://semanticxr:s3cret@db:5432", "names no database"),
        ("postgresql://semanticxr:s3/cret@db/maps", "percent-encoded"),
    ],
    ids=["port-not-a-number", "port-too-large", "unknown-parameter", "no-database", "raw-slash"],
)
def test_a_malformed_postgresql_url_is_refused_naming_the_setting_not_the_password(url, named):
    with pytest.raises(StoreURLError, match="--store") as err:
        open_store(url)
    assert named in str(err.value)
    assert "cret" not in str(err.value) and "semanticxr:***@db" in str(err.value)
    with pytest.raises(SettingsError, match="--store"):  # the server refuses to start
        ServerSettings(store=url)


@pytest.mark.parametrize(
    ("url", "shown"),
    [
        ("postgresql://me:s3cret@db:5432/maps", "postgresql://me:***@db:5432/maps"),
        ("postgres://me:s3cret@db/maps?sslmode=require", "postgres://me:***@db/maps?sslmode=require"),
        ("postgresql://db/maps?user=me&password=s3cret", "postgresql://db/maps?user=me&password=***"),
        ("postgresql://me:s3/cr@t?@db/maps", "postgresql://me:***@db/maps"),
        ("postgresql:///maps?host=/run/pg&sslpassword=s3cret", "postgresql:///maps?host=/run/pg&sslpassword=***"),
        ("host=db password=s3cret dbname=maps", "host=db password=*** dbname=maps"),
        ("postgresql://me@db/maps", "postgresql://me@db/maps"),
        ("sqlite:///data/semanticxr.sqlite3", "sqlite:///data/semanticxr.sqlite3"),
    ],
)  # fmt: skip
def test_a_url_is_shown_without_its_password(url, shown):
    assert redact_url(url) == shown


def test_the_postgresql_urls_are_checked_without_a_server():
    for url in (
        "postgresql://me:s3cret@db.internal:5432/maps",
        "postgres://me@db/maps?connect_timeout=3&sslmode=require",
        "postgresql:///maps?host=/var/run/postgresql",
        "postgresql://me@db1:5432,db2:5433/maps",
    ):
        ServerSettings(store=url)  # no error, nothing opened


# ---------------------------------------------------------------------- the schema
def test_both_stores_keep_the_same_schema_version_and_a_new_database_records_it(fresh_pg_url):
    """A future migration lands in both stores, or this fails."""
    assert postgres.SCHEMA_VERSION == sqlite.SCHEMA_VERSION == 7
    open_store(fresh_pg_url).close()
    assert query(fresh_pg_url, "SELECT version FROM schema_version") == [(7,)]
    tables = query(
        fresh_pg_url, "SELECT tablename FROM pg_tables WHERE schemaname = 'public' ORDER BY 1"
    )
    assert tables == [
        ("changes",),
        ("done_acks",),
        ("objects",),
        ("schema_version",),
        ("sessions",),
        ("shards",),
        ("tombstones",),
    ]


def test_a_newer_schema_version_is_refused_with_a_clear_error(fresh_pg_url):
    open_store(fresh_pg_url).close()
    execute(fresh_pg_url, f"UPDATE schema_version SET version = {postgres.SCHEMA_VERSION + 1}")
    with pytest.raises(StoreVersionError, match="newer than this SemanticXR") as err:
        open_store(fresh_pg_url)
    assert PG_PASSWORD not in str(err.value)


def test_a_database_holding_other_tables_is_refused(fresh_pg_url):
    execute(fresh_pg_url, "CREATE TABLE notes (text text)")
    with pytest.raises(StoreError, match="other tables"):
        open_store(fresh_pg_url)
    assert query(fresh_pg_url, "SELECT to_regclass('sessions')") == [(None,)]


def test_stores_opening_one_new_database_together_create_its_schema_once(fresh_pg_url):
    """Gateways starting at once: one creates the schema, the others wait and use it."""
    errors: list[BaseException] = []
    stores: list[PostgresStore] = []

    def open_one() -> None:
        try:
            stores.append(PostgresStore(fresh_pg_url))
        except BaseException as exc:  # surfaced by the assertion below
            errors.append(exc)

    threads = [threading.Thread(target=open_one) for _ in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=30)
    try:
        assert errors == [] and len(stores) == 4
        stores[0].create_session(record("s1"))
        assert all(store.list_sessions() == [record("s1")] for store in stores)
    finally:
        for store in stores:
            store.close()


# ---------------------------------------------------------------------- one database, many
def test_two_stores_on_one_database_see_each_others_commits(fresh_pg_url):
    with open_store(fresh_pg_url) as one, open_store(fresh_pg_url) as other:
        seeded(one)
        assert everything(other) == everything(one)
        other.commit_keyframe(KeyframeCommit("s1", 3, [make_object(3, version=4)], [], {}, 4))
        assert [(o.id, o.version) for o in one.load_objects("s1")] == [(1, 2), (2, 1), (3, 4)]
        with pytest.raises(ValueError, match="does not follow"):  # the same seq twice
            one.commit_keyframe(KeyframeCommit("s1", 3, [make_object(2, version=5)], [], {}, 4))


def test_the_unix_socket_and_the_postgres_scheme_reach_the_same_database(pg_cluster, fresh_pg_url):
    database = fresh_pg_url.rsplit("/", 1)[1]
    with open_store(pg_cluster.socket_url(database)) as store:
        store.create_session(record("s1"))
    with open_store(fresh_pg_url.replace("postgresql://", "postgres://")) as store:
        assert store.list_sessions() == [record("s1")]


def test_text_postgresql_cannot_hold_is_refused_as_a_value_error(fresh_pg_url):
    """A NUL character: SQLite keeps it, PostgreSQL's text cannot; nothing is written."""
    with open_store(fresh_pg_url) as store:
        with pytest.raises(ValueError, match="NUL"):
            store.create_session(record("s1", name="nul\x00name"))
        assert store.list_sessions() == []


# ---------------------------------------------------------------------- faults
def test_a_stopped_server_refuses_calls_within_the_timeout_and_writes_resume(
    pg_cluster, fresh_pg_url
):
    url = with_timeout(fresh_pg_url)
    with open_store(url) as store:
        seeded(store)
        before = everything(store)
        pg_cluster.stop()
        try:
            calls = {
                "probe": store.probe,
                "commit": lambda: store.commit_keyframe(
                    KeyframeCommit("s1", 3, [make_object(3)], [], {}, 4)
                ),
                "read": lambda: store.load_objects("s1"),
                "open": lambda: open_store(url),
            }
            for what, call in calls.items():
                started = time.monotonic()
                with pytest.raises(StoreUnavailableError) as err:
                    call()
                assert time.monotonic() - started < CONNECT_TIMEOUT_S + MARGIN_S, what
                assert PG_PASSWORD not in str(err.value) and ":***@" in str(err.value), what
        finally:
            pg_cluster.start()
        first_success(store.probe)
        assert everything(store) == before  # the refused commit changed nothing
        store.commit_keyframe(KeyframeCommit("s1", 3, [make_object(3)], [], {}, 4))
    with open_store(url) as store:
        assert [o.id for o in store.load_objects("s1")] == [1, 2, 3]


def test_a_store_carries_on_after_its_server_restarts(pg_cluster, fresh_pg_url):
    """Its pooled connections die with the server; the pool tests each before lending it,
    so the first call after the restart waits for a new one instead of failing."""
    url = with_timeout(fresh_pg_url)
    with open_store(url) as store:
        seeded(store)
        before = everything(store)
        pg_cluster.stop()
        pg_cluster.start()
        started = time.monotonic()
        assert everything(store) == before
        store.commit_keyframe(KeyframeCommit("s1", 3, [make_object(3)], [], {"frames": 7}, 4))
        assert time.monotonic() - started < CONNECT_TIMEOUT_S + MARGIN_S
    with open_store(url) as store:  # and a store opened after the restart
        assert store.load_session("s1").frames == 7


def test_a_wrong_password_is_unavailable_with_the_servers_reason_not_the_password(pg_cluster):
    url = with_timeout(pg_cluster.url("postgres", password="not-the-password"))
    with pytest.raises(StoreUnavailableError, match="password authentication failed") as err:
        open_store(url)
    assert "not-the-password" not in str(err.value)


# ---------------------------------------------------------------------- the server
def test_a_server_on_postgresql_keeps_its_sessions_across_a_restart(
    fresh_pg_url, live_server, caplog
):
    caplog.set_level(logging.INFO, logger="semanticxr")
    first = live_server(store=fresh_pg_url)
    assert redact_url(fresh_pg_url) in caplog.text  # the start-up names its store
    assert PG_PASSWORD not in caplog.text
    created = httpx.post(f"{first.url}/v1/sessions", json={"name": "kitchen"}, timeout=10)
    assert created.status_code == 201, created.text
    sid = created.json()["session_id"]
    first.stop()

    again = live_server(store=fresh_pg_url)
    got = httpx.get(f"{again.url}/v1/sessions/{sid}", timeout=10)
    assert got.status_code == 200, got.text
    assert got.json()["name"] == "kitchen"
    assert [s["session_id"] for s in httpx.get(f"{again.url}/v1/sessions", timeout=10).json()] == [
        sid
    ]


def test_a_server_refuses_keyframes_while_its_database_is_down_and_recovers_by_itself(
    pg_cluster, fresh_pg_url, live_server
):
    """As on a full disk, the keyframe is refused (`storage_unavailable`) and /healthz answers
    503; the server's probe notices the database is back without a keyframe. Unlike a full
    disk, the session's map cannot be read back either, so the server closes the session's
    socket; the device's next connection loads it again."""
    server = live_server(store=with_timeout(fresh_pg_url))
    created = httpx.post(f"{server.url}/v1/sessions", json={"knobs": {"keyframe_interval": 1}})
    stream_url = f"{server.ws_url}/v1/sessions/{created.json()['session_id']}/stream"

    def health() -> int:
        return httpx.get(f"{server.url}/healthz", timeout=10).status_code

    async def keyframe(ws, seq: int) -> dict:
        await ws.send(msgpack.packb(frame_message(list(KITCHEN), seq, cam_xy=(0.01 * seq, 0))))
        return msgpack.unpackb(await asyncio.wait_for(ws.recv(), TIMEOUT_S))

    async def stream() -> tuple[list[dict], int]:
        async with websockets.connect(stream_url) as ws:
            replies = [await keyframe(ws, 0)]
            pg_cluster.stop()
            try:
                replies.append(await keyframe(ws, 1))
                down = await asyncio.to_thread(health)
            finally:
                pg_cluster.start()
        deadline = time.monotonic() + RECOVERY_S
        while await asyncio.to_thread(health) != 200:
            assert time.monotonic() < deadline, "/healthz still 503"
            await asyncio.sleep(0.1)  # polling the server's answer, not synchronisation
        async with websockets.connect(stream_url) as ws:  # the device reconnects
            replies.append(await keyframe(ws, 2))
        return replies, down

    replies, down = asyncio.run(stream())
    assert [r["type"] for r in replies] == ["ack", "error", "ack"], replies
    assert replies[1]["code"] == "storage_unavailable" and down == 503
    session = httpx.get(stream_url.replace("ws://", "http://").removesuffix("/stream")).json()
    assert session["keyframes"] == 2  # the refused one was not mapped
