"""`SqliteStore`: sessions and their confirmed maps in one SQLite file (WAL mode).

What is stored is exactly what the server has acknowledged: the server calls
`commit_keyframe` before it acks a keyframe, and that call returns only once one
transaction holding the keyframe's object changes, tombstones, counters and update seq has
committed. After a restart `load_objects` and `load_delta_log` give back the confirmed map and
the delta log, so the update seq continues and a subscriber resuming with `since` loses
nothing.

Durability: WAL with `synchronous=NORMAL`. A committed transaction is in the WAL file (in the
OS page cache at least) when COMMIT returns, so it survives a crash of the process (kill -9,
OOM kill); it can be lost to a power failure or kernel crash, which would roll the store back
to an earlier consistent state (never a torn one). That trade buys commits without an fsync
each; run on storage with a battery-backed cache or switch to `synchronous=FULL` if power loss
must be covered (a one-line change in `SqliteStore.__init__`).

Arrays are stored as raw little-endian float32 bytes whose shape the schema records (never
pickle): points [n_points, 3], embedding_sum [embedding_dim], label_embeddings [labels,
embedding_dim] (one row per label of label_counts, in its order), a session's last pose [16];
stays are `stays_to_bytes` records. Knobs and label counts are JSON.

The living map (schema 4): an object removed from the map but kept as history keeps its row
with state 'removed' (its last fields: stays, last points); every read of the present map
(objects, counts, the delta log) takes state 'present' only, and its removal stays in
`tombstones` like any other. Changes are rows of `changes` in arrival (rowid) order, written
in the keyframe's transaction.

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
import json
import math
import os
import sqlite3
import threading
from collections import Counter
from collections.abc import Callable, Collection, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from app.mapping.deltas import DeltaLog
from app.mapping.object import (
    MAX_STAYS,
    OBJECT_STATES,
    STAY_BYTES,
    Change,
    MapObject,
    stays_from_bytes,
    stays_to_bytes,
)
from app.store.base import (
    CHANGE_KINDS,
    COUNTER_NAMES,
    SessionRecord,
    Store,
    StoredSession,
    StoreError,
    StoreUnavailableError,
    StoreVersionError,
)

__all__ = ["SCHEMA_VERSION", "SqliteStore"]

_FLOAT32_LE = np.dtype("<f4")
T = TypeVar("T")

_SCHEMA: tuple[str, ...] = (
    """
    CREATE TABLE sessions (
        session_id     TEXT PRIMARY KEY,
        name           TEXT NOT NULL,
        mode           TEXT NOT NULL,
        knobs          TEXT NOT NULL,            -- JSON object {knob: value}
        token_hash     TEXT NOT NULL,
        created_at     REAL NOT NULL,            -- unix time, seconds
        frames         INTEGER NOT NULL,
        keyframes      INTEGER NOT NULL,
        bytes_in       INTEGER NOT NULL,
        bytes_out      INTEGER NOT NULL,
        next_object_id INTEGER NOT NULL,
        seq            INTEGER NOT NULL,         -- the delta log's seq
        delta_floor    INTEGER NOT NULL          -- the delta log's floor
    )
    """,
    """
    CREATE TABLE objects (
        session_id    TEXT NOT NULL REFERENCES sessions (session_id) ON DELETE CASCADE,
        object_id     INTEGER NOT NULL,
        change_seq    INTEGER NOT NULL,          -- seq of the commit that last changed it
        version       INTEGER NOT NULL,
        n_obs         INTEGER NOT NULL,
        frames_seen   INTEGER NOT NULL,
        first_seen    INTEGER NOT NULL,
        last_seen     INTEGER NOT NULL,
        resolution_m  REAL NOT NULL,
        label_counts  TEXT NOT NULL,             -- JSON {label: count}, in first-seen order
        n_points      INTEGER NOT NULL,
        points        BLOB NOT NULL,             -- float32 little-endian [n_points, 3]
        embedding_dim INTEGER,                   -- NULL when the object has no embedding
        embedding_sum BLOB,                      -- float32 little-endian [embedding_dim]
        PRIMARY KEY (session_id, object_id),
        CHECK (length(points) = 12 * n_points),
        CHECK ((embedding_dim IS NULL) = (embedding_sum IS NULL)),
        CHECK (embedding_sum IS NULL OR length(embedding_sum) = 4 * embedding_dim)
    )
    """,
    """
    CREATE TABLE tombstones (
        session_id TEXT NOT NULL REFERENCES sessions (session_id) ON DELETE CASCADE,
        object_id  INTEGER NOT NULL,
        seq        INTEGER NOT NULL,             -- seq of the commit that removed it
        PRIMARY KEY (session_id, object_id)
    ) WITHOUT ROWID
    """,
)

_MIGRATIONS: tuple[tuple[str, ...], ...] = (
    # 1 -> 2: the session's perception backend (sessions before it used `detections`).
    ("ALTER TABLE sessions ADD COLUMN perception TEXT NOT NULL DEFAULT 'detections'",),
    # 2 -> 3: when each session was last used (for retention). Sessions from before it count
    # as used at the upgrade: a session is never deleted for lack of a date.
    (
        "ALTER TABLE sessions ADD COLUMN last_used_at REAL NOT NULL DEFAULT 0",
        "UPDATE sessions SET last_used_at = (julianday('now') - 2440587.5) * 86400.0",
        "CREATE INDEX sessions_by_last_use ON sessions (last_used_at)",
    ),
    # 3 -> 4: the living map. Objects removed from the map stay as history (state), with
    # when they were seen on the device clock, where they stayed, and per-label evidence;
    # the changes the map concluded; the session's last keyframe time and pose. Rows from
    # before it are present objects with no times, stays or per-label sums.
    (
        "ALTER TABLE objects ADD COLUMN state TEXT NOT NULL DEFAULT 'present'"
        " CHECK (state IN ('present', 'removed'))",
        "ALTER TABLE objects ADD COLUMN first_seen_t REAL",  # device clock, seconds
        "ALTER TABLE objects ADD COLUMN last_seen_t REAL",
        # stays_to_bytes records, oldest first: at most MAX_STAYS (<= 2 KB); NULL for none
        f"ALTER TABLE objects ADD COLUMN stays BLOB CHECK (stays IS NULL OR"
        f" (length(stays) % {STAY_BYTES} = 0 AND length(stays) <= {MAX_STAYS * STAY_BYTES}))",
        # float32 little-endian [labels, embedding_dim], a row per label of label_counts in
        # its order (all NaN: no sum for that label); NULL for none
        "ALTER TABLE objects ADD COLUMN label_embeddings BLOB CHECK (label_embeddings IS NULL"
        " OR (embedding_dim > 0 AND length(label_embeddings) % (4 * embedding_dim) = 0))",
        # The present map's reads (delta log, counts) and the removed objects' from the index.
        "CREATE INDEX objects_by_state ON objects (session_id, state, object_id, change_seq)",
        "ALTER TABLE sessions ADD COLUMN last_t REAL",  # frame t of the last keyframe
        "ALTER TABLE sessions ADD COLUMN last_pose BLOB"  # float32 LE [16], row-major 4x4
        " CHECK (last_pose IS NULL OR length(last_pose) = 64)",
        """
        CREATE TABLE changes (
            session_id TEXT NOT NULL REFERENCES sessions (session_id) ON DELETE CASCADE,
            object_id  INTEGER NOT NULL,
            kind       TEXT NOT NULL CHECK (kind IN ('added', 'moved', 'removed')),
            t          REAL NOT NULL,             -- frame t that concluded it (device clock)
            label      TEXT NOT NULL,
            from_x     REAL,                      -- the old place, NULL where none
            from_y     REAL,
            from_z     REAL,
            to_x       REAL,                      -- the new place, NULL where none
            to_y       REAL,
            to_z       REAL,
            seq        INTEGER NOT NULL,          -- the update seq of the commit
            CHECK ((from_x IS NULL) = (from_y IS NULL) AND (from_x IS NULL) = (from_z IS NULL)),
            CHECK ((to_x IS NULL) = (to_y IS NULL) AND (to_x IS NULL) = (to_z IS NULL))
        )
        """,  # rowid order is arrival order
        "CREATE INDEX changes_by_seq ON changes (session_id, seq)",
        "CREATE INDEX changes_by_t ON changes (session_id, t)",
    ),
)
"""_MIGRATIONS[i] takes a store from schema version i + 1 to i + 2; a new store is created
at version 1 (`_SCHEMA`) and migrated like any other, so there is one path to each version."""

SCHEMA_VERSION = 1 + len(_MIGRATIONS)
"""Stored in `PRAGMA user_version`; a schema change is a new entry in _MIGRATIONS."""

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

_SESSION_COLUMNS = (
    "session_id, name, mode, perception, knobs, token_hash, created_at, "
    "frames, keyframes, bytes_in, bytes_out, next_object_id, last_used_at, last_t, last_pose"
)
_OBJECT_COLUMNS = (
    "object_id, version, n_obs, frames_seen, first_seen, last_seen, resolution_m, "
    "label_counts, n_points, points, embedding_dim, embedding_sum, "
    "state, first_seen_t, last_seen_t, stays, label_embeddings"
)
_N_OBJECT_COLUMNS = len(_OBJECT_COLUMNS.split(","))
_CHANGE_COLUMNS = "object_id, kind, t, label, from_x, from_y, from_z, to_x, to_y, to_z, seq"


class SqliteStore(Store):
    """The `Store` in one SQLite file (`sqlite:///<path>`). Thread-safe."""

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
            if version == 0:
                if conn.execute("SELECT count(*) FROM sqlite_master").fetchone()[0]:
                    raise StoreError(
                        f"{self.path} is an SQLite database but not a SemanticXR store"
                    )
                for statement in _SCHEMA:
                    conn.execute(statement)
                version = 1
            for migration in _MIGRATIONS[version - 1 :]:
                for statement in migration:
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

    # ------------------------------------------------------------------ sessions
    def create_session(self, rec: SessionRecord) -> None:
        """Persist a new session; ValueError if its id exists."""
        row = (
            rec.session_id,
            rec.name,
            rec.mode,
            rec.perception,
            _to_json(rec.knobs),
            rec.token_hash,
            float(rec.created_at),
            int(rec.frames),
            int(rec.keyframes),
            int(rec.bytes_in),
            int(rec.bytes_out),
            int(rec.next_object_id),
            float(rec.last_used_at if rec.last_used_at is not None else rec.created_at),
            _checked_time("last_t", rec.last_t),
            None if rec.last_pose is None else _pose_to_blob(rec.last_pose),
        )
        try:
            self._write(
                lambda conn: conn.execute(
                    f"INSERT INTO sessions ({_SESSION_COLUMNS}, seq, delta_floor)"
                    " VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, 0, 0)",
                    row,
                )
            )
        except sqlite3.IntegrityError:
            raise ValueError(f"session {rec.session_id!r} already exists") from None

    def update_session(
        self,
        session_id: str,
        *,
        name: str | None = None,
        knobs: dict | None = None,
        counters: dict[str, int] | None = None,
        last_used_at: float | None = None,
    ) -> None:
        """Change the given fields; counters are absolute values named as in COUNTER_NAMES."""
        assignments: dict[str, Any] = _checked_counters(counters or {})
        if name is not None:
            assignments["name"] = name
        if knobs is not None:
            assignments["knobs"] = _to_json(knobs)
        if last_used_at is not None:
            assignments["last_used_at"] = float(last_used_at)

        def update(conn: sqlite3.Connection) -> None:
            _session_row(conn, session_id, "1")
            if assignments:
                # Column names come from the fixed set above, never from the caller.
                columns = ", ".join(f"{column} = ?" for column in assignments)
                conn.execute(
                    f"UPDATE sessions SET {columns} WHERE session_id = ?",
                    (*assignments.values(), session_id),
                )

        self._write(update)

    def delete_session(self, session_id: str) -> None:
        """Remove the session with its objects, tombstones and changes (no-op if unknown)."""
        self._write(
            lambda conn: conn.execute("DELETE FROM sessions WHERE session_id = ?", (session_id,))
        )

    def list_sessions(self) -> list[SessionRecord]:
        """Every session, oldest first."""
        with self._transaction(write=False) as conn:
            rows = conn.execute(
                f"SELECT {_SESSION_COLUMNS} FROM sessions ORDER BY created_at, session_id"
            ).fetchall()
        return [_session_from_row(row) for row in rows]

    def load_session(self, session_id: str) -> SessionRecord:
        """One session as last committed; KeyError if unknown."""
        with self._transaction(write=False) as conn:
            return _session_from_row(_session_row(conn, session_id, _SESSION_COLUMNS))

    def count_sessions(self) -> int:
        """How many sessions are stored."""
        with self._transaction(write=False) as conn:
            return conn.execute("SELECT count(*) FROM sessions").fetchone()[0]

    def list_stored(self) -> list[StoredSession]:
        """Every session with its present object count and update seq, oldest first; objects
        are counted on the index by state, no map is read."""
        with self._transaction(write=False) as conn:
            rows = conn.execute(
                f"SELECT {_SESSION_COLUMNS}, seq, (SELECT count(*) FROM objects AS o"
                " WHERE o.session_id = s.session_id AND o.state = 'present')"
                " FROM sessions AS s ORDER BY created_at, session_id"
            ).fetchall()
        return [StoredSession(_session_from_row(row[:-2]), row[-1], row[-2]) for row in rows]

    def idle_sessions(self, used_before: float) -> list[str]:
        """Ids of the sessions whose `last_used_at` is before `used_before` (unix time)."""
        with self._transaction(write=False) as conn:
            rows = conn.execute(
                "SELECT session_id FROM sessions WHERE last_used_at < ? ORDER BY last_used_at",
                (float(used_before),),
            ).fetchall()
        return [row[0] for row in rows]

    # ------------------------------------------------------------------ the map
    def commit_keyframe(
        self,
        session_id: str,
        seq: int,
        upserts: list[MapObject],
        removed: list[int],
        counters: dict[str, int],
        next_object_id: int,
        last_used_at: float | None = None,
        *,
        retired: Collection[MapObject] = (),
        changes: Collection[Change] = (),
        retracted_added: Collection[int] = (),
        retracted_removed: Collection[int] = (),
        last_t: float | None = None,
        last_pose: np.ndarray | None = None,
    ) -> None:
        """`Store.commit_keyframe`, in one SQLite transaction (WAL, synchronous): returns
        once the changes survive kill -9; storage errors raise StoreUnavailableError."""
        seq = int(seq)
        removed_ids = sorted({int(oid) for oid in removed})
        gone = set(removed_ids)
        kept = [obj for obj in upserts if int(obj.id) not in gone]
        retired = list(retired)
        retired_ids = [int(obj.id) for obj in retired]
        for obj in kept:
            if obj.state != "present":
                raise ValueError(
                    f"object {obj.id}: an upsert must be present, not {obj.state!r} (a removed "
                    "object kept as history is retired)"
                )
        for obj in retired:
            if obj.state != "removed":
                raise ValueError(
                    f"object {obj.id}: a retired object must be removed, not {obj.state!r}"
                )
        if len(set(retired_ids)) != len(retired_ids) or not gone.issuperset(retired_ids):
            raise ValueError(
                f"session {session_id!r}: retired ids {retired_ids} must be distinct and in "
                f"removed {removed_ids}"
            )
        kept_as_history = set(retired_ids)
        change_rows = [_change_to_row(change, seq) for change in changes]
        retracted_ids = sorted({int(oid) for oid in retracted_added})
        revived_ids = sorted({int(oid) for oid in retracted_removed})
        assignments: dict[str, Any] = _checked_counters(counters)
        if last_used_at is not None:
            assignments["last_used_at"] = float(last_used_at)
        if last_t is not None:
            assignments["last_t"] = _checked_time("last_t", last_t)
        if last_pose is not None:
            assignments["last_pose"] = _pose_to_blob(last_pose)

        def commit(conn: sqlite3.Connection) -> None:
            stored_seq, stored_next_id = _session_row(conn, session_id, "seq, next_object_id")
            # Resuming subscribers rely on "changed after S" meaning "seq > S": a change
            # stored at a seq they may already have seen would never reach them (and
            # neither would a change entry read with since_seq).
            if seq < stored_seq or ((kept or removed_ids or change_rows) and seq == stored_seq):
                raise ValueError(
                    f"session {session_id!r}: seq {seq} does not follow the stored seq {stored_seq}"
                )
            touched_ids = [int(obj.id) for obj in kept] + removed_ids + [r[0] for r in change_rows]
            if next_object_id < stored_next_id or any(i >= next_object_id for i in touched_ids):
                raise ValueError(
                    f"session {session_id!r}: next_object_id {next_object_id} would reuse an id"
                )
            assignments.update(seq=seq, next_object_id=int(next_object_id))
            columns = ", ".join(f"{column} = ?" for column in assignments)
            conn.execute(
                f"UPDATE sessions SET {columns} WHERE session_id = ?",
                (*assignments.values(), session_id),
            )
            # Retired objects are rewritten below with state 'removed': only the others go.
            conn.executemany(
                "DELETE FROM objects WHERE session_id = ? AND object_id = ?",
                [(session_id, oid) for oid in removed_ids if oid not in kept_as_history],
            )
            conn.executemany(
                "INSERT OR REPLACE INTO tombstones (session_id, object_id, seq) VALUES (?, ?, ?)",
                [(session_id, oid, seq) for oid in removed_ids],
            )
            conn.executemany(
                "DELETE FROM tombstones WHERE session_id = ? AND object_id = ?",
                [(session_id, int(obj.id)) for obj in kept],
            )
            # A generator: each object is serialised as it is written, so nothing is copied
            # twice, and a bad object aborts the transaction (rolling back the rows before it).
            conn.executemany(
                f"INSERT OR REPLACE INTO objects (session_id, change_seq, {_OBJECT_COLUMNS})"
                f" VALUES (?, ?, {', '.join('?' * _N_OBJECT_COLUMNS)})",
                ((session_id, seq, *_object_to_row(obj)) for obj in [*kept, *retired]),
            )
            # Before the inserts: a removal this commit takes back is an earlier one.
            conn.executemany(
                "DELETE FROM changes WHERE session_id = ? AND object_id = ? AND kind = 'removed'",
                [(session_id, oid) for oid in revived_ids],
            )
            conn.executemany(
                f"INSERT INTO changes (session_id, {_CHANGE_COLUMNS})"
                " VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                [(session_id, *row) for row in change_rows],
            )
            # After the inserts: no `added` change stays for a retracted id, this one's too.
            conn.executemany(
                "DELETE FROM changes WHERE session_id = ? AND object_id = ? AND kind = 'added'",
                [(session_id, oid) for oid in retracted_ids],
            )

        self._write(commit)

    def load_objects(self, session_id: str) -> list[MapObject]:
        """The session's present map: confirmed objects, state "present", in id order."""
        return self._load_in_state(session_id, "present")

    def load_removed_objects(self, session_id: str) -> list[MapObject]:
        """The session's removed objects kept as history, in id order."""
        return self._load_in_state(session_id, "removed")

    def _load_in_state(self, session_id: str, state: str) -> list[MapObject]:
        with self._transaction(write=False) as conn:
            _session_row(conn, session_id, "1")
            rows = conn.execute(
                f"SELECT {_OBJECT_COLUMNS} FROM objects WHERE session_id = ? AND state = ?"
                " ORDER BY object_id",
                (session_id, state),
            ).fetchall()
        return [_object_from_row(row) for row in rows]

    def load_object(self, session_id: str, object_id: int) -> MapObject | None:
        """One object, present or removed, as last committed; None if there is none."""
        with self._transaction(write=False) as conn:
            _session_row(conn, session_id, "1")
            row = conn.execute(
                f"SELECT {_OBJECT_COLUMNS} FROM objects WHERE session_id = ? AND object_id = ?",
                (session_id, int(object_id)),
            ).fetchone()
        return None if row is None else _object_from_row(row)

    def load_changes(
        self,
        session_id: str,
        *,
        since_t: float | None = None,
        until_t: float | None = None,
        since_seq: int | None = None,
        kinds: Collection[str] | None = None,
        limit: int | None = None,
    ) -> list[Change]:
        """`Store.load_changes`: one indexed query, newest first when limited."""
        where, params = ["session_id = ?"], [session_id]
        for name, bound, op in (("since_t", since_t, ">="), ("until_t", until_t, "<=")):
            if bound is not None:
                if math.isnan(bound):
                    raise ValueError(f"{name} must be a number, not NaN")
                where.append(f"t {op} ?")
                params.append(float(bound))
        if since_seq is not None:
            where.append("seq > ?")
            params.append(int(since_seq))
        if kinds is not None:
            kinds = sorted(set(kinds))
            unknown = [kind for kind in kinds if kind not in CHANGE_KINDS]
            if unknown:
                raise ValueError(
                    f"unknown change kinds {unknown}; kinds: {', '.join(CHANGE_KINDS)}"
                )
            where.append(f"kind IN ({', '.join('?' * len(kinds))})")
            params.extend(kinds)
        if limit is not None and int(limit) < 0:
            raise ValueError(f"limit must be >= 0, got {limit}")
        query = f"SELECT {_CHANGE_COLUMNS} FROM changes WHERE {' AND '.join(where)}"
        with self._transaction(write=False) as conn:
            _session_row(conn, session_id, "1")
            if limit is None:
                rows = conn.execute(f"{query} ORDER BY rowid", params).fetchall()
            else:
                rows = conn.execute(f"{query} ORDER BY rowid DESC LIMIT ?", (*params, int(limit)))
                rows = rows.fetchall()[::-1]
        return [_change_from_row(row) for row in rows]

    def load_delta_log(self, session_id: str) -> DeltaLog:
        """The session's delta log: each present object's change seq, the tombstones (removed
        objects kept as history are tombstones too), seq and floor."""
        with self._transaction(write=False) as conn:
            seq, floor = _session_row(conn, session_id, "seq, delta_floor")
            upserted = conn.execute(
                "SELECT object_id, change_seq FROM objects"
                " WHERE session_id = ? AND state = 'present'",
                (session_id,),
            ).fetchall()
            removed = conn.execute(
                "SELECT object_id, seq FROM tombstones WHERE session_id = ?", (session_id,)
            ).fetchall()
        return DeltaLog.from_state(
            {"seq": seq, "floor": floor, "upserted_at": dict(upserted), "removed_at": dict(removed)}
        )

    def trim_tombstones(self, session_id: str, floor: int) -> None:
        """Forget the removals at or before `floor`; raise the stored floor to it (removed
        objects kept as history stay)."""
        floor = int(floor)

        def trim(conn: sqlite3.Connection) -> None:
            seq, stored_floor = _session_row(conn, session_id, "seq, delta_floor")
            if floor > seq:
                raise ValueError(
                    f"session {session_id!r}: floor {floor} is beyond the stored seq {seq}"
                )
            if floor <= stored_floor:
                return
            conn.execute(
                "DELETE FROM tombstones WHERE session_id = ? AND seq <= ?", (session_id, floor)
            )
            conn.execute(
                "UPDATE sessions SET delta_floor = ? WHERE session_id = ?", (floor, session_id)
            )

        self._write(trim)


# ---------------------------------------------------------------------- rows <-> objects
def _to_json(value: Any) -> str:
    # allow_nan=False: what is stored stays valid JSON for any reader.
    return json.dumps(value, allow_nan=False)


def _is_storage_error(exc: sqlite3.Error) -> bool:
    """True when SQLite says the storage refused the operation (full, I/O, read-only, busy)."""
    code = getattr(exc, "sqlite_errorcode", None)
    return code is not None and code & 0xFF in _STORAGE_ERROR_CODES


def _session_row(conn: sqlite3.Connection, session_id: str, columns: str) -> tuple:
    """The given columns of the session's row; KeyError if there is no such session."""
    row = conn.execute(
        f"SELECT {columns} FROM sessions WHERE session_id = ?", (session_id,)
    ).fetchone()
    if row is None:
        raise KeyError(f"unknown session {session_id!r}")
    return row


def _checked_counters(counters: dict[str, int]) -> dict[str, int]:
    unknown = set(counters) - set(COUNTER_NAMES)
    if unknown:
        raise ValueError(
            f"unknown counters {sorted(unknown)}; known counters: {', '.join(COUNTER_NAMES)}"
        )
    return {name: int(value) for name, value in counters.items()}


def _checked_time(name: str, t: float | None) -> float | None:
    """`t` as a float (None stays None); ValueError naming it when it is not finite."""
    if t is None:
        return None
    t = float(t)
    if not math.isfinite(t):
        raise ValueError(f"{name} must be a finite time in seconds, got {t}")
    return t


def _pose_to_blob(pose: Any) -> bytes:
    """A camera-to-world pose ([4, 4] or [16], row-major) as 16 float32 little-endian."""
    values = np.ascontiguousarray(pose, dtype=_FLOAT32_LE).reshape(-1)
    if values.size != 16 or not np.isfinite(values).all():
        raise ValueError(f"last_pose must be 16 finite values (4x4), got {np.shape(pose)}")
    return values.tobytes()


def _session_from_row(row: tuple) -> SessionRecord:
    sid, name, mode, perception, knobs, token_hash, created_at, *counters = row
    frames, keyframes, bytes_in, bytes_out, next_object_id, last_used_at, last_t, pose = counters
    return SessionRecord(
        session_id=sid,
        name=name,
        mode=mode,
        perception=perception,
        knobs=json.loads(knobs),
        token_hash=token_hash,
        created_at=created_at,
        frames=frames,
        keyframes=keyframes,
        bytes_in=bytes_in,
        bytes_out=bytes_out,
        next_object_id=next_object_id,
        last_used_at=last_used_at,
        last_t=last_t,
        last_pose=None if pose is None else _float32_from_blob(pose, (16,)).tolist(),
    )


def _object_to_row(obj: MapObject) -> tuple:
    """The columns of _OBJECT_COLUMNS for one object; ValueError on badly shaped arrays,
    an unknown state, more than MAX_STAYS stays or a time that is not finite."""
    points = np.ascontiguousarray(obj.points, dtype=_FLOAT32_LE)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"object {obj.id}: points must be [N, 3], got shape {points.shape}")
    if not obj.confirmed:
        raise ValueError(f"object {obj.id}: only confirmed objects are persisted")
    embedding_dim: int | None = None
    embedding_bytes: bytes | None = None
    if obj.embedding_sum is not None:
        embedding = np.ascontiguousarray(obj.embedding_sum, dtype=_FLOAT32_LE)
        if embedding.ndim != 1:
            raise ValueError(f"object {obj.id}: embedding_sum must be [d], got {embedding.shape}")
        embedding_dim, embedding_bytes = len(embedding), embedding.tobytes()
    # Counter keeps insertion order and JSON objects keep theirs: label ties (first seen
    # wins) resolve the same way after a reload.
    labels = _to_json({str(label): int(count) for label, count in obj.label_counts.items()})
    if obj.state not in OBJECT_STATES:
        raise ValueError(f"object {obj.id}: state {obj.state!r} is not one of {OBJECT_STATES}")
    if len(obj.stays) > MAX_STAYS:
        raise ValueError(f"object {obj.id}: {len(obj.stays)} stays, over MAX_STAYS={MAX_STAYS}")
    for stay in obj.stays:
        if not np.isfinite([stay.t_from, stay.t_to, *stay.centroid, *stay.bbox]).all():
            raise ValueError(f"object {obj.id}: a stay holds a value that is not finite")
    stays = stays_to_bytes(obj.stays) if obj.stays else None
    return (
        int(obj.id),
        int(obj.version),
        int(obj.n_obs),
        int(obj.frames_seen),
        int(obj.first_seen),
        int(obj.last_seen),
        float(obj.resolution_m),
        labels,
        len(points),
        points.tobytes(),
        embedding_dim,
        embedding_bytes,
        obj.state,
        _checked_time(f"object {obj.id}: first_seen_t", obj.first_seen_t),
        _checked_time(f"object {obj.id}: last_seen_t", obj.last_seen_t),
        stays,
        _label_embeddings_to_blob(obj, embedding_dim),
    )


def _label_embeddings_to_blob(obj: MapObject, embedding_dim: int | None) -> bytes | None:
    """float32 LE [labels, embedding_dim], a row per label of label_counts in its order (NaN
    for a label without a sum); None when the object has no per-label sums."""
    if not obj.label_embeddings:
        return None
    unknown = [label for label in obj.label_embeddings if label not in obj.label_counts]
    if unknown or embedding_dim is None:
        raise ValueError(
            f"object {obj.id}: per-label embedding sums need an embedding_sum and labels that "
            f"are counted (not counted: {unknown})"
        )
    rows = np.full((len(obj.label_counts), embedding_dim), np.nan, _FLOAT32_LE)
    for i, label in enumerate(obj.label_counts):
        vector = obj.label_embeddings.get(label)
        if vector is None:
            continue
        vector = np.asarray(vector, dtype=_FLOAT32_LE)
        if vector.shape != (embedding_dim,):
            raise ValueError(
                f"object {obj.id}: the embedding sum of {label!r} must be [{embedding_dim}], "
                f"got {vector.shape}"
            )
        rows[i] = vector
    return rows.tobytes()


def _float32_from_blob(blob: bytes, shape: tuple[int, ...]) -> np.ndarray:
    """A writable native float32 array of `shape` from little-endian bytes."""
    array = np.frombuffer(blob, dtype=_FLOAT32_LE)
    if array.size != int(np.prod(shape)):
        raise StoreError(f"stored array has {array.size} values, expected shape {shape}")
    return array.astype(np.float32).reshape(shape)  # astype copies: frombuffer is read-only


def _object_from_row(row: tuple) -> MapObject:
    (
        object_id,
        version,
        n_obs,
        frames_seen,
        first_seen,
        last_seen,
        resolution_m,
        labels,
        n_points,
        points,
        embedding_dim,
        embedding_sum,
        state,
        first_seen_t,
        last_seen_t,
        stays,
        label_embeddings,
    ) = row
    label_counts = Counter(json.loads(labels))
    obj = MapObject(
        id=object_id,
        embedding_sum=(
            None if embedding_sum is None else _float32_from_blob(embedding_sum, (embedding_dim,))
        ),
        label_counts=label_counts,
        n_obs=n_obs,
        frames_seen=frames_seen,
        first_seen=first_seen,
        last_seen=last_seen,
        version=version,
        confirmed=True,
        label_embeddings=_label_embeddings_from_blob(label_embeddings, label_counts, embedding_dim),
        first_seen_t=first_seen_t,
        last_seen_t=last_seen_t,
        state=state,
        stays=[] if stays is None else stays_from_bytes(stays),
    )
    obj.set_points(_float32_from_blob(points, (n_points, 3)), resolution_m)
    return obj


def _label_embeddings_from_blob(
    blob: bytes | None, label_counts: Counter, embedding_dim: int | None
) -> dict[str, np.ndarray]:
    if blob is None:
        return {}
    rows = _float32_from_blob(blob, (len(label_counts), embedding_dim or 0))
    return {
        label: row for label, row in zip(label_counts, rows, strict=True) if not np.isnan(row).all()
    }


def _change_to_row(change: Change, seq: int) -> tuple:
    """The columns of _CHANGE_COLUMNS for one change at `seq`; ValueError on an unknown kind,
    a time that is not finite or a place that is not 3 finite numbers."""
    if change.kind not in CHANGE_KINDS:
        raise ValueError(f"change of object {change.id}: unknown kind {change.kind!r}")
    places: list[float | None] = []
    for name, xyz in (("from", change.from_xyz), ("to", change.to_xyz)):
        if xyz is None:
            places += [None, None, None]
            continue
        values = [float(v) for v in xyz]
        if len(values) != 3 or not all(math.isfinite(v) for v in values):
            raise ValueError(f"change of object {change.id}: {name} must be 3 finite numbers")
        places += values
    t = _checked_time(f"change of object {change.id}: t", change.t)
    return (int(change.id), change.kind, t, str(change.label), *places, seq)


def _change_from_row(row: tuple) -> Change:
    object_id, kind, t, label, fx, fy, fz, tx, ty, tz, seq = row
    return Change(
        id=object_id,
        kind=kind,
        t=t,
        label=label,
        from_xyz=None if fx is None else (fx, fy, fz),
        to_xyz=None if tx is None else (tx, ty, tz),
        seq=seq,
    )
