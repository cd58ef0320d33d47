"""`SqliteStore`: sessions and their confirmed maps in one SQLite file (WAL mode).

The queries are `SqlStore`'s (`sql.py`), the tables `schema.py`'s, in SQLite's spelling
(`dialect.SQLITE`); this module holds the connection, its transactions and what the disk
does to them. The schema version is `PRAGMA user_version`.

Durability: WAL with `synchronous=NORMAL`. A committed transaction is in the WAL file (in the
OS page cache at least) when COMMIT returns, so it survives a crash of the process (kill -9,
OOM kill); it can be lost to a power failure or kernel crash, which would roll the store back
to an earlier consistent state (never a torn one). That trade buys commits without an fsync
each; run on storage with a battery-backed cache or switch to `synchronous=FULL` if power loss
must be covered (a one-line change in `SqliteStore.__init__`).

Every write is BEGIN IMMEDIATE: one writer at a time, across processes too, so a claim, a
renewal or an epoch check and the write after it are never split by another writer.

One connection, shared by all threads (mapping runs in a thread pool) and serialised by a lock:
SQLite allows one writer at a time anyway, and one connection keeps the ordering of commits
the ordering of calls.

A full disk: a write the disk refuses (SQLITE_FULL, an I/O error such as EFBIG past a file
size limit, a read-only file) is rolled back; the store then checkpoints the WAL into the
database, truncates it and tries once more, since a WAL that cannot grow is often all that
is in the way (the database reuses its free pages). If that fails too the write raises
`StoreUnavailableError`, having changed nothing. `probe` makes the same checkpoint and one
small write: it succeeds only once the database has taken every committed page and the WAL
starts empty, so a recovery it reports is room on the disk, not a gap left in an old WAL.
"""

from __future__ import annotations

import contextlib
import os
import sqlite3
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TypeVar

from app.store.base import StoreError, StoreUnavailableError, StoreVersionError
from app.store.dialect import SQLITE
from app.store.schema import SCHEMA_VERSION, statements
from app.store.sql import SqlStore

__all__ = ["SCHEMA_VERSION", "SqliteStore"]

T = TypeVar("T")

_STORAGE_ERROR_CODES = frozenset(
    {
        sqlite3.SQLITE_FULL,
        sqlite3.SQLITE_IOERR,
        sqlite3.SQLITE_READONLY,
        sqlite3.SQLITE_CANTOPEN,
        sqlite3.SQLITE_BUSY,
    }
)
"""Primary result codes meaning "the storage cannot take this write now", not a bad write."""


class SqliteStore(SqlStore):
    """The `Store` in one SQLite file (`sqlite:///<path>`). Thread-safe."""

    dialect = SQLITE

    def __init__(self, path: str | os.PathLike):
        """Open or create the database at `path` (its parent directories are created)."""
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = threading.Lock()
        # isolation_level=None: no implicit transactions; every write is an explicit
        # BEGIN IMMEDIATE ... COMMIT, so its extent is exactly what the code says.
        conn = sqlite3.connect(
            self.path, timeout=5.0, isolation_level=None, check_same_thread=False
        )
        try:
            journal_mode = conn.execute("PRAGMA journal_mode=WAL").fetchone()[0]
            if str(journal_mode).lower() != "wal":
                raise StoreError(f"{self.path}: cannot switch to WAL mode (got {journal_mode!r})")
            conn.execute("PRAGMA synchronous=NORMAL")  # survives kill -9, not power loss
            conn.execute("PRAGMA foreign_keys=ON")  # deleting a session cascades to its rows
            # The WAL keeps its largest size until checkpointed; cap what stays on disk.
            conn.execute("PRAGMA journal_size_limit=67108864")
            self._conn: sqlite3.Connection | None = conn
            self._init_schema()
        except BaseException:
            conn.close()
            self._conn = None
            raise

    # ------------------------------------------------------------------ lifecycle
    def _init_schema(self) -> None:
        with self._transaction() as conn:
            version = conn.execute("PRAGMA user_version").fetchone()[0]
            if version > SCHEMA_VERSION:
                raise StoreVersionError(
                    f"{self.path} has schema version {version}, newer than this SemanticXR "
                    f"understands ({SCHEMA_VERSION}); upgrade SemanticXR or use another data dir"
                )
            if version == SCHEMA_VERSION:
                return
            if version == 0 and conn.execute("SELECT count(*) FROM sqlite_master").fetchone()[0]:
                raise StoreError(f"{self.path} is an SQLite database but not a SemanticXR store")
            for statement in statements(SQLITE, version):
                conn.execute(statement)
            # Set inside the same transaction: a crash leaves the old schema or all of the new.
            conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")

    def close(self) -> None:
        """Close the database (idempotent); nothing committed depends on it being called."""
        with self._lock:
            if self._conn is not None:
                self._conn.close()
                self._conn = None

    @contextmanager
    def _transaction(self, write: bool = True) -> Iterator[sqlite3.Connection]:
        """One transaction under the lock; rolled back if the block raises."""
        with self._lock:
            conn = self._conn
            if conn is None:
                raise StoreError(f"{self.path}: the store is closed")
            # IMMEDIATE takes the write lock up front, so a write never fails half-way on
            # SQLITE_BUSY; a plain BEGIN gives reads one consistent snapshot.
            conn.execute("BEGIN IMMEDIATE" if write else "BEGIN")
            try:
                yield conn
                conn.execute("COMMIT")
            except BaseException:
                if conn.in_transaction:
                    # SQLite may have rolled back already (SQLITE_FULL); a failing ROLLBACK
                    # must not hide why the transaction failed.
                    with contextlib.suppress(sqlite3.Error):
                        conn.execute("ROLLBACK")
                raise

    def _write(self, body: Callable[[sqlite3.Connection], T]) -> T:
        """`body(conn)` in one write transaction. When the disk refuses it: checkpoint and
        truncate the WAL, try once more, then StoreUnavailableError (nothing changed)."""
        try:
            with self._transaction() as conn:
                return body(conn)
        except sqlite3.OperationalError as exc:
            if not _is_storage_error(exc):
                raise
        try:
            self._checkpoint()
            with self._transaction() as conn:
                return body(conn)
        except sqlite3.OperationalError as exc:
            if not _is_storage_error(exc):
                raise
            raise StoreUnavailableError(f"{self.path}: the disk refused a write ({exc})") from exc

    def _checkpoint(self) -> None:
        """Copy every committed page of the WAL into the database and truncate the WAL to
        zero bytes (raises sqlite3.OperationalError if the database cannot take them)."""
        with self._lock:
            if self._conn is None:
                raise StoreError(f"{self.path}: the store is closed")
            # Returns (busy, wal pages, pages checkpointed); busy only with other processes'
            # readers, and then the write after it tells whether there is room.
            self._conn.execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchone()

    # ------------------------------------------------------------------ health
    def probe(self) -> None:
        """Return once a write can land; StoreUnavailableError if not. Checkpoints the WAL
        into the database (so the database must take every committed page: a recovery it
        reports is real room, not a gap in an old WAL) and commits a one-page write."""
        try:
            self._checkpoint()
            with self._transaction() as conn:
                conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")  # rewrites page 1
        except sqlite3.OperationalError as exc:
            if not _is_storage_error(exc):
                raise
            raise StoreUnavailableError(f"{self.path}: the disk refuses writes ({exc})") from exc


# ---------------------------------------------------------------------- helpers
def _is_storage_error(exc: sqlite3.Error) -> bool:
    """True when SQLite says the storage refused the operation (full, I/O, read-only, busy)."""
    code = getattr(exc, "sqlite_errorcode", None)
    return code is not None and code & 0xFF in _STORAGE_ERROR_CODES
