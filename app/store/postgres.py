"""`PostgresStore`: sessions and their confirmed maps in a PostgreSQL database (psycopg 3).

The same contract as `SqliteStore`, and the same rows (`rows.py` encodes both): one
transaction per `commit_keyframe`, committed before the server acks the keyframe; after a
restart `load_objects` and `load_delta_log` give back the confirmed map and the delta log.
What "durable" means is the server's setting: with PostgreSQL's default
`synchronous_commit=on` a commit has been flushed to the server's WAL when it returns.

Opened from `postgresql://user:password@host:port/database` (or `postgres://`, or
`postgresql:///database?host=/socket/dir` for a Unix socket; libpq's parameters after `?`).
The tables go in the connection's current schema (`options=-csearch_path%3Dname` picks
another); an empty schema gets them on first open, one holding other tables is refused.

The queries are `SqlStore`'s (`sql.py`), the tables `schema.py`'s, in PostgreSQL's spelling
(`dialect.POSTGRES`); this module holds the connection pool, its transactions and what the
server's faults do to them. `schema_version` holds the schema version, the same number as
SQLite's `user_version` for the same logical schema; PostgreSQL stores were first made at
version 4. Opening migrates under an advisory lock, so processes opening one database
together migrate it once. Points and embeddings are bytea in the bytes `rows.py` writes
(float32 little-endian); knobs and label counts `json` (its text kept as written: key order
is meaning for label ties); session ids sort by code point (`COLLATE "C"`), as in SQLite.
Changes keep their arrival order in an identity column.

Concurrency: a pool of connections (`psycopg_pool`), so reads and the commits of different
sessions run side by side; a commit locks its session's row first, so commits, trims, claims
and deletions of one session land one at a time in the order they take the lock (a claim
and a fenced write can never interleave). Creations take one advisory lock, so a count
against max_sessions and its insert are never split by another creation. Writes run at READ
COMMITTED (each statement sees what committed before it, the lock waited for included); a
read of more than one statement is one REPEATABLE READ snapshot.

Faults: a server that cannot be reached (stopped, restarting, unreachable within the URL's
`connect_timeout`, 5 s when unset), a connection lost mid-call, a full disk or a read-only
server raise `StoreUnavailableError`. A write that raises it changed nothing, except when the
connection was lost while the server committed: the server then reloads the session from
the store (as after any failed commit), so it holds whichever outcome landed. The pool tests
a connection before lending it, so a restarted server costs the next call about a second,
not an error.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from typing import Any, TypeVar

import psycopg
from psycopg import IsolationLevel, errors
from psycopg.conninfo import conninfo_to_dict
from psycopg.types.string import TextBinaryLoader, TextLoader
from psycopg_pool import ConnectionPool, PoolClosed

from app.store import StoreURLError, redact_url
from app.store.base import StoreError, StoreUnavailableError, StoreVersionError
from app.store.dialect import POSTGRES
from app.store.schema import SCHEMA_VERSION, statements
from app.store.sql import SqlStore

__all__ = ["SCHEMA_VERSION", "PostgresStore"]

T = TypeVar("T")

CONNECT_TIMEOUT_S = 5
"""libpq's connect_timeout when the URL sets none; also how long a call waits for a pooled
connection before StoreUnavailableError."""
POOL_MAX_SIZE = 8
"""Connections a store keeps at most (the mapping pool, REST threads and the store thread
share them; a call waits for a free one)."""

_VERSION_TABLE = """
    CREATE TABLE schema_version (
        singleton boolean PRIMARY KEY DEFAULT true CHECK (singleton),  -- one row
        version   integer NOT NULL
    )
"""
"""Where the schema version is kept (one row)."""

_SCHEMA_LOCK = "semanticxr.store.schema"
"""Names the advisory lock held while a store creates or migrates the schema."""

_UNAVAILABLE = (psycopg.OperationalError, errors.ReadOnlySqlTransaction)
"""Errors meaning "the database cannot take this now" (unreachable, connection lost,
shutting down, disk full, too many connections, a read-only standby), not a bad call.
PoolTimeout, waiting for a connection, is an OperationalError."""


class PostgresStore(SqlStore):
    """The `Store` in a PostgreSQL database (`postgresql://...`). Thread-safe."""

    dialect = POSTGRES

    def __init__(self, url: str, *, max_connections: int = POOL_MAX_SIZE):
        """Connect to the database at `url` (a libpq URL), creating or migrating the schema.

        StoreUnavailableError when the server cannot be reached or refuses the connection
        (its reason included); StoreError when the database holds other tables, or the
        schema cannot be created; StoreVersionError when a newer SemanticXR wrote it;
        StoreURLError when libpq cannot parse `url` (`open_store` checks more)."""
        self.where = redact_url(url)
        """The URL as errors and logs show it (no password)."""
        try:
            params = conninfo_to_dict(url)
        except psycopg.ProgrammingError as exc:
            raise StoreURLError(f"{self.where}: {_reason(exc)}") from None
        timeout_s = int(params.get("connect_timeout") or 0)
        self._wait_s = float(timeout_s if timeout_s > 0 else CONNECT_TIMEOUT_S)
        connect_args: dict[str, Any] = {"connect_timeout": max(2, round(self._wait_s))}
        if not params.get("application_name"):
            connect_args["application_name"] = "semanticxr"
        self._closed = False
        self._close_lock = threading.Lock()
        try:
            with psycopg.connect(url, autocommit=True, **connect_args) as conn:
                _configure(conn)
                self._init_schema(conn)
        except _UNAVAILABLE as exc:
            raise StoreUnavailableError(f"{self.where}: cannot connect ({_reason(exc)})") from exc
        except psycopg.Error as exc:
            raise StoreError(f"{self.where}: cannot open the store ({_reason(exc)})") from exc
        self._pool = ConnectionPool(
            url,
            kwargs=connect_args,
            min_size=1,
            max_size=max_connections,
            open=False,
            configure=_configure,
            check=self._check_connection,
            timeout=self._wait_s,
            # Give up on reconnecting after a while (the next call starts afresh), so the
            # back-off of a long outage never delays the first call after it.
            reconnect_timeout=self._wait_s,
            name="semanticxr-store",
        )
        self._pool.open()

    # ------------------------------------------------------------------ lifecycle
    def _init_schema(self, conn: psycopg.Connection) -> None:
        """Create the schema in an empty database, or migrate it, in one transaction."""
        encoding = conn.execute("SHOW server_encoding").fetchone()[0]
        if encoding.upper() not in ("UTF8", "UTF-8"):
            raise StoreError(
                f"{self.where}: the database's encoding is {encoding}; SemanticXR needs UTF8 "
                "(CREATE DATABASE ... ENCODING 'UTF8')"
            )
        with conn.transaction():
            conn.execute("SELECT pg_advisory_xact_lock(hashtext(%s))", (_SCHEMA_LOCK,))
            if conn.execute("SELECT to_regclass('schema_version')").fetchone()[0] is None:
                tables = conn.execute(
                    "SELECT count(*) FROM pg_tables WHERE schemaname = current_schema()"
                ).fetchone()[0]
                if tables:
                    raise StoreError(
                        f"{self.where}: the database holds other tables but no SemanticXR "
                        "store (use an empty database or schema)"
                    )
                conn.execute(_VERSION_TABLE)
                conn.execute("INSERT INTO schema_version (version) VALUES (0)")
            version = conn.execute("SELECT version FROM schema_version").fetchone()[0]
            if version > SCHEMA_VERSION:
                raise StoreVersionError(
                    f"{self.where} has schema version {version}, newer than this SemanticXR "
                    f"understands ({SCHEMA_VERSION}); upgrade SemanticXR or use another database"
                )
            for statement in statements(POSTGRES, version):
                conn.execute(statement)
            # In the same transaction: a crash leaves the old schema or all of the new.
            conn.execute("UPDATE schema_version SET version = %s", (SCHEMA_VERSION,))

    def close(self) -> None:
        """Close the pool (idempotent); nothing committed depends on it being called."""
        with self._close_lock:
            if not self._closed:
                self._closed = True
                self._pool.close()

    def _check_connection(self, conn: psycopg.Connection) -> None:
        """The pool's test of a connection before lending it. A broken one means the server
        went away or restarted, which broke every idle connection alike: test them all now,
        so the next call is not delayed once for each (the pool waits between tries)."""
        try:
            ConnectionPool.check_connection(conn)
        except psycopg.Error:
            self._pool.check()
            raise

    @contextmanager
    def _transaction(self, write: bool = True) -> Iterator[psycopg.Cursor]:
        """One transaction on a pooled connection, rolled back if the block raises; reads
        are one REPEATABLE READ snapshot. Connection faults become StoreUnavailableError.
        Gives a cursor that reads results in binary (bytea as it is, no hex)."""
        if self._closed:
            raise StoreError(f"{self.where}: the store is closed")
        try:
            with self._pool.connection() as conn:
                conn.read_only = not write
                # Writes: each statement sees every commit before it (after a lock waited
                # for too), whatever the server's default; reads: one snapshot.
                conn.isolation_level = (
                    IsolationLevel.READ_COMMITTED if write else IsolationLevel.REPEATABLE_READ
                )
                with conn.transaction():
                    yield conn.cursor(binary=True)
        except PoolClosed:
            raise StoreError(f"{self.where}: the store is closed") from None
        except _UNAVAILABLE as exc:
            raise StoreUnavailableError(
                f"{self.where}: the database cannot be used now ({_reason(exc)})"
            ) from exc
        except psycopg.DataError as exc:  # a value the columns cannot hold (NUL, > 64 bits)
            raise ValueError(f"{self.where}: {_reason(exc)}") from exc

    def _write(self, body: Callable[[psycopg.Cursor], T]) -> T:
        """`body(cursor)` in one write transaction."""
        with self._transaction() as cursor:
            return body(cursor)

    def _pipeline(self, cursor: psycopg.Cursor) -> AbstractContextManager[Any]:
        """One round trip for the lot: statements go out without waiting for each answer."""
        return cursor.connection.pipeline()

    # ------------------------------------------------------------------ health
    def probe(self) -> None:
        """Return once a write can land (a pooled connection commits a one-row write that
        changes nothing); StoreUnavailableError if not."""
        self._write(lambda cursor: cursor.execute("UPDATE schema_version SET version = version"))


# ---------------------------------------------------------------------- helpers
def _configure(conn: psycopg.Connection) -> None:
    """Every connection: explicit transactions only, and json read as its text (the rows
    decode it, keeping its key order)."""
    conn.autocommit = True
    conn.adapters.register_loader("json", TextLoader)
    conn.adapters.register_loader("json", TextBinaryLoader)


def _reason(exc: psycopg.Error) -> str:
    """The server's or libpq's message, on one line."""
    return " ".join(str(exc).split()) or type(exc).__name__
