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
stays are `stays_to_bytes` records. Knobs and label counts are JSON. `rows.py` encodes and
checks them, the same for every store.

The living map (schema 4): an object removed from the map but kept as history keeps its row
with state 'removed' (its last fields: stays, last points); every read of the present map
(objects, counts, the delta log) takes state 'present' only, and its removal stays in
`tombstones` like any other. Changes are rows of `changes` in arrival (rowid) order, written
in the keyframe's transaction.

Map shards (schema 5): a session's owner, epoch and lease are columns of its row; a claim,
a renewal or an epoch check reads and writes them in the transaction of the call (BEGIN
IMMEDIATE: one writer at a time, across processes too), so two claims never both win and a
fenced write changes nothing. The acks a commit remembers are rows of `done_acks`, in
insertion (rowid) order; the shard registry is `shards`.

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
from collections.abc import Callable, Collection, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from app.mapping.deltas import DeltaLog
from app.mapping.object import MAX_STAYS, STAY_BYTES, Change, MapObject
from app.store.base import (
    SessionRecord,
    ShardRecord,
    Store,
    StoredSession,
    StoreError,
    StoreUnavailableError,
    StoreVersionError,
)
from app.store.rows import (
    CHANGE_COLUMNS,
    CLAIM_SESSION,
    COUNT_SESSIONS,
    DONE_ACK,
    FORGET_SHARD,
    HEARTBEAT_SHARD,
    LIVE_SHARDS,
    N_OBJECT_COLUMNS,
    N_SESSION_COLUMNS,
    OBJECT_COLUMNS,
    RELEASE_OWNED,
    RELEASE_SESSION,
    RENEW_LEASE,
    SESSION_COLUMNS,
    change_filter,
    change_from_row,
    check_epoch,
    check_room,
    checked_counters,
    claimed_epoch,
    clock,
    lease_end,
    not_renewed,
    object_from_row,
    prepare_keyframe,
    session_from_row,
    session_to_row,
    shard_from_row,
    to_json,
)

__all__ = ["SCHEMA_VERSION", "SqliteStore"]

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
    # 4 -> 5: map shards. Each session's owner (the shard holding it), epoch (bumped at each
    # claim: a write naming an older one is fenced) and the owner's lease; frames that came
    # as sightings; the acks of each session's newest frames, so a frame sent again is
    # answered instead of mapped twice; the shard registry. Sessions from before it have no
    # owner, epoch 0 and no sightings.
    (
        "ALTER TABLE sessions ADD COLUMN sightings INTEGER NOT NULL DEFAULT 0",
        "ALTER TABLE sessions ADD COLUMN owner TEXT",  # the shard holding it; NULL: none
        "ALTER TABLE sessions ADD COLUMN epoch INTEGER NOT NULL DEFAULT 0",
        "ALTER TABLE sessions ADD COLUMN lease_until REAL",  # unix time, seconds
        "CREATE INDEX sessions_by_owner ON sessions (owner)",
        """
        CREATE TABLE done_acks (
            done_id    INTEGER PRIMARY KEY,       -- the rowid: insertion order
            session_id TEXT NOT NULL REFERENCES sessions (session_id) ON DELETE CASCADE,
            stream_id  TEXT NOT NULL,
            seq        INTEGER NOT NULL,          -- the frame's seq in its stream
            ack        BLOB NOT NULL,             -- what the server answered, as it keeps it
            UNIQUE (session_id, stream_id, seq)
        )
        """,
        "CREATE INDEX done_acks_in_order ON done_acks (session_id, done_id)",
        """
        CREATE TABLE shards (
            name         TEXT PRIMARY KEY,
            url          TEXT NOT NULL,           -- where gateways reach the shard
            heartbeat_at REAL NOT NULL            -- unix time, seconds
        )
        """,
    ),
    # 5 -> 6: the session's up axis ("+x" ... "-z"), set at creation or inferred from the
    # poses, and where it came from ("set" or "inferred"); NULL while the default (+z)
    # applies, as for every session from before it.
    (
        "ALTER TABLE sessions ADD COLUMN up TEXT"
        " CHECK (up IS NULL OR up IN ('+x', '-x', '+y', '-y', '+z', '-z'))",
        "ALTER TABLE sessions ADD COLUMN up_source TEXT CHECK ((up IS NULL) = (up_source IS NULL)"
        " AND (up_source IS NULL OR up_source IN ('set', 'inferred')))",
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
    def create_session(self, rec: SessionRecord, max_sessions: int | None = None) -> None:
        """Persist a new session; ValueError if its id exists; StoredSessionsLimit when the
        store holds `max_sessions` (counted in the insert's transaction)."""
        row = session_to_row(rec)

        def create(conn: sqlite3.Connection) -> None:
            if max_sessions is not None:  # BEGIN IMMEDIATE: no other writer until COMMIT
                check_room(conn.execute(COUNT_SESSIONS).fetchone()[0], max_sessions)
            conn.execute(
                f"INSERT INTO sessions ({SESSION_COLUMNS}, seq, delta_floor)"
                f" VALUES ({', '.join('?' * N_SESSION_COLUMNS)}, 0, 0)",
                row,
            )

        try:
            self._write(create)
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
        epoch: int | None = None,
    ) -> None:
        """Change the given fields; counters are absolute values named as in COUNTER_NAMES.
        SessionFenced (nothing changed) when `epoch` is given and stale."""
        assignments: dict[str, Any] = checked_counters(counters or {})
        if name is not None:
            assignments["name"] = name
        if knobs is not None:
            assignments["knobs"] = to_json(knobs)
        if last_used_at is not None:
            assignments["last_used_at"] = float(last_used_at)

        def update(conn: sqlite3.Connection) -> None:
            (stored_epoch,) = _session_row(conn, session_id, "epoch")
            check_epoch(session_id, stored_epoch, epoch)
            if assignments:
                # Column names come from the fixed set above, never from the caller.
                columns = ", ".join(f"{column} = ?" for column in assignments)
                conn.execute(
                    f"UPDATE sessions SET {columns} WHERE session_id = ?",
                    (*assignments.values(), session_id),
                )

        self._write(update)

    def delete_session(self, session_id: str) -> None:
        """Remove the session with its objects, tombstones, changes and remembered acks
        (no-op if unknown)."""
        self._write(
            lambda conn: conn.execute("DELETE FROM sessions WHERE session_id = ?", (session_id,))
        )

    def list_sessions(self) -> list[SessionRecord]:
        """Every session, oldest first."""
        with self._transaction(write=False) as conn:
            rows = conn.execute(
                f"SELECT {SESSION_COLUMNS} FROM sessions ORDER BY created_at, session_id"
            ).fetchall()
        return [session_from_row(row) for row in rows]

    def load_session(self, session_id: str) -> SessionRecord:
        """One session as last committed; KeyError if unknown."""
        with self._transaction(write=False) as conn:
            return session_from_row(_session_row(conn, session_id, SESSION_COLUMNS))

    def count_sessions(self) -> int:
        """How many sessions are stored."""
        with self._transaction(write=False) as conn:
            return conn.execute("SELECT count(*) FROM sessions").fetchone()[0]

    def list_stored(self) -> list[StoredSession]:
        """Every session with its present object count and update seq, oldest first; objects
        are counted on the index by state, no map is read."""
        with self._transaction(write=False) as conn:
            rows = conn.execute(
                f"SELECT {SESSION_COLUMNS}, seq, (SELECT count(*) FROM objects AS o"
                " WHERE o.session_id = s.session_id AND o.state = 'present')"
                " FROM sessions AS s ORDER BY created_at, session_id"
            ).fetchall()
        return [StoredSession(session_from_row(row[:-2]), row[-1], row[-2]) for row in rows]

    def idle_sessions(self, used_before: float) -> list[str]:
        """Ids of the sessions whose `last_used_at` is before `used_before` (unix time)."""
        with self._transaction(write=False) as conn:
            rows = conn.execute(
                "SELECT session_id FROM sessions WHERE last_used_at < ? ORDER BY last_used_at",
                (float(used_before),),
            ).fetchall()
        return [row[0] for row in rows]

    # ------------------------------------------------------------------ owners (map shards)
    def claim_session(
        self, session_id: str, owner: str, lease_s: float, now: float | None = None
    ) -> int:
        """`Store.claim_session`: the holder read and the claim written in one transaction
        (BEGIN IMMEDIATE: no other writer in between, in any process)."""
        now = clock(now)
        lease_until = lease_end(lease_s, now)

        def claim(conn: sqlite3.Connection) -> int:
            held_by, held_until, stored_epoch = _session_row(
                conn, session_id, "owner, lease_until, epoch"
            )
            epoch = claimed_epoch(session_id, held_by, held_until, stored_epoch, owner, now)
            conn.execute(CLAIM_SESSION, (owner, epoch, lease_until, session_id))
            return epoch

        return self._write(claim)

    def renew_leases(
        self, owner: str, epochs: Mapping[str, int], lease_s: float, now: float | None = None
    ) -> list[str]:
        """`Store.renew_leases`, in one transaction: the ids `owner` no longer holds there."""
        lease_until = lease_end(lease_s, now)
        if not epochs:
            return []

        def renew(conn: sqlite3.Connection) -> list[str]:
            return [
                sid
                for sid, epoch in epochs.items()
                if conn.execute(RENEW_LEASE, (lease_until, sid, owner, int(epoch))).rowcount
            ]

        return not_renewed(epochs, self._write(renew))

    def release_session(self, session_id: str, owner: str, epoch: int) -> None:
        """No owner, no lease (the epoch kept) if `owner` holds the session at `epoch`."""
        self._write(lambda conn: conn.execute(RELEASE_SESSION, (session_id, owner, int(epoch))))

    def heartbeat_shard(self, name: str, url: str, now: float | None = None) -> None:
        """Shard `name`, at `url`, is alive at `now` (time.time() when None)."""
        heartbeat_at = clock(now)
        self._write(lambda conn: conn.execute(HEARTBEAT_SHARD, (name, url, heartbeat_at)))

    def live_shards(self, max_age_s: float, now: float | None = None) -> list[ShardRecord]:
        """The shards heard from at or after `now - max_age_s`, by name."""
        oldest = clock(now) - float(max_age_s)
        with self._transaction(write=False) as conn:
            rows = conn.execute(LIVE_SHARDS, (oldest,)).fetchall()
        return [shard_from_row(row) for row in rows]

    def forget_shard(self, name: str) -> None:
        """Shard `name` leaves the registry; its sessions are released (epochs kept)."""

        def forget(conn: sqlite3.Connection) -> None:
            conn.execute(FORGET_SHARD, (name,))
            conn.execute(RELEASE_OWNED, (name,))

        self._write(forget)

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
        epoch: int | None = None,
        done: tuple[str, int, bytes] | None = None,
        inferred_up: str | None = None,
    ) -> None:
        """`Store.commit_keyframe`, in one SQLite transaction (WAL, synchronous): returns
        once the changes survive kill -9; storage errors raise StoreUnavailableError."""
        keyframe = prepare_keyframe(
            session_id,
            seq,
            upserts,
            removed,
            counters,
            next_object_id,
            last_used_at,
            retired,
            changes,
            retracted_added,
            retracted_removed,
            last_t,
            last_pose,
            epoch,
            done,
            inferred_up,
        )
        seq = keyframe.seq

        def commit(conn: sqlite3.Connection) -> None:
            stored_seq, stored_next_id, stored_epoch = _session_row(
                conn, session_id, "seq, next_object_id, epoch"
            )
            assignments = keyframe.check_follows(stored_seq, stored_next_id, stored_epoch)
            columns = ", ".join(f"{column} = ?" for column in assignments)
            conn.execute(
                f"UPDATE sessions SET {columns} WHERE session_id = ?",
                (*assignments.values(), session_id),
            )
            # Retired objects are rewritten below with state 'removed': only the others go.
            conn.executemany(
                "DELETE FROM objects WHERE session_id = ? AND object_id = ?",
                [(session_id, oid) for oid in keyframe.deleted_ids],
            )
            conn.executemany(
                "INSERT OR REPLACE INTO tombstones (session_id, object_id, seq) VALUES (?, ?, ?)",
                [(session_id, oid, seq) for oid in keyframe.removed_ids],
            )
            conn.executemany(
                "DELETE FROM tombstones WHERE session_id = ? AND object_id = ?",
                [(session_id, int(obj.id)) for obj in keyframe.kept],
            )
            # A generator: each object is serialised as it is written, so nothing is copied
            # twice, and a bad object aborts the transaction (rolling back the rows before it).
            conn.executemany(
                f"INSERT OR REPLACE INTO objects (session_id, change_seq, {OBJECT_COLUMNS})"
                f" VALUES (?, ?, {', '.join('?' * N_OBJECT_COLUMNS)})",
                ((session_id, seq, *row) for row in keyframe.object_rows()),
            )
            # Before the inserts: a removal this commit takes back is an earlier one.
            conn.executemany(
                "DELETE FROM changes WHERE session_id = ? AND object_id = ? AND kind = 'removed'",
                [(session_id, oid) for oid in keyframe.revived_ids],
            )
            conn.executemany(
                f"INSERT INTO changes (session_id, {CHANGE_COLUMNS})"
                " VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                [(session_id, *row) for row in keyframe.change_rows],
            )
            # After the inserts: no `added` change stays for a retracted id, this one's too.
            conn.executemany(
                "DELETE FROM changes WHERE session_id = ? AND object_id = ? AND kind = 'added'",
                [(session_id, oid) for oid in keyframe.retracted_ids],
            )
            for statement, params in keyframe.done_statements():
                conn.execute(statement, params)

        self._write(commit)

    def done_ack(self, session_id: str, stream_id: str, seq: int) -> bytes | None:
        """The ack remembered for frame `seq` of `stream_id`; None if none is."""
        with self._transaction(write=False) as conn:
            _session_row(conn, session_id, "1")
            row = conn.execute(DONE_ACK, (session_id, stream_id, int(seq))).fetchone()
        return None if row is None else bytes(row[0])

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
                f"SELECT {OBJECT_COLUMNS} FROM objects WHERE session_id = ? AND state = ?"
                " ORDER BY object_id",
                (session_id, state),
            ).fetchall()
        return [object_from_row(row) for row in rows]

    def load_object(self, session_id: str, object_id: int) -> MapObject | None:
        """One object, present or removed, as last committed; None if there is none."""
        with self._transaction(write=False) as conn:
            _session_row(conn, session_id, "1")
            row = conn.execute(
                f"SELECT {OBJECT_COLUMNS} FROM objects WHERE session_id = ? AND object_id = ?",
                (session_id, int(object_id)),
            ).fetchone()
        return None if row is None else object_from_row(row)

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
        wanted = change_filter(since_t, until_t, since_seq, kinds, limit)
        where, params = ["session_id = ?"], [session_id]
        for condition, value in (
            ("t >= ?", wanted.since_t),
            ("t <= ?", wanted.until_t),
            ("seq > ?", wanted.since_seq),
        ):
            if value is not None:
                where.append(condition)
                params.append(value)
        if wanted.kinds is not None:
            where.append(f"kind IN ({', '.join('?' * len(wanted.kinds))})")
            params.extend(wanted.kinds)
        query = f"SELECT {CHANGE_COLUMNS} FROM changes WHERE {' AND '.join(where)}"
        with self._transaction(write=False) as conn:
            _session_row(conn, session_id, "1")
            if wanted.limit is None:
                rows = conn.execute(f"{query} ORDER BY rowid", params).fetchall()
            else:
                rows = conn.execute(f"{query} ORDER BY rowid DESC LIMIT ?", (*params, wanted.limit))
                rows = rows.fetchall()[::-1]
        return [change_from_row(row) for row in rows]

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

    def trim_tombstones(self, session_id: str, floor: int, *, epoch: int | None = None) -> None:
        """Forget the removals at or before `floor`; raise the stored floor to it (removed
        objects kept as history stay). SessionFenced when `epoch` is given and stale."""
        floor = int(floor)

        def trim(conn: sqlite3.Connection) -> None:
            seq, stored_floor, stored_epoch = _session_row(
                conn, session_id, "seq, delta_floor, epoch"
            )
            check_epoch(session_id, stored_epoch, epoch)
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


# ---------------------------------------------------------------------- helpers
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
