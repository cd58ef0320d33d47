"""The store interface: what the server needs from persistence, whatever keeps the bytes.

The contract every implementation keeps: `commit_keyframe` returns only once the keyframe's
changes are durable (the server acks after it), in one all-or-nothing step; after a restart
`load_objects` and `load_delta_log` give back exactly the confirmed map and delta log last
committed, so the update seq continues and a subscriber resuming with `since` loses nothing.

When the storage cannot take a write (disk full, I/O error, read-only), a write raises
`StoreUnavailableError` and changes nothing; `probe` tells when writes can land again.

The store is where sessions live: a server keeps only the maps in use in memory and loads
the others from here on first use, so listing, counting and finding idle sessions read the
sessions' rows only, never their maps.

Map shards (several server processes on one store) hold each session on one shard at a time.
A shard claims a session (`claim_session`): it becomes the owner, with a lease it renews
(`renew_leases`) while it keeps the session, and the session's epoch goes up by one. Each
write the owner makes names that epoch: once another shard has claimed the session (the
owner hung past its lease, or restarted), the old epoch is stale and its writes raise
`SessionFenced`, changing nothing. Shards say they are alive in the shard registry
(`heartbeat_shard`, `live_shards`). A keyframe's commit can also remember its ack under the
frame's (stream, seq) (`done_ack`), so a frame sent again after a reconnection is answered
with the same ack instead of being mapped twice.
"""

from __future__ import annotations

import abc
from collections.abc import Collection, Mapping
from dataclasses import KW_ONLY, dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # annotations only: settings check store URLs without loading the mapping
    import numpy as np

    from app.mapping.deltas import DeltaLog
    from app.mapping.object import Change, MapObject

COUNTER_NAMES: tuple[str, ...] = ("frames", "keyframes", "bytes_in", "bytes_out", "sightings")
"""Per-session counters a store keeps (absolute values, set by the server)."""
CHANGE_KINDS: tuple[str, ...] = ("added", "moved", "removed")
"""The kinds of `Change` a store keeps."""
DONE_WINDOW = 256
"""Per session, how many (stream, seq) acks a store remembers (`Store.done_ack`): the newest,
by the order they were committed."""


class StoreError(RuntimeError):
    """The store cannot be used: not a SemanticXR store, closed, corrupt, or a bad URL."""


class StoreVersionError(StoreError):
    """The store was written by a newer SemanticXR (unknown schema version)."""


class StoreUnavailableError(StoreError):
    """The storage cannot take a write now (disk full, I/O error, read-only); the write
    changed nothing. Transient: retry later (`Store.probe` says when)."""


class SessionFenced(StoreError):
    """The session was claimed by another owner: this owner's epoch is stale. The write
    changed nothing; the session is no longer this owner's to write."""

    def __init__(self, session_id: str, epoch: int | None = None, stored_epoch: int | None = None):
        stale = "" if epoch is None else f" {epoch}"
        now = "" if stored_epoch is None else f" (the session is at epoch {stored_epoch})"
        super().__init__(
            f"session {session_id!r} was claimed by another owner: this owner's epoch{stale} "
            f"is stale{now}"
        )
        self.session_id = session_id
        self.epoch = epoch
        """The stale epoch the write named."""
        self.stored_epoch = stored_epoch
        """The session's epoch in the store."""


class SessionHeld(StoreError):
    """A claim refused: a live owner holds the session (its lease has not run out)."""

    def __init__(self, session_id: str, owner: str, lease_until: float | None):
        super().__init__(f"session {session_id!r} is held by {owner!r} (lease until {lease_until})")
        self.session_id = session_id
        self.owner = owner
        """The owner holding the session (a shard's name)."""
        self.lease_until = lease_until
        """Unix time (seconds) the owner's lease ends, unless renewed."""


class StoredSessionsLimit(StoreError):
    """A session not created: the store already holds `limit` sessions (max_sessions)."""

    def __init__(self, limit: int):
        super().__init__(f"the store holds its maximum of {limit} sessions")
        self.limit = limit


@dataclass
class SessionRecord:
    """One session as persisted. Counters are absolute values, not increments."""

    session_id: str
    name: str
    mode: str
    knobs: dict
    """Knob name -> value (JSON-serialisable)."""
    token_hash: str
    created_at: float
    """Unix time, seconds."""
    frames: int = 0
    keyframes: int = 0
    bytes_in: int = 0
    bytes_out: int = 0
    sightings: int = 0
    """Frames that arrived as sightings (a non-keyframe's detections) rather than whole."""
    next_object_id: int = 1
    """Id the session's next new object gets (ids are never reused, even after a restart)."""
    perception: str = "detections"
    """Name of the session's perception backend (app.perception.BACKENDS)."""
    last_used_at: float | None = None
    """Unix time (seconds) of the session's last frame or use: what retention measures
    idleness by. None (when made) means `created_at`."""
    last_t: float | None = None
    """Device-clock time (frame `t`, seconds) of the session's last committed keyframe;
    None before its first (or in a store from before it was kept)."""
    last_pose: list[float] | None = None
    """That keyframe's camera-to-world pose: 16 floats (float32 values), row-major 4x4."""
    owner: str | None = None
    """The shard that holds the session (`Store.claim_session`); None when none does."""
    epoch: int = 0
    """Bumped at every claim; an owner's writes name the epoch its claim returned."""
    lease_until: float | None = None
    """Unix time (seconds) the owner's lease ends unless renewed; None without an owner."""
    up: str | None = None
    """The world axis that is up ("+x", "-x", "+y", "-y", "+z" or "-z"), set at creation or
    inferred from the poses; None while neither (the default, +z, applies)."""
    up_source: str | None = None
    """With `up`: "set" (at creation) or "inferred" (from the poses); None without."""
    text_tower: str = "minilm"
    """The session's text tower: "minilm" (sessions from before it too) or "static"."""
    tower_sha256: str | None = None
    """With a "static" tower: the SHA-256 (64 lowercase hex digits) of the tower file the
    session was created with, which it must be loaded with; None for "minilm"."""

    def __post_init__(self) -> None:
        if self.last_used_at is None:
            self.last_used_at = self.created_at


@dataclass
class StoredSession:
    """One entry of `Store.list_stored`: a session's row and the size of its map."""

    record: SessionRecord
    objects: int
    """Confirmed objects stored in the present map (removed ones kept as history not
    counted)."""
    seq: int
    """The delta log's seq (the session's update seq)."""


@dataclass(frozen=True)
class ShardRecord:
    """One map shard in the shard registry (`Store.heartbeat_shard`)."""

    name: str
    url: str
    """Where gateways reach the shard."""
    heartbeat_at: float
    """Unix time (seconds) of the shard's last heartbeat."""


@dataclass
class KeyframeCommit:
    """One keyframe's changes, persisted at once by `Store.commit_keyframe`.

    A keyframe that changed nothing gives the unchanged seq and empty lists (to persist the
    counters). An id both upserted and removed ends up removed, as in `DeltaLog.commit`.
    """

    session_id: str
    seq: int
    """The delta log's seq after the commit: the objects' and changes' seq."""
    upserts: list[MapObject]
    """Confirmed objects changed at `seq`, stored with their current fields, state
    "present"."""
    removed: list[int]
    """Ids removed from the present map at `seq`: tombstoned, and their rows deleted unless
    retired."""
    counters: dict[str, int]
    """Absolute values, named as in COUNTER_NAMES."""
    next_object_id: int
    last_used_at: float | None = None
    """The session's new `last_used_at` (unix time, seconds), if given."""
    _: KW_ONLY
    retired: Collection[MapObject] = ()
    """Removed objects kept as history (each id also in `removed`, each object confirmed
    with state "removed"): their rows are kept with their final fields and leave every read
    of the present map."""
    changes: Collection[Change] = ()
    """The keyframe's changes, stored with seq = `seq` (their own seq ignored), after every
    earlier one (arrival order)."""
    retracted_added: Collection[int] = ()
    """Object ids whose `added` changes are deleted (a published object merged into another:
    no `added` change stays for it)."""
    retracted_removed: Collection[int] = ()
    """Object ids whose earlier `removed` changes are deleted (a removed object found at a
    new place: the move replaces its removal)."""
    last_t: float | None = None
    """The keyframe's frame `t` (device clock, seconds), kept on the session row when
    given."""
    last_pose: np.ndarray | None = None
    """The keyframe's camera-to-world pose (float [4, 4] or [16], row-major), kept on the
    session row when given."""
    epoch: int | None = None
    """When given, the commit applies only while the session is at that epoch."""
    done: tuple[str, int, bytes] | None = None
    """(stream_id, seq, ack): the ack of the frame committed, remembered under its
    (stream_id, seq) in the same transaction (`Store.done_ack`; replacing an earlier one
    under that key); the session keeps the newest DONE_WINDOW."""
    inferred_up: str | None = None
    """The up axis the session's poses settled ("+y", ...), kept on the session row with
    up_source "inferred" (the server gives it once, and only to a session whose up is not
    set)."""


class Store(abc.ABC):
    """Sessions and their confirmed maps. Implementations are thread-safe.

    Unknown session ids raise KeyError, except in `delete_session` (idempotent),
    `create_session` (ValueError on a duplicate), `release_session` and `renew_leases` (no
    error). Every call raises StoreUnavailableError (having changed nothing) when the storage
    cannot be used now.

    A write given an `epoch` (the one `claim_session` returned to its owner) applies only
    while the session is still at that epoch; otherwise it raises SessionFenced and changes
    nothing (checked in the write's own transaction). Without one it applies regardless (a
    server that is not a map shard).
    """

    # ------------------------------------------------------------------ sessions
    @abc.abstractmethod
    def create_session(self, rec: SessionRecord, max_sessions: int | None = None) -> None:
        """Persist a new session; ValueError if its id exists. With `max_sessions`, the count
        and the insert are one transaction (two creations at once never both take the last
        place): StoredSessionsLimit, nothing written, when the store holds that many."""

    @abc.abstractmethod
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

    @abc.abstractmethod
    def delete_session(self, session_id: str) -> None:
        """Remove the session with its objects, tombstones, changes and remembered acks
        (no-op if unknown)."""

    @abc.abstractmethod
    def list_sessions(self) -> list[SessionRecord]:
        """Every session, oldest first."""

    def load_session(self, session_id: str) -> SessionRecord:
        """One session as last committed; KeyError if unknown."""
        for rec in self.list_sessions():
            if rec.session_id == session_id:
                return rec
        raise KeyError(f"unknown session {session_id!r}")

    def count_sessions(self) -> int:
        """How many sessions are stored."""
        return len(self.list_sessions())

    def list_stored(self) -> list[StoredSession]:
        """Every session with its object count and update seq, oldest first (no map loaded,
        where the implementation can count without one)."""
        return [
            StoredSession(
                rec,
                len(self.load_objects(rec.session_id)),
                self.load_delta_log(rec.session_id).seq,
            )
            for rec in self.list_sessions()
        ]

    def idle_sessions(self, used_before: float) -> list[str]:
        """Ids of the sessions whose `last_used_at` is before `used_before` (unix time)."""
        return [
            rec.session_id
            for rec in self.list_sessions()
            if rec.last_used_at is not None and rec.last_used_at < used_before
        ]

    # ------------------------------------------------------------------ owners (map shards)
    @abc.abstractmethod
    def claim_session(
        self, session_id: str, owner: str, lease_s: float, now: float | None = None
    ) -> int:
        """Make `owner` the session's owner until `now + lease_s` and return the session's new
        epoch (one more than before: the previous holder's writes are fenced from now on, a
        re-claim by the same owner included, which fences its previous incarnation).

        Atomic. Allowed when the session has no owner, `owner` holds it, or the holder's lease
        ended before `now`; otherwise SessionHeld (naming the holder), nothing changed.
        now: unix time, seconds (time.time() when None); ValueError on a lease_s that is not
        a finite number > 0."""

    @abc.abstractmethod
    def renew_leases(
        self, owner: str, epochs: Mapping[str, int], lease_s: float, now: float | None = None
    ) -> list[str]:
        """Extend to `now + lease_s` the lease of each session `owner` still holds at the epoch
        given (`epochs`: session id -> epoch), in one transaction; the ids (of `epochs`, in its
        order) it no longer holds there (claimed by another, or deleted): drop them."""

    @abc.abstractmethod
    def release_session(self, session_id: str, owner: str, epoch: int) -> None:
        """Let the session go (no owner, no lease; the epoch kept) if `owner` holds it at
        `epoch`, so another can claim it at once; otherwise nothing (no error, an unknown
        session included)."""

    @abc.abstractmethod
    def heartbeat_shard(self, name: str, url: str, now: float | None = None) -> None:
        """Record that shard `name`, reached at `url`, is alive at `now` (time.time() when
        None): its row in the shard registry, made or replaced."""

    @abc.abstractmethod
    def live_shards(self, max_age_s: float, now: float | None = None) -> list[ShardRecord]:
        """The shards whose last heartbeat is at or after `now - max_age_s`, by name."""

    @abc.abstractmethod
    def forget_shard(self, name: str) -> None:
        """Remove shard `name` from the registry and let go of every session it owns (no
        owner, no lease; epochs kept), so other shards can claim them at once."""

    # ------------------------------------------------------------------ the map
    @abc.abstractmethod
    def commit_keyframe(self, commit: KeyframeCommit) -> None:
        """Persist one keyframe's changes (`commit`) at once; returns once they survive a
        crash.

        Raises ValueError (and changes nothing) on a seq older than the stored one, changes
        to objects or change entries without a newer seq, an unconfirmed object, an upsert
        that is not present or a retired object that is not removed or not in `removed`, an
        id not below `next_object_id`, more than MAX_STAYS stays, a time that is not finite,
        a change of an unknown kind, arrays that are not float32 points [N, 3] /
        embedding [d] / per-label sums [d] of the object's labels / a pose of 16 values, a
        `done` that is not (str, int, bytes), or an `inferred_up` that names no axis;
        KeyError on an unknown session; SessionFenced on a stale epoch;
        StoreUnavailableError (and changes nothing) when the storage cannot take it.
        """

    @abc.abstractmethod
    def done_ack(self, session_id: str, stream_id: str, seq: int) -> bytes | None:
        """The ack a commit remembered for frame `seq` of stream `stream_id` (its `done`);
        None if none is remembered (never committed, or older than the newest DONE_WINDOW)."""

    @abc.abstractmethod
    def load_objects(self, session_id: str) -> list[MapObject]:
        """The session's present map: its confirmed objects with state "present" in id
        order, exactly as last committed."""

    @abc.abstractmethod
    def load_removed_objects(self, session_id: str) -> list[MapObject]:
        """The session's removed objects (state "removed", kept as history with their stays
        and last points) in id order, exactly as last committed."""

    @abc.abstractmethod
    def load_object(self, session_id: str, object_id: int) -> MapObject | None:
        """One object of the session, present or removed, as last committed; None if the
        session has no such object (never had it, or it was deleted: merged, pruned)."""

    @abc.abstractmethod
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
        """The session's changes in arrival order (the order they were committed, which is
        the time order unless the device clock went backwards), each with its commit's seq.

        since_t, until_t: keep changes with since_t <= t <= until_t (device clock, seconds)
        since_seq:        keep changes committed after that update seq (seq > since_seq)
        kinds:            keep these kinds only ("added", "moved", "removed")
        limit:            keep the newest `limit` of the rest (still returned oldest first)
        ValueError on an unknown kind, a NaN bound or a negative limit.
        """

    @abc.abstractmethod
    def load_delta_log(self, session_id: str) -> DeltaLog:
        """The session's delta log: each present object's change seq, the tombstones (of
        deleted and of removed objects alike), seq and floor."""

    @abc.abstractmethod
    def trim_tombstones(self, session_id: str, floor: int, *, epoch: int | None = None) -> None:
        """Forget the removals at or before seq `floor` and raise the stored floor to it.

        Mirrors `DeltaLog.floor`: a subscriber resuming from before the floor gets a full
        snapshot, so those tombstones can no longer reach anyone. Removed objects kept as
        history stay. A floor at or below the stored one changes nothing; ValueError on a
        floor beyond the stored seq; SessionFenced (nothing changed) when `epoch` is given
        and stale.
        """

    # ------------------------------------------------------------------ health
    @abc.abstractmethod
    def probe(self) -> None:
        """Return once the storage can take a write now; StoreUnavailableError if it cannot.

        Cheap enough to call about once a second while writes fail (to notice the disk has
        room again without waiting for a keyframe); may use the call to make room (e.g.
        fold a write-ahead log into the database). Changes nothing a reader can see."""

    # ------------------------------------------------------------------ lifecycle
    @abc.abstractmethod
    def close(self) -> None:
        """Release the store (idempotent); nothing committed depends on it being called."""

    def __enter__(self) -> Store:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
