"""`SqlStore`: every query of a store, written once for every SQL database.

What is stored is exactly what the server has acknowledged: the server calls
`commit_keyframe` before it acks a keyframe, and that call returns only once one
transaction holding the keyframe's object changes, tombstones, counters and update seq has
committed. After a restart `load_objects` and `load_delta_log` give back the confirmed map and
the delta log, so the update seq continues and a subscriber resuming with `since` loses
nothing.

The statements are written with `?` placeholders and run through the store's `Dialect`
(`dialect.py`), which spells what differs between databases; the tables are `schema.py`'s
and the values in them `rows.py`'s. A store of one database (`sqlite.py`, `postgres.py`)
adds the connection, its transactions and its errors: `_transaction` gives a connection (or
cursor) in one transaction, `_write` runs a body in a write transaction, `_pipeline` lets a
batch of statements go out without waiting for each answer.

The living map: an object removed from the map but kept as history keeps its row with state
'removed' (its last fields: stays, last points); every read of the present map (objects,
counts, the delta log) takes state 'present' only, and its removal stays in `tombstones`
like any other. Changes are rows of `changes` in arrival order, written in the keyframe's
transaction.

Map shards: a session's owner, epoch and lease are columns of its row; a claim, a renewal or
an epoch check reads and writes them in the transaction of the call, the session's row
locked first (`Dialect.lock_row`), so two claims never both win and a fenced write changes
nothing. The acks a commit remembers are rows of `done_acks`, in insertion order; the shard
registry is `shards`.
"""

from __future__ import annotations

import abc
import contextlib
from collections.abc import Callable, Collection, Mapping
from contextlib import AbstractContextManager
from typing import Any, TypeVar

from app.mapping.deltas import DeltaLog
from app.mapping.object import Change, MapObject
from app.store.base import (
    DONE_WINDOW,
    KeyframeCommit,
    SessionRecord,
    ShardRecord,
    Store,
    StoredSession,
)
from app.store.dialect import Dialect
from app.store.rows import (
    CHANGE_COLUMNS,
    N_OBJECT_COLUMNS,
    N_SESSION_COLUMNS,
    OBJECT_COLUMNS,
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

__all__ = ["SqlStore"]

T = TypeVar("T")
Connection = Any
"""What `_transaction` gives: an object with `execute(statement, params)` returning a
cursor (`fetchone`, `fetchall`, `rowcount`) and `executemany(statement, rows)`."""

CREATE_LOCK = "semanticxr.store.create"
"""Names the lock a creation holds from its count to its commit (`Dialect.lock_creations`)."""


def _marks(n: int) -> str:
    return ", ".join(["?"] * n)


# ---------------------------------------------------------------------- statements
INSERT_SESSION = (
    f"INSERT INTO sessions ({SESSION_COLUMNS}, seq, delta_floor)"
    f" VALUES ({_marks(N_SESSION_COLUMNS)}, 0, 0) ON CONFLICT (session_id) DO NOTHING"
)
"""(`session_to_row`): a new session at seq 0; no row changed when the id exists."""
COUNT_SESSIONS = "SELECT count(*) FROM sessions"
LIST_SESSIONS = f"SELECT {SESSION_COLUMNS} FROM sessions ORDER BY created_at, session_id"
LIST_STORED = (
    f"SELECT {SESSION_COLUMNS}, seq, (SELECT count(*) FROM objects AS o"
    " WHERE o.session_id = s.session_id AND o.state = 'present')"
    " FROM sessions AS s ORDER BY created_at, session_id"
)
"""Each session's row, seq and present objects counted on the index by state."""
IDLE_SESSIONS = (
    "SELECT session_id FROM sessions WHERE last_used_at < ? ORDER BY last_used_at, session_id"
)
DELETE_SESSION = "DELETE FROM sessions WHERE session_id = ?"
"""Its objects, tombstones, changes and acks go with it (ON DELETE CASCADE)."""

CLAIM_SESSION = "UPDATE sessions SET owner = ?, epoch = ?, lease_until = ? WHERE session_id = ?"
"""(owner, new epoch, lease_until, session_id), once `claimed_epoch` allowed it."""
RENEW_LEASE = "UPDATE sessions SET lease_until = ? WHERE session_id = ? AND owner = ? AND epoch = ?"
"""(lease_until, session_id, owner, epoch): one row changed while the owner holds it there."""
RENEW_LEASES = (
    "UPDATE sessions AS s SET lease_until = ?"
    " FROM unnest(?::text[], ?::bigint[]) AS held (session_id, epoch)"
    " WHERE s.session_id = held.session_id AND s.epoch = held.epoch AND s.owner = ?"
    " RETURNING s.session_id"
)
"""RENEW_LEASE for many sessions in one statement, where ids batch (arrays):
(lease_until, ids, epochs, owner)."""
RELEASE_SESSION = (
    "UPDATE sessions SET owner = NULL, lease_until = NULL"
    " WHERE session_id = ? AND owner = ? AND epoch = ?"
)
"""(session_id, owner, epoch): the epoch stays, so the released owner stays fenced."""
RELEASE_OWNED = "UPDATE sessions SET owner = NULL, lease_until = NULL WHERE owner = ?"
"""(owner,): every session a forgotten shard held, claimable at once."""
HEARTBEAT_SHARD = (
    "INSERT INTO shards (name, url, heartbeat_at) VALUES (?, ?, ?)"
    " ON CONFLICT (name) DO UPDATE SET url = excluded.url, heartbeat_at = excluded.heartbeat_at"
)
LIVE_SHARDS = "SELECT name, url, heartbeat_at FROM shards WHERE heartbeat_at >= ? ORDER BY name"
"""(oldest heartbeat_at,): rows for `shard_from_row`."""
FORGET_SHARD = "DELETE FROM shards WHERE name = ?"

DELETE_OBJECTS = "DELETE FROM objects WHERE session_id = ? AND object_id {in_ids}"
TOMBSTONE = (
    "INSERT INTO tombstones (session_id, object_id, seq) SELECT ?, {each_id}, ? WHERE true"
    " ON CONFLICT (session_id, object_id) DO UPDATE SET seq = excluded.seq"
)
"""(session_id, ids, seq); `WHERE true` keeps SQLite's parser from reading ON as a join's."""
FORGET_TOMBSTONES = "DELETE FROM tombstones WHERE session_id = ? AND object_id {in_ids}"
UPSERT_OBJECT = (
    f"INSERT INTO objects (session_id, change_seq, {OBJECT_COLUMNS})"
    f" VALUES (?, ?, {_marks(N_OBJECT_COLUMNS)})"
    " ON CONFLICT (session_id, object_id) DO UPDATE SET "
    + ", ".join(
        f"{column} = excluded.{column}"
        for column in ["change_seq", *OBJECT_COLUMNS.replace(" ", "").split(",")[1:]]
    )
)
"""(session_id, change_seq, `object_to_row`)."""
DELETE_CHANGES = "DELETE FROM changes WHERE session_id = ? AND object_id {in_ids} AND kind = ?"
"""(session_id, ids, kind)."""
INSERT_CHANGE = (
    f"INSERT INTO changes (session_id, {CHANGE_COLUMNS})"
    f" VALUES (?, {_marks(len(CHANGE_COLUMNS.split(',')))})"
)
"""(session_id, `change_to_row`); the database gives its arrival order."""
REMEMBER_DONE = (
    "INSERT INTO done_acks (session_id, stream_id, seq, ack) VALUES (?, ?, ?, ?)"
    " ON CONFLICT (session_id, stream_id, seq) DO UPDATE SET ack = excluded.ack"
)
"""(session_id, stream_id, seq, ack); done_id (insertion order) is given by the database."""
FORGET_OLD_DONE = (
    "DELETE FROM done_acks WHERE session_id = ? AND done_id <= (SELECT done_id FROM done_acks"
    " WHERE session_id = ? ORDER BY done_id DESC LIMIT 1 OFFSET ?)"
)
"""(session_id, session_id, DONE_WINDOW): the session's acks older than its newest window."""
DONE_ACK = "SELECT ack FROM done_acks WHERE session_id = ? AND stream_id = ? AND seq = ?"
OBJECTS_IN_STATE = (
    f"SELECT {OBJECT_COLUMNS} FROM objects WHERE session_id = ? AND state = ? ORDER BY object_id"
)
ONE_OBJECT = f"SELECT {OBJECT_COLUMNS} FROM objects WHERE session_id = ? AND object_id = ?"
PRESENT_CHANGE_SEQS = (
    "SELECT object_id, change_seq FROM objects WHERE session_id = ? AND state = 'present'"
    " ORDER BY object_id"
)
TOMBSTONES = "SELECT object_id, seq FROM tombstones WHERE session_id = ? ORDER BY object_id"
TRIM_TOMBSTONES = "DELETE FROM tombstones WHERE session_id = ? AND seq <= ?"
SET_FLOOR = "UPDATE sessions SET delta_floor = ? WHERE session_id = ?"


class SqlStore(Store):
    """The `Store` on an SQL database: every query, against `dialect`. A subclass gives the
    connection and its transactions; faults of the database are its to translate."""

    dialect: Dialect

    @abc.abstractmethod
    def _transaction(self, write: bool = True) -> AbstractContextManager[Connection]:
        """One transaction: committed when the block ends, rolled back if it raises. A read
        (`write=False`) sees one consistent snapshot."""

    @abc.abstractmethod
    def _write(self, body: Callable[[Connection], T]) -> T:
        """`body(conn)` in one write transaction; its result."""

    def _pipeline(self, conn: Connection) -> AbstractContextManager[Any]:
        """Statements run in the block may go out without waiting for each answer."""
        return contextlib.nullcontext()

    def _run(self, conn: Connection, statement: str, params: Any = ()) -> Any:
        """Run one statement (with `?` placeholders); its cursor."""
        return conn.execute(self.dialect.sql(statement), params)

    def _run_for_ids(
        self, conn: Connection, statement: str, before: tuple, ids: list[int], after: tuple = ()
    ) -> None:
        """Run `statement` (its `{in_ids}` or `{each_id}` the ids' place, between the
        parameters `before` and `after`) for `ids`: once with them all or once for each, as
        the dialect batches; not at all when there are none."""
        if not ids:
            return
        dialect = self.dialect
        statement = dialect.sql(statement.format(in_ids=dialect.in_ids, each_id=dialect.each_id))
        conn.executemany(statement, [(*before, value, *after) for value in dialect.ids(ids)])

    def _session_row(
        self, conn: Connection, session_id: str, columns: str, *, lock: bool = False
    ) -> tuple:
        """The given columns of the session's row (locked until the transaction ends if
        `lock`: the transaction goes on to change it); KeyError if there is no such
        session."""
        row = self._run(
            conn,
            f"SELECT {columns} FROM sessions WHERE session_id = ?"
            + (self.dialect.lock_row if lock else ""),
            (session_id,),
        ).fetchone()
        if row is None:
            raise KeyError(f"unknown session {session_id!r}")
        return row

    def _set_session(self, conn: Connection, session_id: str, assignments: dict[str, Any]) -> int:
        """Set the session's columns (names from the stores' fixed sets, never a caller's);
        how many rows changed (0: no such session)."""
        columns = ", ".join(f"{column} = ?" for column in assignments)
        return self._run(
            conn,
            f"UPDATE sessions SET {columns} WHERE session_id = ?",
            (*assignments.values(), session_id),
        ).rowcount

    # ------------------------------------------------------------------ sessions
    def create_session(self, rec: SessionRecord, max_sessions: int | None = None) -> None:
        """Persist a new session; ValueError if its id exists; StoredSessionsLimit when the
        store holds `max_sessions` (counted in the insert's transaction, creations queued)."""
        row = session_to_row(rec)

        def create(conn: Connection) -> int:
            # Every creation, limited or not, queues here: none lands between a count and
            # its insert (each sees every creation that went before).
            if self.dialect.lock_creations is not None:
                self._run(conn, self.dialect.lock_creations, (CREATE_LOCK,))
            if max_sessions is not None:
                check_room(self._run(conn, COUNT_SESSIONS).fetchone()[0], max_sessions)
            return self._run(conn, INSERT_SESSION, row).rowcount

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

        def update(conn: Connection) -> None:
            if epoch is not None or not assignments:
                (stored_epoch,) = self._session_row(
                    conn, session_id, "epoch", lock=epoch is not None
                )
                check_epoch(session_id, stored_epoch, epoch)
            if assignments and not self._set_session(conn, session_id, assignments):
                raise KeyError(f"unknown session {session_id!r}")

        self._write(update)

    def delete_session(self, session_id: str) -> None:
        """Remove the session with its objects, tombstones, changes and remembered acks
        (no-op if unknown)."""
        self._write(lambda conn: self._run(conn, DELETE_SESSION, (session_id,)))

    def list_sessions(self) -> list[SessionRecord]:
        """Every session, oldest first."""
        with self._transaction(write=False) as conn:
            rows = self._run(conn, LIST_SESSIONS).fetchall()
        return [session_from_row(row) for row in rows]

    def load_session(self, session_id: str) -> SessionRecord:
        """One session as last committed; KeyError if unknown."""
        with self._transaction(write=False) as conn:
            return session_from_row(self._session_row(conn, session_id, SESSION_COLUMNS))

    def count_sessions(self) -> int:
        """How many sessions are stored."""
        with self._transaction(write=False) as conn:
            return self._run(conn, COUNT_SESSIONS).fetchone()[0]

    def list_stored(self) -> list[StoredSession]:
        """Every session with its present object count and update seq, oldest first; objects
        are counted on the index by state, no map is read."""
        with self._transaction(write=False) as conn:
            rows = self._run(conn, LIST_STORED).fetchall()
        return [StoredSession(session_from_row(row[:-2]), row[-1], row[-2]) for row in rows]

    def idle_sessions(self, used_before: float) -> list[str]:
        """Ids of the sessions whose `last_used_at` is before `used_before` (unix time)."""
        with self._transaction(write=False) as conn:
            rows = self._run(conn, IDLE_SESSIONS, (float(used_before),)).fetchall()
        return [row[0] for row in rows]

    # ------------------------------------------------------------------ owners (map shards)
    def claim_session(
        self, session_id: str, owner: str, lease_s: float, now: float | None = None
    ) -> int:
        """`Store.claim_session`: the holder read under the session row's lock and the claim
        written in the same transaction (a concurrent claim waits, then sees this one)."""
        now = clock(now)
        lease_until = lease_end(lease_s, now)

        def claim(conn: Connection) -> int:
            held_by, held_until, stored_epoch = self._session_row(
                conn, session_id, "owner, lease_until, epoch", lock=True
            )
            epoch = claimed_epoch(session_id, held_by, held_until, stored_epoch, owner, now)
            self._run(conn, CLAIM_SESSION, (owner, epoch, lease_until, session_id))
            return epoch

        return self._write(claim)

    def renew_leases(
        self, owner: str, epochs: Mapping[str, int], lease_s: float, now: float | None = None
    ) -> list[str]:
        """`Store.renew_leases`, in one transaction: the ids `owner` no longer holds there."""
        lease_until = lease_end(lease_s, now)
        if not epochs:
            return []

        def renew(conn: Connection) -> list[str]:
            if self.dialect.batches_ids:  # one statement for them all
                ids, held = list(epochs), [int(epoch) for epoch in epochs.values()]
                rows = self._run(conn, RENEW_LEASES, (lease_until, ids, held, owner)).fetchall()
                return [row[0] for row in rows]
            return [
                sid
                for sid, epoch in epochs.items()
                if self._run(conn, RENEW_LEASE, (lease_until, sid, owner, int(epoch))).rowcount
            ]

        return not_renewed(epochs, self._write(renew))

    def release_session(self, session_id: str, owner: str, epoch: int) -> None:
        """No owner, no lease (the epoch kept) if `owner` holds the session at `epoch`."""
        self._write(lambda conn: self._run(conn, RELEASE_SESSION, (session_id, owner, int(epoch))))

    def heartbeat_shard(self, name: str, url: str, now: float | None = None) -> None:
        """Shard `name`, at `url`, is alive at `now` (time.time() when None)."""
        heartbeat_at = clock(now)
        self._write(lambda conn: self._run(conn, HEARTBEAT_SHARD, (name, url, heartbeat_at)))

    def live_shards(self, max_age_s: float, now: float | None = None) -> list[ShardRecord]:
        """The shards heard from at or after `now - max_age_s`, by name (code point order)."""
        oldest = clock(now) - float(max_age_s)
        with self._transaction(write=False) as conn:
            rows = self._run(conn, LIVE_SHARDS, (oldest,)).fetchall()
        return [shard_from_row(row) for row in rows]

    def forget_shard(self, name: str) -> None:
        """Shard `name` leaves the registry; its sessions are released (epochs kept)."""

        def forget(conn: Connection) -> None:
            self._run(conn, FORGET_SHARD, (name,))
            self._run(conn, RELEASE_OWNED, (name,))

        self._write(forget)

    # ------------------------------------------------------------------ the map
    def commit_keyframe(self, commit: KeyframeCommit) -> None:
        """`Store.commit_keyframe`, in one transaction under the session row's lock (the
        epoch checked under it): returns once the database has committed it."""
        keyframe = prepare_keyframe(commit)
        session_id = keyframe.session_id
        seq = keyframe.seq

        def write(conn: Connection) -> None:
            # The row lock orders this session's commits (and trims, claims, deletions) one
            # by one: no claim lands between the epoch's check and the commit.
            stored_seq, stored_next_id, stored_epoch = self._session_row(
                conn, session_id, "seq, next_object_id, epoch", lock=True
            )
            assignments = keyframe.check_follows(stored_seq, stored_next_id, stored_epoch)
            with self._pipeline(conn):
                self._set_session(conn, session_id, assignments)
                # Retired objects are rewritten below with state 'removed': only the others go.
                self._run_for_ids(conn, DELETE_OBJECTS, (session_id,), keyframe.deleted_ids)
                self._run_for_ids(conn, TOMBSTONE, (session_id,), keyframe.removed_ids, (seq,))
                kept_ids = [int(obj.id) for obj in keyframe.kept]
                self._run_for_ids(conn, FORGET_TOMBSTONES, (session_id,), kept_ids)
                # A generator: each object is encoded as it is written, so nothing is copied
                # twice, and a bad object aborts the transaction (rolling back the rows
                # before it).
                conn.executemany(
                    self.dialect.sql(UPSERT_OBJECT),
                    ((session_id, seq, *row) for row in keyframe.object_rows()),
                )
                # Before the inserts: a removal this commit takes back is an earlier one.
                revived = keyframe.revived_ids
                self._run_for_ids(conn, DELETE_CHANGES, (session_id,), revived, ("removed",))
                if keyframe.change_rows:
                    conn.executemany(
                        self.dialect.sql(INSERT_CHANGE),
                        [(session_id, *row) for row in keyframe.change_rows],
                    )
                # After the inserts: no `added` change stays for a retracted id, this one's too.
                retracted = keyframe.retracted_ids
                self._run_for_ids(conn, DELETE_CHANGES, (session_id,), retracted, ("added",))
                if keyframe.done is not None:
                    self._run(conn, REMEMBER_DONE, (session_id, *keyframe.done))
                    self._run(conn, FORGET_OLD_DONE, (session_id, session_id, DONE_WINDOW))

        self._write(write)

    def done_ack(self, session_id: str, stream_id: str, seq: int) -> bytes | None:
        """The ack remembered for frame `seq` of `stream_id`; None if none is."""
        with self._transaction(write=False) as conn:
            self._session_row(conn, session_id, "1")
            row = self._run(conn, DONE_ACK, (session_id, stream_id, int(seq))).fetchone()
        return None if row is None else bytes(row[0])

    def load_objects(self, session_id: str) -> list[MapObject]:
        """The session's present map: confirmed objects, state "present", in id order."""
        return self._load_in_state(session_id, "present")

    def load_removed_objects(self, session_id: str) -> list[MapObject]:
        """The session's removed objects kept as history, in id order."""
        return self._load_in_state(session_id, "removed")

    def _load_in_state(self, session_id: str, state: str) -> list[MapObject]:
        with self._transaction(write=False) as conn:
            self._session_row(conn, session_id, "1")
            rows = self._run(conn, OBJECTS_IN_STATE, (session_id, state)).fetchall()
        return [object_from_row(row) for row in rows]

    def load_object(self, session_id: str, object_id: int) -> MapObject | None:
        """One object, present or removed, as last committed; None if there is none."""
        with self._transaction(write=False) as conn:
            self._session_row(conn, session_id, "1")
            row = self._run(conn, ONE_OBJECT, (session_id, int(object_id))).fetchone()
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
            where.append(f"kind IN ({_marks(len(wanted.kinds))})" if wanted.kinds else "false")
            params.extend(wanted.kinds)
        query = f"SELECT {CHANGE_COLUMNS} FROM changes WHERE {' AND '.join(where)}"
        order = self.dialect.arrival_order
        with self._transaction(write=False) as conn:
            self._session_row(conn, session_id, "1")
            if wanted.limit is None:
                rows = self._run(conn, f"{query} ORDER BY {order}", params).fetchall()
            else:
                rows = self._run(
                    conn, f"{query} ORDER BY {order} DESC LIMIT ?", (*params, wanted.limit)
                ).fetchall()[::-1]
        return [change_from_row(row) for row in rows]

    def load_delta_log(self, session_id: str) -> DeltaLog:
        """The session's delta log: each present object's change seq, the tombstones (removed
        objects kept as history are tombstones too), seq and floor."""
        with self._transaction(write=False) as conn:
            seq, floor = self._session_row(conn, session_id, "seq, delta_floor")
            upserted = self._run(conn, PRESENT_CHANGE_SEQS, (session_id,)).fetchall()
            removed = self._run(conn, TOMBSTONES, (session_id,)).fetchall()
        return DeltaLog.from_state(
            {"seq": seq, "floor": floor, "upserted_at": dict(upserted), "removed_at": dict(removed)}
        )

    def trim_tombstones(self, session_id: str, floor: int, *, epoch: int | None = None) -> None:
        """Forget the removals at or before `floor`; raise the stored floor to it (removed
        objects kept as history stay). SessionFenced when `epoch` is given and stale."""
        floor = int(floor)

        def trim(conn: Connection) -> None:
            seq, stored_floor, stored_epoch = self._session_row(
                conn, session_id, "seq, delta_floor, epoch", lock=True
            )
            check_epoch(session_id, stored_epoch, epoch)
            if floor > seq:
                raise ValueError(
                    f"session {session_id!r}: floor {floor} is beyond the stored seq {seq}"
                )
            if floor <= stored_floor:
                return
            self._run(conn, TRIM_TOMBSTONES, (session_id, floor))
            self._run(conn, SET_FLOOR, (floor, session_id))

        self._write(trim)
