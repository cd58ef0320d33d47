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

Schema: `schema_version` holds the version, the same number as SQLite's `user_version` for
the same logical schema (4: the living map; 5: map shards). PostgreSQL stores start at
version 4 (`_SCHEMA`) and are migrated from there, new ones too; a schema change is an entry
in `_MIGRATIONS` here and in `sqlite.py` (a test holds the two versions equal). Opening migrates under an advisory lock, so processes opening one database
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
from collections.abc import Callable, Collection, Iterator, Mapping
from contextlib import contextmanager
from typing import Any, TypeVar

import numpy as np
import psycopg
from psycopg import IsolationLevel, errors, sql
from psycopg.conninfo import conninfo_to_dict
from psycopg.types.string import TextBinaryLoader, TextLoader
from psycopg_pool import ConnectionPool, PoolClosed

from app.mapping.deltas import DeltaLog
from app.mapping.object import MAX_STAYS, STAY_BYTES, Change, MapObject
from app.store import StoreURLError, redact_url
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
    with_format_params,
)

__all__ = ["SCHEMA_VERSION", "PostgresStore"]

T = TypeVar("T")

CONNECT_TIMEOUT_S = 5
"""libpq's connect_timeout when the URL sets none; also how long a call waits for a pooled
connection before StoreUnavailableError."""
POOL_MAX_SIZE = 8
"""Connections a store keeps at most (the mapping pool, REST threads and the store thread
share them; a call waits for a free one)."""

_FIRST_VERSION = 4
"""The schema version `_SCHEMA` creates: the first one PostgreSQL stores had."""

_SCHEMA: tuple[str, ...] = (
    """
    CREATE TABLE schema_version (
        singleton boolean PRIMARY KEY DEFAULT true CHECK (singleton),  -- one row
        version   integer NOT NULL
    )
    """,
    """
    CREATE TABLE sessions (
        session_id     text COLLATE "C" PRIMARY KEY,  -- sorted by code point, as in SQLite
        name           text NOT NULL,
        mode           text NOT NULL,
        perception     text NOT NULL,
        knobs          json NOT NULL,             -- {knob: value}
        token_hash     text NOT NULL,
        created_at     double precision NOT NULL, -- unix time, seconds
        frames         bigint NOT NULL,
        keyframes      bigint NOT NULL,
        bytes_in       bigint NOT NULL,
        bytes_out      bigint NOT NULL,
        next_object_id bigint NOT NULL,
        seq            bigint NOT NULL,           -- the delta log's seq
        delta_floor    bigint NOT NULL,           -- the delta log's floor
        last_used_at   double precision NOT NULL, -- unix time, seconds (retention)
        last_t         double precision,          -- frame t of the last keyframe
        last_pose      bytea                      -- float32 LE [16], row-major 4x4
            CHECK (last_pose IS NULL OR length(last_pose) = 64)
    )
    """,
    "CREATE INDEX sessions_by_last_use ON sessions (last_used_at)",
    f"""
    CREATE TABLE objects (
        session_id    text COLLATE "C" NOT NULL
            REFERENCES sessions (session_id) ON DELETE CASCADE,
        object_id     bigint NOT NULL,
        change_seq    bigint NOT NULL,           -- seq of the commit that last changed it
        version       bigint NOT NULL,
        n_obs         bigint NOT NULL,
        frames_seen   bigint NOT NULL,
        first_seen    bigint NOT NULL,
        last_seen     bigint NOT NULL,
        resolution_m  double precision NOT NULL,
        label_counts  json NOT NULL,             -- {{label: count}}, in first-seen order
        n_points      integer NOT NULL,
        points        bytea NOT NULL,            -- float32 little-endian [n_points, 3]
        embedding_dim integer,                   -- NULL when the object has no embedding
        embedding_sum bytea,                     -- float32 little-endian [embedding_dim]
        state         text NOT NULL CHECK (state IN ('present', 'removed')),
        first_seen_t  double precision,          -- device clock, seconds
        last_seen_t   double precision,
        -- stays_to_bytes records, oldest first: at most MAX_STAYS; NULL for none
        stays         bytea CHECK (stays IS NULL OR (length(stays) % {STAY_BYTES} = 0
                                   AND length(stays) <= {MAX_STAYS * STAY_BYTES})),
        -- float32 LE [labels, embedding_dim], a row per label of label_counts (NaN: none)
        label_embeddings bytea CHECK (label_embeddings IS NULL OR (embedding_dim > 0
                                      AND length(label_embeddings) % (4 * embedding_dim) = 0)),
        PRIMARY KEY (session_id, object_id),
        CHECK (length(points) = 12 * n_points),
        CHECK ((embedding_dim IS NULL) = (embedding_sum IS NULL)),
        CHECK (embedding_sum IS NULL OR length(embedding_sum) = 4 * embedding_dim)
    )
    """,
    # Points and per-label sums are float noise: compressing them costs time and saves nothing.
    "ALTER TABLE objects ALTER COLUMN points SET STORAGE EXTERNAL",
    "ALTER TABLE objects ALTER COLUMN label_embeddings SET STORAGE EXTERNAL",
    # The present map's reads (delta log, counts) and the removed objects' from the index.
    "CREATE INDEX objects_by_state ON objects (session_id, state, object_id, change_seq)",
    """
    CREATE TABLE tombstones (
        session_id text COLLATE "C" NOT NULL
            REFERENCES sessions (session_id) ON DELETE CASCADE,
        object_id  bigint NOT NULL,
        seq        bigint NOT NULL,              -- seq of the commit that removed it
        PRIMARY KEY (session_id, object_id)
    )
    """,
    """
    CREATE TABLE changes (
        change_id  bigint GENERATED ALWAYS AS IDENTITY PRIMARY KEY,  -- arrival order
        session_id text COLLATE "C" NOT NULL
            REFERENCES sessions (session_id) ON DELETE CASCADE,
        object_id  bigint NOT NULL,
        kind       text NOT NULL CHECK (kind IN ('added', 'moved', 'removed')),
        t          double precision NOT NULL,    -- frame t that concluded it (device clock)
        label      text NOT NULL,
        from_x     double precision,             -- the old place, NULL where none
        from_y     double precision,
        from_z     double precision,
        to_x       double precision,             -- the new place, NULL where none
        to_y       double precision,
        to_z       double precision,
        seq        bigint NOT NULL,              -- the update seq of the commit
        CHECK ((from_x IS NULL) = (from_y IS NULL) AND (from_x IS NULL) = (from_z IS NULL)),
        CHECK ((to_x IS NULL) = (to_y IS NULL) AND (to_x IS NULL) = (to_z IS NULL))
    )
    """,
    "CREATE INDEX changes_in_order ON changes (session_id, change_id)",
    "CREATE INDEX changes_by_seq ON changes (session_id, seq)",
    "CREATE INDEX changes_by_t ON changes (session_id, t)",
)
"""Schema version 4 (`_FIRST_VERSION`), the same logical tables as SQLite's."""

_MIGRATIONS: tuple[tuple[str, ...], ...] = (
    # 4 -> 5: map shards. Each session's owner (the shard holding it), epoch (bumped at each
    # claim: a write naming an older one is fenced) and the owner's lease; frames that came
    # as sightings; the acks of each session's newest frames, so a frame sent again is
    # answered instead of mapped twice; the shard registry. Sessions from before it have no
    # owner, epoch 0 and no sightings.
    (
        "ALTER TABLE sessions ADD COLUMN sightings bigint NOT NULL DEFAULT 0",
        'ALTER TABLE sessions ADD COLUMN owner text COLLATE "C"',  # the shard; NULL: none
        "ALTER TABLE sessions ADD COLUMN epoch bigint NOT NULL DEFAULT 0",
        "ALTER TABLE sessions ADD COLUMN lease_until double precision",  # unix time, seconds
        "CREATE INDEX sessions_by_owner ON sessions (owner)",
        """
        CREATE TABLE done_acks (
            done_id    bigint GENERATED ALWAYS AS IDENTITY PRIMARY KEY,  -- insertion order
            session_id text COLLATE "C" NOT NULL
                REFERENCES sessions (session_id) ON DELETE CASCADE,
            stream_id  text NOT NULL,
            seq        bigint NOT NULL,              -- the frame's seq in its stream
            ack        bytea NOT NULL,               -- what the server answered, as it keeps it
            UNIQUE (session_id, stream_id, seq)
        )
        """,
        "CREATE INDEX done_acks_in_order ON done_acks (session_id, done_id)",
        """
        CREATE TABLE shards (
            name         text COLLATE "C" PRIMARY KEY,  -- listed by code point, as in SQLite
            url          text NOT NULL,                 -- where gateways reach the shard
            heartbeat_at double precision NOT NULL      -- unix time, seconds
        )
        """,
    ),
    # 5 -> 6: the session's up axis ("+x" ... "-z"), set at creation or inferred from the
    # poses, and where it came from ("set" or "inferred"); NULL while the default (+z)
    # applies, as for every session from before it.
    (
        "ALTER TABLE sessions ADD COLUMN up text"
        " CHECK (up IS NULL OR up IN ('+x', '-x', '+y', '-y', '+z', '-z'))",
        "ALTER TABLE sessions ADD COLUMN up_source text"
        " CHECK (up_source IS NULL OR up_source IN ('set', 'inferred'))",
        "ALTER TABLE sessions ADD CHECK ((up IS NULL) = (up_source IS NULL))",
    ),
)
"""_MIGRATIONS[i] takes a store from schema version _FIRST_VERSION + i to the next one,
in one transaction with the new version number."""

SCHEMA_VERSION = _FIRST_VERSION + len(_MIGRATIONS)
"""Stored in `schema_version`; equal to `sqlite.SCHEMA_VERSION` (the same logical schema)."""

_SCHEMA_LOCK = "semanticxr.store.schema"
"""Names the advisory lock held while a store creates or migrates the schema."""
_CREATE_LOCK = "semanticxr.store.create"
"""Names the advisory lock a creation holds from its count to its commit."""

_UNAVAILABLE = (psycopg.OperationalError, errors.ReadOnlySqlTransaction)
"""Errors meaning "the database cannot take this now" (unreachable, connection lost,
shutting down, disk full, too many connections, a read-only standby), not a bad call.
PoolTimeout, waiting for a connection, is an OperationalError."""

_RENEW_LEASES = (
    "UPDATE sessions AS s SET lease_until = %s"
    " FROM unnest(%s::text[], %s::bigint[]) AS held (session_id, epoch)"
    " WHERE s.session_id = held.session_id AND s.epoch = held.epoch AND s.owner = %s"
    " RETURNING s.session_id"
)
"""rows.RENEW_LEASE for many sessions in one round trip: (lease_until, ids, epochs, owner)."""

_OBJECT_UPSERT = (
    f"INSERT INTO objects (session_id, change_seq, {OBJECT_COLUMNS})"
    f" VALUES (%s, %s, {', '.join(['%s'] * N_OBJECT_COLUMNS)})"
    " ON CONFLICT (session_id, object_id) DO UPDATE SET "
    + ", ".join(
        f"{column} = EXCLUDED.{column}"
        for column in ["change_seq", *OBJECT_COLUMNS.replace(" ", "").split(",")[1:]]
    )
)


class PostgresStore(Store):
    """The `Store` in a PostgreSQL database (`postgresql://...`). Thread-safe."""

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
                for statement in _SCHEMA:
                    conn.execute(statement)
                conn.execute("INSERT INTO schema_version (version) VALUES (%s)", (_FIRST_VERSION,))
            version = conn.execute("SELECT version FROM schema_version").fetchone()[0]
            if version > SCHEMA_VERSION:
                raise StoreVersionError(
                    f"{self.where} has schema version {version}, newer than this SemanticXR "
                    f"understands ({SCHEMA_VERSION}); upgrade SemanticXR or use another database"
                )
            for migration in _MIGRATIONS[version - _FIRST_VERSION :]:
                for statement in migration:
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
    def _transaction(self, write: bool = True) -> Iterator[psycopg.Connection]:
        """One transaction on a pooled connection, rolled back if the block raises; reads
        are one REPEATABLE READ snapshot. Connection faults become StoreUnavailableError."""
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
                    yield conn
        except PoolClosed:
            raise StoreError(f"{self.where}: the store is closed") from None
        except _UNAVAILABLE as exc:
            raise StoreUnavailableError(
                f"{self.where}: the database cannot be used now ({_reason(exc)})"
            ) from exc
        except psycopg.DataError as exc:  # a value the columns cannot hold (NUL, > 64 bits)
            raise ValueError(f"{self.where}: {_reason(exc)}") from exc

    def _write(self, body: Callable[[psycopg.Connection], T]) -> T:
        """`body(conn)` in one write transaction."""
        with self._transaction() as conn:
            return body(conn)

    # ------------------------------------------------------------------ health
    def probe(self) -> None:
        """Return once a write can land (a pooled connection commits a one-row write that
        changes nothing); StoreUnavailableError if not."""
        self._write(lambda conn: conn.execute("UPDATE schema_version SET version = version"))

    # ------------------------------------------------------------------ sessions
    def create_session(self, rec: SessionRecord, max_sessions: int | None = None) -> None:
        """Persist a new session; ValueError if its id exists; StoredSessionsLimit when the
        store holds `max_sessions` (counted under the creations' lock, in the insert's
        transaction)."""
        row = session_to_row(rec)

        def create(conn: psycopg.Connection) -> int:
            # Every creation, limited or not, queues here: none lands between a count and
            # its insert. At READ COMMITTED the count sees each creation that went before.
            conn.execute("SELECT pg_advisory_xact_lock(hashtext(%s))", (_CREATE_LOCK,))
            if max_sessions is not None:
                check_room(conn.execute(COUNT_SESSIONS).fetchone()[0], max_sessions)
            return conn.execute(
                f"INSERT INTO sessions ({SESSION_COLUMNS}, seq, delta_floor)"
                f" VALUES ({', '.join(['%s'] * N_SESSION_COLUMNS)}, 0, 0)"
                " ON CONFLICT (session_id) DO NOTHING",
                row,
            ).rowcount

        if not self._write(create):
            raise ValueError(f"session {rec.session_id!r} already exists")

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
        SessionFenced (nothing changed) when `epoch` is given and stale (checked under the
        session row's lock)."""
        assignments: dict[str, Any] = checked_counters(counters or {})
        if name is not None:
            assignments["name"] = name
        if knobs is not None:
            assignments["knobs"] = to_json(knobs)
        if last_used_at is not None:
            assignments["last_used_at"] = float(last_used_at)

        def update(conn: psycopg.Connection) -> None:
            if epoch is not None or not assignments:
                (stored_epoch,) = _session_row(conn, session_id, "epoch", lock=epoch is not None)
                check_epoch(session_id, stored_epoch, epoch)
            if assignments and not _set_session(conn, session_id, assignments):
                raise KeyError(f"unknown session {session_id!r}")

        self._write(update)

    def delete_session(self, session_id: str) -> None:
        """Remove the session with its objects, tombstones, changes and remembered acks
        (no-op if unknown)."""
        self._write(
            lambda conn: conn.execute("DELETE FROM sessions WHERE session_id = %s", (session_id,))
        )

    def list_sessions(self) -> list[SessionRecord]:
        """Every session, oldest first."""
        with self._transaction(write=False) as conn:
            rows = conn.execute(
                f"SELECT {SESSION_COLUMNS} FROM sessions ORDER BY created_at, session_id",
                binary=True,
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
                " FROM sessions AS s ORDER BY created_at, session_id",
                binary=True,
            ).fetchall()
        return [StoredSession(session_from_row(row[:-2]), row[-1], row[-2]) for row in rows]

    def idle_sessions(self, used_before: float) -> list[str]:
        """Ids of the sessions whose `last_used_at` is before `used_before` (unix time)."""
        with self._transaction(write=False) as conn:
            rows = conn.execute(
                "SELECT session_id FROM sessions WHERE last_used_at < %s"
                " ORDER BY last_used_at, session_id",
                (float(used_before),),
            ).fetchall()
        return [row[0] for row in rows]

    # ------------------------------------------------------------------ owners (map shards)
    def claim_session(
        self, session_id: str, owner: str, lease_s: float, now: float | None = None
    ) -> int:
        """`Store.claim_session`: the holder read under the session row's lock and the claim
        written in the same transaction (a concurrent claim waits, then sees this one)."""
        now = clock(now)
        lease_until = lease_end(lease_s, now)

        def claim(conn: psycopg.Connection) -> int:
            held_by, held_until, stored_epoch = _session_row(
                conn, session_id, "owner, lease_until, epoch", lock=True
            )
            epoch = claimed_epoch(session_id, held_by, held_until, stored_epoch, owner, now)
            conn.execute(with_format_params(CLAIM_SESSION), (owner, epoch, lease_until, session_id))
            return epoch

        return self._write(claim)

    def renew_leases(
        self, owner: str, epochs: Mapping[str, int], lease_s: float, now: float | None = None
    ) -> list[str]:
        """`Store.renew_leases`, in one statement: the ids `owner` no longer holds there."""
        lease_until = lease_end(lease_s, now)
        if not epochs:
            return []
        ids, held_epochs = list(epochs), [int(epoch) for epoch in epochs.values()]
        rows = self._write(
            lambda conn: conn.execute(
                _RENEW_LEASES, (lease_until, ids, held_epochs, owner)
            ).fetchall()
        )
        return not_renewed(epochs, [row[0] for row in rows])

    def release_session(self, session_id: str, owner: str, epoch: int) -> None:
        """No owner, no lease (the epoch kept) if `owner` holds the session at `epoch`."""
        self._write(
            lambda conn: conn.execute(
                with_format_params(RELEASE_SESSION), (session_id, owner, int(epoch))
            )
        )

    def heartbeat_shard(self, name: str, url: str, now: float | None = None) -> None:
        """Shard `name`, at `url`, is alive at `now` (time.time() when None)."""
        heartbeat_at = clock(now)
        self._write(
            lambda conn: conn.execute(
                with_format_params(HEARTBEAT_SHARD), (name, url, heartbeat_at)
            )
        )

    def live_shards(self, max_age_s: float, now: float | None = None) -> list[ShardRecord]:
        """The shards heard from at or after `now - max_age_s`, by name (code point order)."""
        oldest = clock(now) - float(max_age_s)
        with self._transaction(write=False) as conn:
            rows = conn.execute(with_format_params(LIVE_SHARDS), (oldest,)).fetchall()
        return [shard_from_row(row) for row in rows]

    def forget_shard(self, name: str) -> None:
        """Shard `name` leaves the registry; its sessions are released (epochs kept)."""

        def forget(conn: psycopg.Connection) -> None:
            conn.execute(with_format_params(FORGET_SHARD), (name,))
            conn.execute(with_format_params(RELEASE_OWNED), (name,))

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
        """`Store.commit_keyframe`, in one transaction under the session row's lock (the epoch
        checked under it): returns once the server has committed it; faults raise
        StoreUnavailableError."""
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

        def commit(conn: psycopg.Connection) -> None:
            # The row lock orders this session's commits (and trims, claims, deletions) one
            # by one: no claim lands between the epoch's check and the commit.
            stored_seq, stored_next_id, stored_epoch = _session_row(
                conn, session_id, "seq, next_object_id, epoch", lock=True
            )
            assignments = keyframe.check_follows(stored_seq, stored_next_id, stored_epoch)
            cursor = conn.cursor()
            # One round trip for the lot: statements go out without waiting for each answer.
            with conn.pipeline():
                _set_session(conn, session_id, assignments)
                if keyframe.deleted_ids:  # retired objects are rewritten below: not these
                    cursor.execute(
                        "DELETE FROM objects WHERE session_id = %s AND object_id = ANY(%s)",
                        (session_id, keyframe.deleted_ids),
                    )
                if keyframe.removed_ids:
                    cursor.execute(
                        "INSERT INTO tombstones (session_id, object_id, seq)"
                        " SELECT %s, unnest(%s::bigint[]), %s"
                        " ON CONFLICT (session_id, object_id) DO UPDATE SET seq = EXCLUDED.seq",
                        (session_id, keyframe.removed_ids, seq),
                    )
                if keyframe.kept:
                    cursor.execute(
                        "DELETE FROM tombstones WHERE session_id = %s AND object_id = ANY(%s)",
                        (session_id, [int(obj.id) for obj in keyframe.kept]),
                    )
                # A generator: each object is encoded as it is sent, and a bad one aborts
                # the transaction (rolling back the rows before it).
                cursor.executemany(
                    _OBJECT_UPSERT, ((session_id, seq, *row) for row in keyframe.object_rows())
                )
                if keyframe.revived_ids:  # before the inserts: an earlier removal goes
                    cursor.execute(
                        "DELETE FROM changes WHERE session_id = %s AND object_id = ANY(%s)"
                        " AND kind = 'removed'",
                        (session_id, keyframe.revived_ids),
                    )
                cursor.executemany(
                    f"INSERT INTO changes (session_id, {CHANGE_COLUMNS})"
                    f" VALUES (%s, {', '.join(['%s'] * len(CHANGE_COLUMNS.split(',')))})",
                    [(session_id, *row) for row in keyframe.change_rows],
                )
                if keyframe.retracted_ids:  # after the inserts: this commit's `added` too
                    cursor.execute(
                        "DELETE FROM changes WHERE session_id = %s AND object_id = ANY(%s)"
                        " AND kind = 'added'",
                        (session_id, keyframe.retracted_ids),
                    )
                for statement, params in keyframe.done_statements():
                    cursor.execute(with_format_params(statement), params)

        self._write(commit)

    def done_ack(self, session_id: str, stream_id: str, seq: int) -> bytes | None:
        """The ack remembered for frame `seq` of `stream_id`; None if none is."""
        with self._transaction(write=False) as conn:
            _session_row(conn, session_id, "1")
            row = conn.execute(
                with_format_params(DONE_ACK), (session_id, stream_id, int(seq)), binary=True
            ).fetchone()
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
                f"SELECT {OBJECT_COLUMNS} FROM objects WHERE session_id = %s AND state = %s"
                " ORDER BY object_id",
                (session_id, state),
                binary=True,  # bytea as it is, no hex
            ).fetchall()
        return [object_from_row(row) for row in rows]

    def load_object(self, session_id: str, object_id: int) -> MapObject | None:
        """One object, present or removed, as last committed; None if there is none."""
        with self._transaction(write=False) as conn:
            _session_row(conn, session_id, "1")
            row = conn.execute(
                f"SELECT {OBJECT_COLUMNS} FROM objects WHERE session_id = %s AND object_id = %s",
                (session_id, int(object_id)),
                binary=True,
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
        where, params = ["session_id = %s"], [session_id]
        for condition, value in (
            ("t >= %s", wanted.since_t),
            ("t <= %s", wanted.until_t),
            ("seq > %s", wanted.since_seq),
            ("kind = ANY(%s::text[])", wanted.kinds),
        ):
            if value is not None:
                where.append(condition)
                params.append(value)
        query = f"SELECT {CHANGE_COLUMNS} FROM changes WHERE {' AND '.join(where)}"
        with self._transaction(write=False) as conn:
            _session_row(conn, session_id, "1")
            if wanted.limit is None:
                rows = conn.execute(f"{query} ORDER BY change_id", params).fetchall()
            else:
                rows = conn.execute(
                    f"{query} ORDER BY change_id DESC LIMIT %s", (*params, wanted.limit)
                ).fetchall()[::-1]
        return [change_from_row(row) for row in rows]

    def load_delta_log(self, session_id: str) -> DeltaLog:
        """The session's delta log: each present object's change seq, the tombstones (removed
        objects kept as history are tombstones too), seq and floor."""
        with self._transaction(write=False) as conn:
            seq, floor = _session_row(conn, session_id, "seq, delta_floor")
            upserted = conn.execute(
                "SELECT object_id, change_seq FROM objects"
                " WHERE session_id = %s AND state = 'present' ORDER BY object_id",
                (session_id,),
            ).fetchall()
            removed = conn.execute(
                "SELECT object_id, seq FROM tombstones WHERE session_id = %s ORDER BY object_id",
                (session_id,),
            ).fetchall()
        return DeltaLog.from_state(
            {"seq": seq, "floor": floor, "upserted_at": dict(upserted), "removed_at": dict(removed)}
        )

    def trim_tombstones(self, session_id: str, floor: int, *, epoch: int | None = None) -> None:
        """Forget the removals at or before `floor`; raise the stored floor to it (removed
        objects kept as history stay). SessionFenced when `epoch` is given and stale."""
        floor = int(floor)

        def trim(conn: psycopg.Connection) -> None:
            seq, stored_floor, stored_epoch = _session_row(
                conn, session_id, "seq, delta_floor, epoch", lock=True
            )
            check_epoch(session_id, stored_epoch, epoch)
            if floor > seq:
                raise ValueError(
                    f"session {session_id!r}: floor {floor} is beyond the stored seq {seq}"
                )
            if floor <= stored_floor:
                return
            conn.execute(
                "DELETE FROM tombstones WHERE session_id = %s AND seq <= %s", (session_id, floor)
            )
            conn.execute(
                "UPDATE sessions SET delta_floor = %s WHERE session_id = %s", (floor, session_id)
            )

        self._write(trim)


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


def _session_row(
    conn: psycopg.Connection, session_id: str, columns: str, *, lock: bool = False
) -> tuple:
    """The given columns of the session's row (locked for this transaction's update if
    `lock`); KeyError if there is no such session."""
    row = conn.execute(
        f"SELECT {columns} FROM sessions WHERE session_id = %s"
        + (" FOR NO KEY UPDATE" if lock else ""),
        (session_id,),
        binary=True,
    ).fetchone()
    if row is None:
        raise KeyError(f"unknown session {session_id!r}")
    return row


def _set_session(conn: psycopg.Connection, session_id: str, assignments: dict[str, Any]) -> int:
    """Set the session's columns (names from the stores' fixed sets, never a caller's);
    how many rows changed (0: no such session)."""
    columns = sql.SQL(", ").join(
        sql.SQL("{} = %s").format(sql.Identifier(column)) for column in assignments
    )
    return conn.execute(
        sql.SQL("UPDATE sessions SET {} WHERE session_id = %s").format(columns),
        (*assignments.values(), session_id),
    ).rowcount
