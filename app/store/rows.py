"""The rows every store writes: sessions, objects and changes as column values, one encoding.

Pure functions, no I/O: the store's queries (`sql.py`) put these values in its tables, so
every database keeps the same bytes and refuses the same inputs. Arrays are raw
little-endian float32 bytes whose shape the row records (never pickle): points [n_points, 3],
embedding_sum [embedding_dim], label_embeddings [labels, embedding_dim] (one row per label of
label_counts, in its order), a session's last pose [16]; stays are `stays_to_bytes` records.
Knobs and label counts are JSON text (key order kept: label ties resolve the same after a
reload).

`prepare_keyframe` checks and encodes one `KeyframeCommit` before its transaction opens;
`PreparedKeyframe.check_follows` is the part that needs the stored row.

A session's up axis (schema 6) is its name, "+x" ... "-z" (`UP_AXES`), and where it came
from, "set" or "inferred" (`UP_SOURCES`); both NULL while the default applies.

Owners and the shard registry (schema 5): the decisions around their statements
(`claimed_epoch`, `check_epoch`) are here, the statements in `sql.py`.
"""

from __future__ import annotations

import json
import math
import time
from collections import Counter
from collections.abc import Collection, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from app.mapping.object import (
    MAX_STAYS,
    OBJECT_STATES,
    Change,
    MapObject,
    stays_from_bytes,
    stays_to_bytes,
)
from app.protocol.rest import UP_AXES
from app.store.base import (
    CHANGE_KINDS,
    COUNTER_NAMES,
    KeyframeCommit,
    SessionFenced,
    SessionHeld,
    SessionRecord,
    ShardRecord,
    StoredSessionsLimit,
    StoreError,
)

FLOAT32_LE = np.dtype("<f4")
UP_SOURCES = ("set", "inferred")
"""Where a stored `up` came from (the default, +z, is stored as no up at all)."""

SESSION_COLUMNS = (
    "session_id, name, mode, perception, knobs, token_hash, created_at, "
    "frames, keyframes, bytes_in, bytes_out, next_object_id, last_used_at, last_t, last_pose, "
    "sightings, owner, epoch, lease_until, up, up_source, text_tower, tower_sha256"
)
"""The columns of `session_to_row` / `session_from_row`, in order."""
N_SESSION_COLUMNS = len(SESSION_COLUMNS.split(","))
OBJECT_COLUMNS = (
    "object_id, version, n_obs, frames_seen, first_seen, last_seen, resolution_m, "
    "label_counts, n_points, points, embedding_dim, embedding_sum, "
    "state, first_seen_t, last_seen_t, stays, label_embeddings"
)
"""The columns of `object_to_row` / `object_from_row`, in order."""
N_OBJECT_COLUMNS = len(OBJECT_COLUMNS.split(","))
CHANGE_COLUMNS = "object_id, kind, t, label, from_x, from_y, from_z, to_x, to_y, to_z, seq"
"""The columns of `change_to_row` / `change_from_row`, in order."""


# ---------------------------------------------------------------------- one keyframe
@dataclass
class PreparedKeyframe:
    """One `KeyframeCommit`, checked and encoded as far as it can be without the stored
    session row (`prepare_keyframe`)."""

    session_id: str
    seq: int
    next_object_id: int
    kept: list[MapObject]
    """Upserts whose id is not also removed: written with state "present"."""
    retired: list[MapObject]
    """Removed objects kept as history: rewritten with state "removed"."""
    removed_ids: list[int]
    """Every removed id, sorted: tombstoned at `seq`."""
    deleted_ids: list[int]
    """Removed ids whose rows go (those not retired)."""
    change_rows: list[tuple]
    """`change_to_row` of each change, at `seq`, in arrival order."""
    retracted_ids: list[int]
    """Ids whose `added` changes go (after this commit's changes are written)."""
    revived_ids: list[int]
    """Ids whose earlier `removed` changes go (before this commit's changes are written)."""
    assignments: dict[str, Any]
    """Session columns to set: counters, last use, last t and pose, an inferred up."""
    epoch: int | None
    """The epoch the commit applies at (None: at any)."""
    done: tuple[str, int, bytes] | None
    """(stream_id, seq, ack) to remember, or None."""

    def check_follows(
        self, stored_seq: int, stored_next_id: int, stored_epoch: int
    ) -> dict[str, Any]:
        """The session columns to set, seq and next_object_id included; SessionFenced when
        the commit names an epoch the session is no longer at; ValueError when the commit
        does not follow the stored row (an older seq, changes without a newer seq, an id
        that is not below next_object_id or a next_object_id going back)."""
        check_epoch(self.session_id, stored_epoch, self.epoch)
        seq, next_object_id = self.seq, self.next_object_id
        # Resuming subscribers rely on "changed after S" meaning "seq > S": a change
        # stored at a seq they may already have seen would never reach them (and
        # neither would a change entry read with since_seq).
        changes_something = self.kept or self.removed_ids or self.change_rows
        if seq < stored_seq or (changes_something and seq == stored_seq):
            raise ValueError(
                f"session {self.session_id!r}: seq {seq} does not follow the stored seq "
                f"{stored_seq}"
            )
        touched_ids = (
            [int(obj.id) for obj in self.kept]
            + self.removed_ids
            + [row[0] for row in self.change_rows]
        )
        if next_object_id < stored_next_id or any(i >= next_object_id for i in touched_ids):
            raise ValueError(
                f"session {self.session_id!r}: next_object_id {next_object_id} would reuse an id"
            )
        return {**self.assignments, "seq": seq, "next_object_id": int(next_object_id)}

    def object_rows(self) -> Iterator[tuple]:
        """`object_to_row` of the kept objects, then of the retired ones; a generator, so
        each object is encoded as it is written and a bad one stops the writing there."""
        return (object_to_row(obj) for obj in [*self.kept, *self.retired])


def prepare_keyframe(commit: KeyframeCommit) -> PreparedKeyframe:
    """`commit` checked and encoded; ValueError as `Store.commit_keyframe` documents, except
    the checks against the stored row (`PreparedKeyframe.check_follows`) and the objects'
    own (`object_to_row`, as they are written)."""
    session_id, seq, last_pose = commit.session_id, commit.seq, commit.last_pose
    removed_ids = sorted({int(oid) for oid in commit.removed})
    gone = set(removed_ids)
    kept = [obj for obj in commit.upserts if int(obj.id) not in gone]
    retired = list(commit.retired)
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
    seq = int(seq)
    change_rows = [change_to_row(change, seq) for change in commit.changes]
    assignments: dict[str, Any] = checked_counters(commit.counters)
    if commit.last_used_at is not None:
        assignments["last_used_at"] = float(commit.last_used_at)
    if commit.last_t is not None:
        assignments["last_t"] = checked_time("last_t", commit.last_t)
    if last_pose is not None:
        assignments["last_pose"] = pose_to_blob(last_pose)
    if commit.inferred_up is not None:
        assignments["up"], assignments["up_source"] = checked_up(commit.inferred_up, "inferred")
    return PreparedKeyframe(
        session_id=session_id,
        seq=seq,
        next_object_id=commit.next_object_id,
        kept=kept,
        retired=retired,
        removed_ids=removed_ids,
        deleted_ids=[oid for oid in removed_ids if oid not in kept_as_history],
        change_rows=change_rows,
        retracted_ids=sorted({int(oid) for oid in commit.retracted_added}),
        revived_ids=sorted({int(oid) for oid in commit.retracted_removed}),
        assignments=assignments,
        epoch=None if commit.epoch is None else int(commit.epoch),
        done=checked_done(commit.done),
    )


def checked_done(done: tuple[str, int, bytes] | None) -> tuple[str, int, bytes] | None:
    """A commit's `done` as (str, int, bytes); ValueError when it is not one."""
    if done is None:
        return None
    try:
        stream_id, seq, ack = done
    except (TypeError, ValueError):
        raise ValueError(f"done must be (stream_id, seq, ack), got {done!r}") from None
    if not isinstance(stream_id, str) or not isinstance(ack, bytes | bytearray | memoryview):
        raise ValueError(
            f"done must be (str stream_id, int seq, bytes ack), got ({type(stream_id).__name__},"
            f" {type(seq).__name__}, {type(ack).__name__})"
        )
    return stream_id, int(seq), bytes(ack)


# ---------------------------------------------------------------------- owners and shards
def check_epoch(session_id: str, stored_epoch: int, epoch: int | None) -> None:
    """SessionFenced when a write names an epoch (`epoch` not None) the session is no longer
    at (`stored_epoch`, read in the write's transaction)."""
    if epoch is not None and int(epoch) != stored_epoch:
        raise SessionFenced(session_id, int(epoch), stored_epoch)


def claimed_epoch(
    session_id: str,
    held_by: str | None,
    lease_until: float | None,
    stored_epoch: int,
    owner: str,
    now: float,
) -> int:
    """The epoch a claim by `owner` at `now` gives a session held by `held_by` until
    `lease_until` (read under the claim's lock) at `stored_epoch`: one more. SessionHeld when
    another owner's lease is still running (an owner without a lease holds nothing)."""
    if held_by is not None and held_by != owner and lease_until is not None and lease_until >= now:
        raise SessionHeld(session_id, held_by, lease_until)
    return stored_epoch + 1


def lease_end(lease_s: float, now: float | None) -> float:
    """`now + lease_s` (now: time.time() when None); ValueError on a lease that is not a
    finite number of seconds > 0 or a time that is not finite."""
    lease_s = float(lease_s)
    if not (math.isfinite(lease_s) and lease_s > 0):
        raise ValueError(f"lease_s must be a finite number of seconds > 0, got {lease_s}")
    return clock(now) + lease_s


def clock(now: float | None) -> float:
    """`now` as a float, time.time() when None; ValueError when it is not finite."""
    return time.time() if now is None else checked_time("now", now)


def not_renewed(epochs: Mapping[str, int], renewed: Collection[str]) -> list[str]:
    """The ids of `epochs`, in its order, whose lease was not renewed."""
    renewed = set(renewed)
    return [sid for sid in epochs if sid not in renewed]


def check_room(stored: int, max_sessions: int | None) -> None:
    """StoredSessionsLimit when `stored` sessions leave no room under `max_sessions`."""
    if max_sessions is not None and stored >= max_sessions:
        raise StoredSessionsLimit(int(max_sessions))


def shard_from_row(row: tuple) -> ShardRecord:
    name, url, heartbeat_at = row
    return ShardRecord(name=name, url=url, heartbeat_at=heartbeat_at)


# ---------------------------------------------------------------------- reading changes
@dataclass(frozen=True)
class ChangeFilter:
    """`Store.load_changes`'s filter, checked (`change_filter`)."""

    since_t: float | None
    until_t: float | None
    since_seq: int | None
    kinds: list[str] | None
    """Sorted, distinct, known kinds."""
    limit: int | None


def change_filter(
    since_t: float | None,
    until_t: float | None,
    since_seq: int | None,
    kinds: Collection[str] | None,
    limit: int | None,
) -> ChangeFilter:
    """The filter of `Store.load_changes`; ValueError on an unknown kind, a NaN bound or a
    negative limit."""
    for name, bound in (("since_t", since_t), ("until_t", until_t)):
        if bound is not None and math.isnan(bound):
            raise ValueError(f"{name} must be a number, not NaN")
    if kinds is not None:
        kinds = sorted(set(kinds))
        unknown = [kind for kind in kinds if kind not in CHANGE_KINDS]
        if unknown:
            raise ValueError(f"unknown change kinds {unknown}; kinds: {', '.join(CHANGE_KINDS)}")
    if limit is not None and int(limit) < 0:
        raise ValueError(f"limit must be >= 0, got {limit}")
    return ChangeFilter(
        since_t=None if since_t is None else float(since_t),
        until_t=None if until_t is None else float(until_t),
        since_seq=None if since_seq is None else int(since_seq),
        kinds=kinds,
        limit=None if limit is None else int(limit),
    )


# ---------------------------------------------------------------------- rows <-> objects
def session_to_row(rec: SessionRecord) -> tuple:
    """The columns of SESSION_COLUMNS for a new session; ValueError on a last_t that is not
    finite, a pose that is not 16 finite values or an up that is not an axis set or
    inferred."""
    up, up_source = (None, None) if rec.up is None else checked_up(rec.up, rec.up_source)
    return (
        rec.session_id,
        rec.name,
        rec.mode,
        rec.perception,
        to_json(rec.knobs),
        rec.token_hash,
        float(rec.created_at),
        int(rec.frames),
        int(rec.keyframes),
        int(rec.bytes_in),
        int(rec.bytes_out),
        int(rec.next_object_id),
        float(rec.last_used_at if rec.last_used_at is not None else rec.created_at),
        checked_time("last_t", rec.last_t),
        None if rec.last_pose is None else pose_to_blob(rec.last_pose),
        int(rec.sightings),
        rec.owner,
        int(rec.epoch),
        checked_time("lease_until", rec.lease_until),
        up,
        up_source,
        *checked_tower(rec.text_tower, rec.tower_sha256),
    )


TEXT_TOWERS = ("minilm", "static")
"""A session's text towers (app.protocol.rest.TEXT_TOWERS)."""


def checked_tower(text_tower: str, sha256: str | None) -> tuple[str, str | None]:
    """(text_tower, sha256) when the tower is one of TEXT_TOWERS and a static one names its
    file's SHA-256 (64 lowercase hex digits; none for minilm); ValueError otherwise."""
    if text_tower not in TEXT_TOWERS:
        raise ValueError(f"text_tower must be one of {', '.join(TEXT_TOWERS)}; got {text_tower!r}")
    if text_tower == "static":
        if not isinstance(sha256, str) or not is_sha256(sha256):
            raise ValueError(
                f"a static text tower needs its file's sha256 (64 lowercase hex digits); "
                f"got {sha256!r}"
            )
    elif sha256 is not None:
        raise ValueError(f"tower_sha256 is only for a static text tower, not {text_tower!r}")
    return text_tower, sha256


def is_sha256(text: str) -> bool:
    """Whether `text` is a SHA-256 as the store keeps it: 64 lowercase hex digits."""
    return len(text) == 64 and all(c in "0123456789abcdef" for c in text)


def checked_up(up: str, source: str | None) -> tuple[str, str]:
    """(up, source) when `up` names an axis (UP_AXES) and `source` is one of UP_SOURCES;
    ValueError otherwise."""
    if up not in UP_AXES:
        raise ValueError(f"up must be one of {', '.join(UP_AXES)}; got {up!r}")
    if source not in UP_SOURCES:
        raise ValueError(f"up_source must be one of {', '.join(UP_SOURCES)}; got {source!r}")
    return up, source


def to_json(value: Any) -> str:
    # allow_nan=False: what is stored stays valid JSON for any reader.
    return json.dumps(value, allow_nan=False)


def checked_counters(counters: dict[str, int]) -> dict[str, int]:
    unknown = set(counters) - set(COUNTER_NAMES)
    if unknown:
        raise ValueError(
            f"unknown counters {sorted(unknown)}; known counters: {', '.join(COUNTER_NAMES)}"
        )
    return {name: int(value) for name, value in counters.items()}


def checked_time(name: str, t: float | None) -> float | None:
    """`t` as a float (None stays None); ValueError naming it when it is not finite."""
    if t is None:
        return None
    t = float(t)
    if not math.isfinite(t):
        raise ValueError(f"{name} must be a finite time in seconds, got {t}")
    return t


def pose_to_blob(pose: Any) -> bytes:
    """A camera-to-world pose ([4, 4] or [16], row-major) as 16 float32 little-endian."""
    values = np.ascontiguousarray(pose, dtype=FLOAT32_LE).reshape(-1)
    if values.size != 16 or not np.isfinite(values).all():
        raise ValueError(f"last_pose must be 16 finite values (4x4), got {np.shape(pose)}")
    return values.tobytes()


def session_from_row(row: tuple) -> SessionRecord:
    sid, name, mode, perception, knobs, token_hash, created_at, *counters = row
    frames, keyframes, bytes_in, bytes_out, next_object_id, last_used_at, last_t, pose, *rest = (
        counters
    )
    sightings, owner, epoch, lease_until, up, up_source, text_tower, tower_sha256 = rest
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
        last_pose=None if pose is None else float32_from_blob(pose, (16,)).tolist(),
        sightings=sightings,
        owner=owner,
        epoch=epoch,
        lease_until=lease_until,
        up=up,
        up_source=up_source,
        text_tower=text_tower,
        tower_sha256=tower_sha256,
    )


def object_to_row(obj: MapObject) -> tuple:
    """The columns of OBJECT_COLUMNS for one object; ValueError on badly shaped arrays,
    an unknown state, more than MAX_STAYS stays or a time that is not finite."""
    points = np.ascontiguousarray(obj.points, dtype=FLOAT32_LE)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"object {obj.id}: points must be [N, 3], got shape {points.shape}")
    if not obj.confirmed:
        raise ValueError(f"object {obj.id}: only confirmed objects are persisted")
    embedding_dim: int | None = None
    embedding_bytes: bytes | None = None
    if obj.embedding_sum is not None:
        embedding = np.ascontiguousarray(obj.embedding_sum, dtype=FLOAT32_LE)
        if embedding.ndim != 1:
            raise ValueError(f"object {obj.id}: embedding_sum must be [d], got {embedding.shape}")
        embedding_dim, embedding_bytes = len(embedding), embedding.tobytes()
    # Counter keeps insertion order and JSON objects keep theirs: label ties (first seen
    # wins) resolve the same way after a reload.
    labels = to_json({str(label): int(count) for label, count in obj.label_counts.items()})
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
        checked_time(f"object {obj.id}: first_seen_t", obj.first_seen_t),
        checked_time(f"object {obj.id}: last_seen_t", obj.last_seen_t),
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
    rows = np.full((len(obj.label_counts), embedding_dim), np.nan, FLOAT32_LE)
    for i, label in enumerate(obj.label_counts):
        vector = obj.label_embeddings.get(label)
        if vector is None:
            continue
        vector = np.asarray(vector, dtype=FLOAT32_LE)
        if vector.shape != (embedding_dim,):
            raise ValueError(
                f"object {obj.id}: the embedding sum of {label!r} must be [{embedding_dim}], "
                f"got {vector.shape}"
            )
        rows[i] = vector
    return rows.tobytes()


def float32_from_blob(blob: bytes, shape: tuple[int, ...]) -> np.ndarray:
    """A writable native float32 array of `shape` from little-endian bytes."""
    array = np.frombuffer(blob, dtype=FLOAT32_LE)
    if array.size != int(np.prod(shape)):
        raise StoreError(f"stored array has {array.size} values, expected shape {shape}")
    return array.astype(np.float32).reshape(shape)  # astype copies: frombuffer is read-only


def object_from_row(row: tuple) -> MapObject:
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
            None if embedding_sum is None else float32_from_blob(embedding_sum, (embedding_dim,))
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
    obj.set_points(float32_from_blob(points, (n_points, 3)), resolution_m)
    return obj


def _label_embeddings_from_blob(
    blob: bytes | None, label_counts: Counter, embedding_dim: int | None
) -> dict[str, np.ndarray]:
    if blob is None:
        return {}
    rows = float32_from_blob(blob, (len(label_counts), embedding_dim or 0))
    return {
        label: row for label, row in zip(label_counts, rows, strict=True) if not np.isnan(row).all()
    }


def change_to_row(change: Change, seq: int) -> tuple:
    """The columns of CHANGE_COLUMNS for one change at `seq`; ValueError on an unknown kind,
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
    t = checked_time(f"change of object {change.id}: t", change.t)
    return (int(change.id), change.kind, t, str(change.label), *places, seq)


def change_from_row(row: tuple) -> Change:
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
