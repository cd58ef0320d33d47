"""Sessions: one mapping engine each, the keyframe pipeline, update fan-out, persistence.

Threading model: the event loop only moves bytes. Frames are unpacked, decoded and
validated in a small decode pool; keyframes are mapped in the mapping pool, which sessions
share round-robin (`RoundRobinScheduler`: no session waits behind more than one keyframe of
each other session). Each session maps one keyframe at a time (`_map_lock`), and readers of
the map (queries, object lists, delta building) take the same lock, so they see whole
keyframes. If keyframes arrive faster than a session maps them, only the newest waits: an
older waiting keyframe is acknowledged as dropped (frames are samples, not a log).

Commit, then publish: a keyframe's changes are visible only once the store has them. The
keyframe maps and commits inside one hold of `_map_lock`; if the commit (or the mapping)
fails, the engine is put back to the store's durable state before the lock is released, so
no reader ever sees a change the store lacks and no seq is reused for other contents.
While the store refuses writes (disk full, I/O error) keyframes get `storage_unavailable`
without being mapped, queries keep answering from the durable map, and the store is probed
about once a second until it takes writes again (`StorageHealth`, `/healthz`).

Stored versus resident: sessions live in the store, and only the maps in use are in memory
(`app.server.residency`). Start-up loads no map; a session loads on its first use (a request
or a socket) through the same path a restart took (`_restored`), and is unloaded (its
counters and last use saved) after idle_unload_s without use, or when the resident budget
(max_resident_sessions) needs room, least recently used first, never while a socket is open
or a keyframe is in flight. Unloading and loading lose what a restart loses, nothing more:
the map and the delta log are durable at every commit, so deltas resume by seq. Retention
(session_retention_days, off by default) deletes sessions unused for longer, at start and
then periodically.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import hmac
import itertools
import logging
import math
import secrets
import threading
import time
import uuid
from collections import deque
from collections.abc import Awaitable, Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import NamedTuple, TypeVar

import msgpack
import numpy as np

from app.config import Knobs, knobs_to_dict, updated_knobs
from app.errors import InputError
from app.keyframes import is_keyframe
from app.mapping.deltas import DeltaLog
from app.mapping.engine import (
    MAX_WORLD_M,
    RECENT_CHANGES,
    MappingEngine,
    QueryHit,
    limit_numpy_threads,
)
from app.mapping.export import imported_object, imported_stay
from app.mapping.grammar import is_relational, parse
from app.mapping.held import held_points
from app.mapping.object import Change, MapObject
from app.mapping.places import DEFAULT_UP, UpInference, up_vector
from app.mapping.publish import client_points, update_message
from app.mapping.relational import MapThing, RelationalHit, answer
from app.mapping.relations import ObjectGeometry, RelationIndex
from app.mapping.relevance import Rating, rate_hits
from app.perception import DEFAULT_BACKEND, BackendOptions, UnknownBackendError, make_backend
from app.perception.base import FrameDetections, PerceptionBackend
from app.protocol import Ack, ErrorReply, FrameBudget, FrameInput
from app.protocol.rest import (
    UP_AXES,
    EmbeddingInfo,
    LatencySummary,
    MapExport,
    SessionStats,
    SessionSummary,
)
from app.semantics import TextEncoder
from app.server.metrics import Metrics
from app.server.residency import Residency
from app.server.scheduler import RoundRobinScheduler
from app.server.settings import ServerSettings
from app.store import (
    KeyframeCommit,
    SessionFenced,
    SessionRecord,
    Store,
    StoredSessionsLimit,
    StoreUnavailableError,
)

Reply = Callable[[dict], Awaitable[None]]

NO_DETECTIONS_WARNING = (
    "frames arrive without detections, and this session's perception backend (detections) "
    "maps only what the device detects: nothing will be mapped. Run the server with "
    "--perception models (its sessions then detect objects in the pixels), or stream from a "
    "device that sends detections."
)
FLUSH_AFTER_S = 1.0
"""Longest a confirmed change waits for its publication when keyframes stop coming."""
STORAGE_PROBE_INTERVAL_S = 1.0
"""While the store refuses writes, how often it is probed (by keyframes and a timer)."""
COUNTERS_SAVE_INTERVAL_S = 1.0
"""Most frames counted but not saved: a counters-only write follows a frame when the
session's counters were last saved longer ago than this (kill -9 loses at most that)."""
BUSY_RETRY_AFTER_S = 5
"""Retry-After (seconds) when every resident session is busy: no room to load another."""
STORAGE_RETRY_AFTER_S = 2
"""Retry-After (seconds) when the store cannot save the session that would make room."""
SOCKET_LOAD_WORKERS = 4
"""Threads that check sockets' access and load their sessions (off the event loop)."""
LAST_USE_SAVE_INTERVAL_S = 60.0
"""Longest a session's last use (of requests only) waits to be saved while it stays resident."""
RETENTION_CHECK_MAX_INTERVAL_S = 600.0
"""Retention is checked every tenth of the retention period, at least this often."""
SIGHTINGS_WAITING = 8
"""Most non-keyframes a session holds for sighting while a keyframe is on its way or a reader
holds the map; beyond it the oldest is forgotten (frames are samples, not a log)."""
STORAGE_UNAVAILABLE_MESSAGE = (
    "the server cannot save the map now (storage unavailable), so it did not map this "
    "keyframe; the map so far is safe and queries still work; retry later"
)

log = logging.getLogger("semanticxr")


T = TypeVar("T")


def hash_token(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


def token_matches(record: SessionRecord, token: str | None) -> bool:
    """Whether `token` is the session's own (compared in constant time)."""
    return token is not None and hmac.compare_digest(hash_token(token), record.token_hash)


class StoredSessionsFull(RuntimeError):
    """The store holds max_sessions sessions: no session can be created or imported until
    some are deleted. Permanent until then, so not a 503 (which says "retry later")."""


class StorageUnavailable(RuntimeError):
    """A keyframe refused unmapped because the store cannot save now (`storage_unavailable`)."""


class SessionMoved(RuntimeError):
    """This map shard lost its claim on a session (another shard claimed it: this one hung or
    was cut off for longer than its lease). The session is dropped here, unsaved changes
    included; the gateway sends its frames to the new owner."""

    MESSAGE = (
        "this map shard no longer holds the session (another shard took it over); the "
        "keyframe was not mapped here: reconnect (a gateway does so by itself) and resend it"
    )


class PersistFailed(RuntimeError):
    """A keyframe mapped but not saved for a reason other than the storage (a bug); the map
    was put back to its durable state."""


class StorageHealth:
    """Whether the store takes writes; a failure streak runs from the first failed write to
    the next successful one (a commit or a probe). Thread-safe."""

    REASON = "storage unavailable: the server cannot save changes (disk full, I/O error or database down)"
    """What /healthz says while a streak lasts (details, such as paths, go to the log only)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._failing_since: float | None = None
        self._failures = 0
        self._last_probe = -math.inf

    @property
    def failing(self) -> bool:
        return self._failing_since is not None

    @property
    def reason(self) -> str | None:
        """None while writes succeed."""
        return self.REASON if self.failing else None

    def failed(self) -> bool:
        """Record a failed write; True when it starts a streak."""
        with self._lock:
            self._failures += 1
            if self._failing_since is not None:
                return False
            self._failing_since = time.monotonic()
            self._last_probe = self._failing_since
            return True

    def succeeded(self) -> tuple[float, int] | None:
        """Record a successful write; (streak seconds, failed writes) when it ends a streak."""
        with self._lock:
            if self._failing_since is None:
                return None
            ended = (time.monotonic() - self._failing_since, self._failures)
            self._failing_since, self._failures = None, 0
            return ended

    def probe_due(self) -> bool:
        """True (and the probe clock restarts) when failing and the last probe is older than
        STORAGE_PROBE_INTERVAL_S."""
        with self._lock:
            now = time.monotonic()
            if self._failing_since is None or now - self._last_probe < STORAGE_PROBE_INTERVAL_S:
                return False
            self._last_probe = now
            return True


@dataclass
class _Pending:
    frame: FrameInput
    sent: FrameDetections | None
    """The detections the device sent, as validated (the backend's `sent`)."""
    reply: Reply
    received_t: float
    decode_ms: float
    """Time the frame took to decode and validate (part of its mapping latency)."""
    stream: str | None = None
    """The socket's stream id: a keyframe committed under (session, stream, seq) is acked
    from the store, not mapped again, when it is sent again (a gateway resending after a
    shard failure)."""


@dataclass
class _Relations:
    """A session's relation index and the object versions it holds."""

    index: RelationIndex
    versions: dict[int, int]
    """id -> the version of the object whose points the index holds."""


class _Mapped(NamedTuple):
    ack: Ack
    keyframe: int | None
    """The session's keyframe count after it (None: answered from the store, not mapped)."""
    latency_ms: float


@dataclass
class Session:
    record: SessionRecord
    engine: MappingEngine
    bytes_in: dict[str, int] = field(
        default_factory=lambda: {"rgb": 0, "depth": 0, "detections": 0}
    )
    bytes_out: dict[str, int] = field(default_factory=lambda: {"updates": 0})
    dropped: int = 0
    latencies_ms: deque = field(default_factory=lambda: deque(maxlen=2000))
    subscribers: int = 0
    _map_lock: threading.Lock = field(default_factory=threading.Lock)
    _pending: _Pending | None = None
    _mapping: bool = False
    _published: asyncio.Event = field(default_factory=asyncio.Event)
    _published_seq: int = 0
    _flush_timer: asyncio.TimerHandle | None = None
    _closed: bool = False
    _fps_window: deque = field(default_factory=lambda: deque(maxlen=60))
    _stored_floor: int = 0
    """The delta log floor the store holds (its tombstones at or below it are trimmed)."""
    warnings: list[str] = field(default_factory=list)
    """Problems worth a user's attention, each said once (in the log and in the stats)."""
    _relations: _Relations | None = None
    """The relation index of the confirmed objects, made by the first relational query."""
    _relations_lock: threading.Lock = field(default_factory=threading.Lock)
    users: int = 0
    """Sockets and requests using the session now (counted by `Residency`)."""
    last_used: float = field(default_factory=time.monotonic)
    """time.monotonic() of the last use (frame, request, socket): idleness, LRU order."""
    _sightings_waiting: deque = field(default_factory=lambda: deque(maxlen=SIGHTINGS_WAITING))
    """(frame, sent) of validated non-keyframes not yet counted as sightings (`sight`)."""
    moved: bool = False
    """Closed because another map shard took the session over (not deleted)."""
    on_close: set[Callable[[], None]] = field(default_factory=set)
    """Called on the event loop when the session closes (a stream socket waiting for its
    device's next frame closes at once)."""
    epoch: int | None = None
    """On a map shard: the epoch of this shard's claim; every write is conditional on it.
    None on a standalone server (it claims nothing)."""
    up_inference: UpInference = field(default_factory=UpInference)
    """The up axis its keyframes' poses say, while the session has none set or settled
    (memory only: a session unloaded before its poses settle one starts counting again)."""

    @property
    def busy(self) -> bool:
        """In use (open sockets, requests) or mapping a keyframe: never unloaded then."""
        return self.users > 0 or self._mapping

    def touch(self) -> None:
        """Note a use now (for idle unloading and for retention, which the store keeps)."""
        self.last_used = time.monotonic()
        self.record.last_used_at = time.time()

    @property
    def closed(self) -> bool:
        """True once the session is deleted (its sockets then close)."""
        return self._closed

    @property
    def id(self) -> str:
        return self.record.session_id

    @property
    def knobs(self) -> Knobs:
        return self.engine.knobs

    def check_token(self, token: str | None) -> bool:
        return token_matches(self.record, token)

    @property
    def up_axis(self) -> str:
        """The world axis that is up ("+z", "+y", ...): set at creation, else inferred from
        the poses once they settle one (`UpInference`), else DEFAULT_UP."""
        return self.record.up or DEFAULT_UP

    @property
    def up_source(self) -> str:
        """Where `up_axis` comes from: "set", "inferred" or "default"."""
        return self.record.up_source or "default"

    @property
    def up(self) -> np.ndarray:
        """`up_axis` as a unit vector, float64 [3]: what relations and places are measured
        along."""
        return up_vector(self.up_axis)

    # ------------------------------------------------------------------ reading
    def stats(self) -> SessionStats:
        """The session's figures. mapping_latency_ms: p50/p95 of the server time per mapped
        keyframe (DESIGN.md "Mapping latency"): decode + perception + mapping + delta (its
        commit to the delta log and the store), without the time it queued for a worker."""
        lat = np.asarray(self.latencies_ms) if self.latencies_ms else None
        with self._map_lock:
            confirmed = sum(o.confirmed for o in self.engine.objects.values())
            seq = self.engine.log.seq
        window = list(self._fps_window)
        fps = (
            (len(window) - 1) / (window[-1] - window[0])
            if len(window) > 1 and window[-1] > window[0]
            else 0.0
        )
        return SessionStats(
            session_id=self.id,
            name=self.record.name,
            mode=self.engine.mode,
            perception=self.record.perception,
            created_at=self.record.created_at,
            frames=self.record.frames,
            frames_whole=self.record.frames - self.record.sightings,
            sightings=self.record.sightings,
            keyframes=self.engine.keyframes,
            dropped_frames=self.dropped,
            objects=confirmed,
            fps=fps,
            bytes_in=dict(self.bytes_in, total=sum(self.bytes_in.values())),
            bytes_out=dict(self.bytes_out, total=sum(self.bytes_out.values())),
            mapping_latency_ms=LatencySummary(
                p50=float(np.percentile(lat, 50)) if lat is not None else None,
                p95=float(np.percentile(lat, 95)) if lat is not None else None,
            ),
            update_seq=seq,
            subscribers=self.subscribers,
            embedding=EmbeddingInfo(
                model=self.engine.encoder.model_id, dim=self.engine.encoder.dim
            ),
            knobs=knobs_to_dict(self.knobs),
            warnings=list(self.warnings),
            up=self.up_axis,
            up_source=self.up_source,
        )

    def warn_once(self, warning: str) -> None:
        """Say `warning` in the server log and the session's stats, unless already said."""
        if warning not in self.warnings:
            self.warnings.append(warning)
            log.warning("session %s: %s", self.id, warning)

    def objects(self) -> list[MapObject]:
        with self._map_lock:
            return self.engine.confirmed_objects()

    def query(self, text: str, k: int) -> list[QueryHit]:
        return self.rated_query(text, k)[0]

    def rated_query(
        self, text: str, k: int, removed: list[MapObject] | None = None
    ) -> tuple[list[QueryHit], Rating]:
        """The top-k hits, best first, and how well they answer (app.mapping.relevance).

        removed: objects of the map's history (state "removed") ranked with the present
        ones (`include=removed`: "where did I leave my laptop")."""
        embedding = self.engine.encoder.encode_query(text)  # outside the lock: the slow part
        with self._map_lock:
            hits = self.engine.query_embedding(embedding, k)
        if removed:
            scores = np.stack([o.embedding for o in removed]) @ embedding.astype(np.float32)
            hits = [*hits, *(QueryHit(o, float(s)) for o, s in zip(removed, scores, strict=True))]
            hits = sorted(hits, key=lambda h: -h.score)[:k]
        return hits, rate_hits(self.engine.encoder, embedding, [h.object.label for h in hits])

    def relational_query(
        self, text: str, k: int, asker: np.ndarray | None = None
    ) -> tuple[list[RelationalHit], dict[int, MapObject]] | None:
        """The top-k hits of a question about how things stand ("the mug on the desk",
        app.mapping.relational) and the objects they name by id; None for a question to
        answer as plain (`rated_query`). Up is the session's (`up`); the asker stands at
        `asker` (world metres), else at the camera of the newest device pose."""
        reading = parse(text)
        if not is_relational(reading):
            return None
        with self._map_lock:
            objects = [(o, o.version) for o in self.engine.confirmed_objects()]
            pose = self.engine.last_pose
        up = self.up
        viewer = asker if asker is not None or pose is None else np.asarray(pose)[:3, 3]
        things = [MapThing(o.id, o.label, o.embedding) for o, _ in objects]
        with self._relations_lock:  # the index computes pairs as it is read
            index = self._relation_index(objects, up)
            hits = answer(reading, things, index, self.engine.encoder, viewer, k)
        if hits is None:
            return None
        return hits, {o.id: o for o, _ in objects}

    def _relation_index(
        self, objects: list[tuple[MapObject, int]], up: np.ndarray
    ) -> RelationIndex:
        """Under `_relations_lock`: the index brought up to the confirmed objects (id,
        version), each by exactly the points a device's local map holds (its client-capped
        points as the wire and the local map store them: `held_points`), so a relation's
        degree is the same on the server and on the device. Each query pays a pass over the
        ids; only objects whose version changed get new bodies, and only their pairs are
        recomputed, when read. A new up axis starts a new index."""
        held = self._relations
        if held is None or not np.array_equal(held.index.up, up):
            held = self._relations = _Relations(RelationIndex(up), {})
        max_points = self.knobs.max_object_points_client
        upserts = {
            o.id: ObjectGeometry(o.label, held_points(client_points(o, max_points)))
            for o, version in objects
            if held.versions.get(o.id) != version
        }
        present = {o.id for o, _ in objects}
        removed = [i for i in held.versions if i not in present]
        held.index.update(upserts, removed)
        for i in removed:
            del held.versions[i]
        held.versions.update({o.id: version for o, version in objects if o.id in upserts})
        return held.index

    def build_delta(self, since: int | None) -> dict:
        """The update message for a subscriber whose last applied seq is `since`."""
        with self._map_lock:
            return update_message(self.engine, since)

    # ------------------------------------------------------------------ sightings
    def sight(self, frame: FrameInput, sent: FrameDetections) -> None:
        """In a decode thread: count a validated non-keyframe's detections as sightings
        towards confirmation (`MappingEngine.sight`), in frame order and without ever
        waiting for the map. While a keyframe is on its way (waiting for its turn or
        mapping) the frame waits behind it, since the keyframe may create the candidates it
        sights; the next keyframe counts what waits before it maps, and so does the next
        sighting once the map is free. A sighting changes nothing published: a candidate it
        qualifies is confirmed, then committed and published, by the next keyframe."""
        self._sightings_waiting.append((frame, sent))
        if not self._mapping and self._map_lock.acquire(blocking=False):
            try:
                self.sight_waiting()
            finally:
                self._map_lock.release()

    def sight_waiting(self) -> None:
        """Under the map lock: count the waiting sightings, oldest first. A sighting that
        fails is logged and forgotten; it never fails a keyframe."""
        while self._sightings_waiting and not self._closed:
            frame, sent = self._sightings_waiting.popleft()
            try:
                self.engine.sight(frame, sent)
            except Exception:
                log.exception(
                    "session %s: counting frame %s as a sighting failed", self.id, frame.seq
                )

    # ------------------------------------------------------------------ publishing
    def wait_published(self) -> asyncio.Event:
        """An event set at the next publication (every local_map_update_frequency keyframes)."""
        return self._published

    def _publish(self) -> None:
        if self._flush_timer is not None:
            self._flush_timer.cancel()
            self._flush_timer = None
        self._published_seq = self.engine.log.seq
        event, self._published = self._published, asyncio.Event()
        event.set()

    def after_keyframe(self, keyframe: int) -> None:
        """Publish every `local_map_update_frequency` keyframes; a change left over between
        publications goes out at most FLUSH_AFTER_S later, so subscribers always catch up."""
        if keyframe % self.knobs.local_map_update_frequency == 0:
            self._publish()
        elif self.engine.log.seq > self._published_seq and self._flush_timer is None:
            self._flush_timer = asyncio.get_running_loop().call_later(FLUSH_AFTER_S, self.flush)

    def flush(self) -> None:
        """Publish now if the map changed since the last publication (e.g. a stream ended)."""
        self._flush_timer = None
        if self.engine.log.seq > self._published_seq:
            self._publish()

    def close(self) -> None:
        """On the event loop: mark the session closed (deleted or moved), wake its update
        subscribers and run `on_close` (stream sockets close themselves)."""
        self._closed = True
        self._publish()
        for callback in self.on_close:
            with contextlib.suppress(Exception):
                callback()


class SessionManager:
    """All sessions of a server, their persistence and their keyframe pipelines."""

    def __init__(
        self, settings: ServerSettings, store: Store, encoder: TextEncoder, metrics: Metrics
    ):
        self.settings = settings
        self.store = store
        self.encoder = encoder
        self.metrics = metrics
        # every worker limits numpy's BLAS itself: where torch is loaded, a limit set in one
        # thread (the server's, when it does not run in the main thread) may not reach others
        self.pool = ThreadPoolExecutor(
            max_workers=settings.mapping_workers,
            thread_name_prefix="map",
            initializer=limit_numpy_threads,
        )
        self.scheduler = RoundRobinScheduler(self.pool, settings.mapping_workers)
        self._map_tasks: set[asyncio.Task] = set()
        self.decode_pool = ThreadPoolExecutor(
            max_workers=settings.decode_workers,
            thread_name_prefix="decode",
            initializer=limit_numpy_threads,
        )
        """Frames are decoded apart from mapping: a slow keyframe never delays the acks of
        other frames, and a burst of frames never delays a keyframe's mapping."""
        self.frame_budget = FrameBudget(settings.max_frame_pixels, settings.max_instances_per_frame)
        """What a frame may cost, checked before its pixels are decoded."""
        self.resident: Residency[Session] = Residency(
            settings.max_resident_sessions, self._load, self._unload, BUSY_RETRY_AFTER_S
        )
        """The sessions whose maps are in memory; every session is in the store."""
        self._retention_due = -math.inf
        """time.monotonic() at which retention is next checked."""
        self.storage = StorageHealth()
        self._store_io = ThreadPoolExecutor(max_workers=1, thread_name_prefix="store")
        """Counters-only writes, probes, idle unloading and retention: off the event loop,
        out of the mapping pool."""
        self._socket_pool = ThreadPoolExecutor(
            max_workers=SOCKET_LOAD_WORKERS, thread_name_prefix="load"
        )
        """Sockets' access checks and session loads (REST runs them in its own threads)."""
        self._counters_saved_at: dict[str, float] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        """The server's event loop (set when housekeeping starts): sessions another shard
        took over are closed on it."""
        self.backends: dict[str, PerceptionBackend] = {}
        """Perception backends loaded (at start), by name: what sessions may choose."""
        for name in [*settings.perception_backends, DEFAULT_BACKEND]:
            self._load_backend(name)

    def _load_backend(self, name: str) -> PerceptionBackend:
        if name not in self.backends:
            options = BackendOptions(models_dir=self.settings.models_dir)
            self.backends[name] = make_backend(name, options)
        return self.backends[name]

    def _engine(self, rec: SessionRecord, knobs: Knobs) -> MappingEngine:
        """The session's engine: its backend as its organisation uses it, and the backend's
        text encoder when it has one (a `models` session embeds labels and queries with
        CLIP's text tower, and announces that model), else the server's."""
        backend = self._load_backend(rec.perception).for_mode(rec.mode)
        encoder = backend.text_encoder or self.encoder
        return MappingEngine(
            encoder, knobs, mode=rec.mode, backend=backend, max_objects=self.settings.max_objects
        )

    @property
    def sessions(self) -> dict[str, Session]:
        """The resident sessions, by id (a snapshot; stored sessions: `list_sessions`)."""
        return self.resident.snapshot()

    def restore(self) -> int:
        """At start: delete the sessions past their retention (when it is set) and count the
        stored sessions; returns how many. Loads no map: each loads on its first use."""
        self.apply_retention()
        stored = self.store.count_sessions()
        self.metrics.sessions_stored.set(stored)
        if self.settings.shard_name is not None:
            self.keep_claims()  # gateways may route to this shard from now on
            log.info(
                "map shard %s at %s (leases of %g s)",
                self.settings.shard_name,
                self.settings.shard_address,
                self.settings.shard_lease_s,
            )
        log.info(
            "%d sessions stored; maps load on first use (at most %d in memory, unloaded after "
            "%g s unused)",
            stored,
            self.settings.max_resident_sessions,
            self.settings.idle_unload_s,
        )
        return stored

    def close(self) -> None:
        """Close every session, let keyframes in flight finish, then save every resident
        session's counters (frames counted since the last keyframe are not lost to a
        shutdown)."""
        resident = list(self.sessions.values())
        for session in resident:
            session.close()
        self.pool.shutdown(wait=True, cancel_futures=True)
        self.decode_pool.shutdown(wait=True, cancel_futures=True)
        self._socket_pool.shutdown(wait=True, cancel_futures=True)
        self._store_io.shutdown(wait=True, cancel_futures=True)
        for session in resident:
            self._save_counters(session, even_if_failing=True)
            self._release_claim(session)
        if self.settings.shard_name is not None:
            with contextlib.suppress(StoreUnavailableError):  # else its heartbeat goes stale
                self.store.forget_shard(self.settings.shard_name)

    # ------------------------------------------------------------------ resident or stored
    def record(self, sid: str) -> SessionRecord | None:
        """Session `sid`'s record (the resident one, else the stored row: no map is read);
        None when there is no such session."""
        session = self.resident.get(sid)
        if session is not None:
            return session.record
        try:
            return self.store.load_session(sid)
        except KeyError:
            return None

    def acquire(self, sid: str) -> Session:
        """Session `sid` in use until `release(session)`: loaded first if not resident (off
        the event loop: call it from a thread). Raises KeyError when no such session is
        stored, ResidentSessionsBusy when every resident session is busy, or
        StoreUnavailableError when the session that would make room cannot be saved."""
        return self.resident.acquire(sid)

    def release(self, session: Session) -> None:
        """End a use of `session`; its last use reaches the store within
        LAST_USE_SAVE_INTERVAL_S (frames and keyframes save it sooner)."""
        self.resident.release(session)
        saved_at = self._counters_saved_at.get(session.id, -math.inf)
        if time.monotonic() - saved_at >= LAST_USE_SAVE_INTERVAL_S:
            self.save_counters_soon(session)

    def _restored(self, rec: SessionRecord) -> Session:
        """The session as the store holds it: confirmed objects, delta log, counters (what a
        restart gives back, and what a load after an unload gives back).

        A stored log with more than max_tombstones (a smaller setting, or a database from
        before tombstones were trimmed) is trimmed now, in memory and in the store (or at
        its next commit, if the store refuses writes now)."""
        stored = self.store.load_delta_log(rec.session_id)
        log = DeltaLog.from_state(stored.state(), self.settings.max_tombstones)
        floor = stored.floor
        if log.floor > stored.floor:
            with contextlib.suppress(StoreUnavailableError):
                self.store.trim_tombstones(rec.session_id, log.floor)
                floor = log.floor
        engine = self._engine(rec, updated_knobs(Knobs(), rec.knobs))
        self._restore_engine(engine, rec, log)
        return Session(rec, engine, _stored_floor=floor)

    def _restore_engine(self, engine: MappingEngine, rec: SessionRecord, log: DeltaLog) -> None:
        """Put the stored map into `engine`: its present objects, delta log, newest keyframe
        (time and pose) and newest changes (for deltas)."""
        engine.restore(
            self.store.load_objects(rec.session_id),
            log,
            rec.keyframes,
            rec.next_object_id,
            last_t=rec.last_t,
            recent_changes=self.store.load_changes(rec.session_id, limit=RECENT_CHANGES),
        )
        if rec.last_pose is not None:
            engine.last_pose = np.asarray(rec.last_pose, np.float64).reshape(4, 4)

    def _load(self, sid: str) -> Session:
        """`Residency`'s loader (in the caller's thread): the stored session; KeyError if none."""
        t0 = time.perf_counter()
        epoch = self._claim(sid)  # first: what loads next is final (older owners are fenced)
        session = self._restored(self.store.load_session(sid))
        session.epoch = epoch
        session.touch()
        # Retention counts from this use, even if the server is killed before the next save
        # (and while the store refuses writes, from the last use it holds).
        with contextlib.suppress(StoreUnavailableError):
            self.store.update_session(sid, last_used_at=session.record.last_used_at, epoch=epoch)
            self._counters_saved_at[sid] = time.monotonic()
        self.metrics.session_loads.inc()
        self.metrics.session_load_latency.observe(time.perf_counter() - t0)
        return session

    def _unload(self, session: Session, reason: str) -> None:
        """`Residency`'s unloader: save what only memory holds (frame and byte counters, last
        use; the map and delta log are saved at every commit) and let the session go.
        StoreUnavailableError (it stays resident) when the store refuses the write."""
        with session._map_lock:  # after a counters save in flight, never before it
            try:
                self.store.update_session(
                    session.id,
                    counters=self._counters(session, False),
                    last_used_at=session.record.last_used_at,
                    epoch=session.epoch,
                )
            except (KeyError, SessionFenced):
                pass  # deleted or taken over meanwhile: nothing left to save here
            except StoreUnavailableError as exc:
                self._store_failed(f"saving session {session.id} to unload it", exc)
                raise
            else:
                self._store_succeeded()
        self._release_claim(session)
        self._counters_saved_at.pop(session.id, None)
        self.metrics.session_unloads.labels(reason=reason).inc()
        log.info(
            "session %s unloaded from memory (%s); it loads again on its next use",
            session.id,
            "unused for --idle-unload-s" if reason == "idle" else "room for another",
        )

    # ------------------------------------------------------------------ claims (map shards)
    def _claim(self, sid: str) -> int | None:
        """On a map shard: claim session `sid` in the store (its epoch), fencing any earlier
        owner's writes; SessionHeld when a live shard holds it. None on a standalone server."""
        name = self.settings.shard_name
        if name is None:
            return None
        return self.store.claim_session(sid, name, self.settings.shard_lease_s)

    def _release_claim(self, session: Session) -> None:
        """Let another shard take `session` at once (it was saved and unloaded here)."""
        if session.epoch is not None:
            with contextlib.suppress(StoreUnavailableError):  # then its lease runs out
                self.store.release_session(session.id, self.settings.shard_name, session.epoch)

    def _drop_taken_over(self, session: Session, close: bool = True) -> None:
        """Forget a session another shard claimed (this one hung or lost the store for longer
        than its lease): nothing of it is written from here again, and its sockets close
        (`close`; else the keyframe pipeline closes it once its reply has gone out)."""
        if self.resident.get(session.id) is session:
            self.resident.forget(session)
        if session.moved:  # a renewal and a write both found the claim gone
            return
        session.moved = True
        self.metrics.sessions_taken_over.inc()
        log.warning(
            "session %s: another map shard claimed it (this shard's lease ran out); dropped "
            "here, its sockets close and reconnect to the new owner",
            session.id,
        )
        if not close:
            return
        if self._loop is not None and not self._loop.is_closed():
            self._loop.call_soon_threadsafe(session.close)
        else:
            session._closed = True

    def keep_claims(self) -> None:
        """On a map shard, every second: say it is alive (with the address gateways reach it
        at) and renew the leases of its resident sessions; drop those another shard took."""
        name = self.settings.shard_name
        if name is None:
            return
        resident = self.sessions
        self.store.heartbeat_shard(name, self.settings.shard_address)
        epochs = {sid: s.epoch for sid, s in resident.items() if s.epoch is not None}
        for sid in self.store.renew_leases(name, epochs, self.settings.shard_lease_s):
            self._drop_taken_over(resident[sid])

    def unload_idle(self) -> list[str]:
        """Unload the sessions unused for idle_unload_s (no frames, requests or sockets, no
        keyframe in flight); their ids."""
        return self.resident.unload_idle(self.settings.idle_unload_s)

    def list_sessions(self) -> list[SessionSummary]:
        """Every stored session, oldest first, as `GET /v1/sessions` lists it: a resident one
        with its live figures, the others from their stored rows (no map is loaded);
        `resident` says which."""
        listed = []
        for entry in self.store.list_stored():
            rec = entry.record
            session = self.resident.get(rec.session_id)
            if session is not None:
                stats = session.stats()
                listed.append(
                    SessionSummary(
                        session_id=stats.session_id,
                        name=stats.name,
                        mode=stats.mode,
                        objects=stats.objects,
                        frames=stats.frames,
                        frames_whole=stats.frames_whole,
                        sightings=stats.sightings,
                        keyframes=stats.keyframes,
                        fps=stats.fps,
                        update_seq=stats.update_seq,
                        last_used_at=session.record.last_used_at,
                        resident=True,
                        up=stats.up,
                        up_source=stats.up_source,
                    )
                )
                continue
            listed.append(
                SessionSummary(
                    session_id=rec.session_id,
                    name=rec.name,
                    mode=rec.mode,
                    objects=entry.objects,
                    frames=rec.frames,
                    frames_whole=rec.frames - rec.sightings,
                    sightings=rec.sightings,
                    keyframes=rec.keyframes,
                    fps=0.0,
                    update_seq=entry.seq,
                    last_used_at=rec.last_used_at,
                    resident=False,
                    up=rec.up or DEFAULT_UP,
                    up_source=rec.up_source or "default",
                )
            )
        return listed

    # ------------------------------------------------------------------ retention
    def apply_retention(self) -> list[str]:
        """Delete every session unused (no frames, requests or sockets) for longer than
        session_retention_days, each logged and counted; their ids. Does nothing when
        retention is off (unset). A resident session counts by its use in memory, and one
        in use is never deleted."""
        days = self.settings.session_retention_days
        if days is None:
            return []
        period_s = days * 86_400.0
        self._retention_due = time.monotonic() + min(RETENTION_CHECK_MAX_INTERVAL_S, period_s / 10)
        cutoff = time.time() - period_s

        def still_idle(session: Session | None) -> bool:
            return session is None or (
                not session.busy and (session.record.last_used_at or 0.0) < cutoff
            )

        def delete_if_unused(session: Session | None, sid: str) -> bool:
            if session is None:  # nobody can load it now: its stored last use is final
                rec = self.record(sid)
                if rec is None or (rec.last_used_at or 0.0) >= cutoff:
                    return False
            self._delete(sid, session)
            return True

        deleted = []
        for sid in self.store.idle_sessions(cutoff):
            if self.resident.remove(
                sid, lambda session, sid=sid: delete_if_unused(session, sid), still_idle
            ):
                deleted.append(sid)
                self.metrics.sessions_expired.inc()
                log.info(
                    "session %s deleted: unused for over %g days (--session-retention-days)",
                    sid,
                    days,
                )
        if deleted:
            self.metrics.sessions_stored.set(self.store.count_sessions())
        return deleted

    def _retention_check_due(self) -> bool:
        return (
            self.settings.session_retention_days is not None
            and time.monotonic() >= self._retention_due
        )

    # ------------------------------------------------------------------ lifecycle
    def create(
        self,
        name: str | None,
        mode: str,
        knob_changes: dict,
        perception: str | None = None,
        up: str | None = None,
    ) -> tuple[Session, str]:
        """A new session and its token (the only time the token is shown), resident.

        perception: one of the backends loaded at start (default: the first the server's
        `perception` setting names); UnknownBackendError naming --perception otherwise.
        up: the world axis that is up ("+x", "-x", "+y", "-y", "+z", "-z"; InputError naming
        `up` otherwise); None: inferred from the poses (`Session.up_axis`).
        Raises StoredSessionsFull past max_sessions stored, and as `acquire` does when the
        resident budget has no room."""
        session, token = self._create(name, mode, knob_changes, perception, up)
        self.release(session)
        return session, token

    def _create(
        self,
        name: str | None,
        mode: str,
        knob_changes: dict,
        perception: str | None,
        up: str | None = None,
        up_source: str = "set",
    ) -> tuple[Session, str]:
        """`create`, the session left in use (release it); `up_source`: where a given `up`
        came from ("set", or "inferred" by the session an import comes from)."""
        if up is not None and up not in UP_AXES:
            raise InputError("up", f"must be one of {', '.join(UP_AXES)}; got {up!r}")
        knobs = updated_knobs(Knobs(), knob_changes or {})
        perception = perception or self.settings.perception_backends[0]
        if perception not in self.backends:
            raise UnknownBackendError(
                f"perception {perception!r} is not loaded on this server; choose one of "
                f"{', '.join(self.backends)} (a server loads backends with --perception)"
            )
        self._check_room_to_store()  # before making room in memory for nothing
        token = secrets.token_urlsafe(24)
        sid = uuid.uuid4().hex[:16]
        now = time.time()
        rec = SessionRecord(
            session_id=sid,
            name=name or f"session-{sid[:6]}",
            mode=mode,
            knobs=knobs_to_dict(knobs),
            token_hash=hash_token(token),
            created_at=now,
            perception=perception,
            last_used_at=now,
            up=up,
            up_source=None if up is None else up_source,
        )

        def make() -> Session:
            try:  # the count and the insert in one transaction: never two in the last place
                self.store.create_session(rec, max_sessions=self.settings.max_sessions)
            except StoredSessionsLimit:
                self._check_room_to_store()  # raises StoredSessionsFull with the fix
                raise
            engine = self._engine(rec, knobs)
            engine.restore([], DeltaLog(max_tombstones=self.settings.max_tombstones), 0, 1)
            return Session(rec, engine, epoch=self._claim(sid))

        session = self.resident.admit(sid, make, users=1)
        self.metrics.sessions_stored.inc()
        return session, token

    def _check_room_to_store(self) -> None:
        """Raise StoredSessionsFull, with the fix, when the store holds max_sessions."""
        limit = self.settings.max_sessions
        if self.store.count_sessions() >= limit:
            raise StoredSessionsFull(
                f"the server stores its maximum of {limit} sessions (--max-sessions); delete "
                f"sessions you no longer need (semanticxr sessions delete SID) or raise "
                f"--max-sessions"
            )

    def import_session(self, export: MapExport) -> tuple[Session, str]:
        """A new session holding an export's objects, with their ids, and its token.

        The export's history comes along: its removed objects (kept as history, out of the
        map) and its changes. Everything is committed to the store before the session is
        used, so a restart keeps it: the changes at the update seqs they carry (one commit
        per seq, in order, so `since_seq` reads the same history) and the objects at the
        seq of the newest change (1 without changes), which is the session's update seq.
        The export's up axis, when it has one, is kept with its source (set or inferred).
        Raises as `create` does, and InputError naming the field when the export's embedding
        dimension is not the session's encoder's, it holds more objects or removed objects
        than max_objects, an id twice, a removed object or a stay beyond MAX_WORLD_M, or
        changes out of seq order; nothing is left behind then."""
        spec = export.session
        removed_records = export.removed_objects or []
        for name, records in (("objects", export.objects), ("removed_objects", removed_records)):
            if len(records) > self.settings.max_objects:
                raise InputError(
                    name, f"{len(records)} objects, over max_objects={self.settings.max_objects}"
                )
        _check_imported_history(export)
        perception = spec.perception if spec.perception in self.backends else None
        session, token = self._create(
            spec.name, spec.mode, spec.knobs, perception, spec.up, spec.up_source or "set"
        )
        try:
            engine = session.engine
            if spec.embedding.dim != engine.encoder.dim:
                raise InputError(
                    "session.embedding.dim",
                    f"{spec.embedding.dim}, but this server embeds with {engine.encoder.model_id} "
                    f"({engine.encoder.dim} dimensions)",
                )
            records = [*export.objects, *removed_records]
            without = [o.label for o in records if o.embedding is None]
            by_label = dict(zip(without, engine.encoder.encode(without), strict=True))
            objects, removed = [], []
            for name, state, group, into in (
                ("objects", "present", export.objects, objects),
                ("removed_objects", "removed", removed_records, removed),
            ):
                for i, o in enumerate(group):
                    embedding = (
                        np.asarray(o.embedding, np.float32) if o.embedding else by_label[o.label]
                    )
                    if len(embedding) != engine.encoder.dim:
                        raise InputError(
                            f"{name}[{i}].embedding",
                            f"{len(embedding)} values, not {engine.encoder.dim}",
                        )
                    into.append(
                        imported_object(
                            o.id,
                            o.version,
                            o.label,
                            o.n_obs,
                            o.points,
                            embedding,
                            engine.knobs.voxel_size_m,
                            first_seen_t=o.first_seen_t,
                            last_seen_t=o.last_seen_t,
                            stays=[imported_stay(**s.model_dump()) for s in o.stays or []],
                            state=state,
                        )
                    )
            changes = [
                Change(c.id, c.kind, c.t, c.label, _xyz(c.from_), _xyz(c.to), c.seq)
                for c in export.changes or []
            ]
            if not objects and not removed and not changes:
                return session, token
            ids = [o.id for o in objects] + [o.id for o in removed] + [c.id for c in changes]
            next_object_id = max(ids) + 1
            seq = max([1, *(c.seq for c in changes)])
            with session._map_lock:
                counters = self._counters(session)
                for change_seq, group in itertools.groupby(changes, key=lambda c: c.seq):
                    if change_seq < seq:  # the newest seq's changes go with the objects
                        self.store.commit_keyframe(KeyframeCommit(
                            session.id, change_seq, [], [], counters, next_object_id,
                            changes=list(group), epoch=session.epoch,
                        ))  # fmt: skip
                self.store.commit_keyframe(
                    KeyframeCommit(
                        session.id,
                        seq,
                        objects,
                        [o.id for o in removed],
                        counters=counters,
                        next_object_id=next_object_id,
                        retired=removed,
                        changes=[c for c in changes if c.seq == seq],
                        epoch=session.epoch,
                    )
                )
                log = DeltaLog.from_state(
                    {
                        "seq": seq,
                        "floor": 0,
                        "upserted_at": {o.id: seq for o in objects},
                        "removed_at": {o.id: seq for o in removed},
                    },
                    self.settings.max_tombstones,
                )
                engine.restore(
                    objects, log, engine.keyframes, next_object_id, recent_changes=changes
                )
                session.record.next_object_id = next_object_id
        except BaseException:
            self.delete(session.id)
            raise
        finally:
            self.release(session)
        return session, token

    def export_contents(
        self, session: Session
    ) -> tuple[list[MapObject], list[MapObject], list[Change]]:
        """What a JSON export of `session` holds, read at one instant (under the map lock):
        its confirmed objects, its removed objects kept as history and its changes (the
        last two from the store, which holds all of them)."""
        with session._map_lock:
            return (
                session.engine.confirmed_objects(),
                self.store.load_removed_objects(session.id),
                self.store.load_changes(session.id),
            )

    def delete(self, sid: str) -> None:
        """Delete session `sid` with its map, resident or not (its sockets close)."""
        self.resident.remove(sid, lambda session: self._delete(sid, session))
        self.metrics.sessions_stored.set(self.store.count_sessions())

    def _delete(self, sid: str, session: Session | None) -> bool:
        if session is None:
            self.store.delete_session(sid)
            return True
        session.close()
        with session._map_lock:  # let a keyframe in flight finish first
            self.store.delete_session(sid)
        self._counters_saved_at.pop(sid, None)
        return True

    def set_knobs(self, session: Session, changes: dict) -> Knobs:
        with session._map_lock:
            knobs = updated_knobs(session.knobs, changes)
            self.store.update_session(session.id, knobs=knobs_to_dict(knobs), epoch=session.epoch)
            session.engine.knobs = knobs
            session.record.knobs = knobs_to_dict(knobs)
        return knobs

    async def in_thread(self, fn: Callable[..., T], *args: object) -> T:
        """`fn(*args)` in a socket thread (access checks and loads of sessions for sockets:
        the event loop only moves bytes)."""
        return await asyncio.get_running_loop().run_in_executor(self._socket_pool, fn, *args)

    # ------------------------------------------------------------------ ingest
    async def decode(self, decode: Callable[[], T]) -> T:
        """Run a frame's unpacking, decoding and validation in the decode pool (never on the
        event loop: a hostile message costs a decode thread, not every session's sockets)."""
        return await asyncio.get_running_loop().run_in_executor(self.decode_pool, decode)

    async def sight(
        self, session: Session, frame: FrameInput, sent: FrameDetections | None
    ) -> None:
        """Count a validated non-keyframe's detections as sightings (`Session.sight`), in the
        decode pool; only where the session maps the device's own detections."""
        if sent is None or session.engine.backend.name != DEFAULT_BACKEND:
            return
        with contextlib.suppress(RuntimeError):  # the pool shut down: the server is stopping
            await asyncio.get_running_loop().run_in_executor(
                self.decode_pool, session.sight, frame, sent
            )

    @staticmethod
    def keyframe_next(session: Session) -> bool:
        """Whether the session's next valid frame is the shared selector's keyframe (what
        `count_frame` will say of it, unless another socket's frame is counted first)."""
        return is_keyframe(session.record.frames, session.knobs.keyframe_interval)

    def count_frame(
        self, session: Session, frame_bytes: dict[str, int], keyframe: bool | None = None
    ) -> bool:
        """Count a valid frame (or sighting); True when it is a keyframe: the one the device
        picked (`keyframe`, with the sightings extension), else the shared selector's pick
        among the frames received (`app.keyframes.is_keyframe`). The counters reach the
        store with each keyframe, or in a counters-only write when they were last saved more
        than COUNTERS_SAVE_INTERVAL_S ago. A frame the device did not pick (`keyframe`
        False) is a sighting: counted in `frames` and apart in `record.sightings`."""
        rec = session.record
        rec.frames += 1
        if keyframe is False:
            rec.sightings += 1
        session.touch()
        if "detections" not in frame_bytes and session.engine.backend.name == DEFAULT_BACKEND:
            session.warn_once(NO_DETECTIONS_WARNING)
        now = time.monotonic()
        session._fps_window.append(now)
        for kind, n in frame_bytes.items():
            session.bytes_in[kind] = session.bytes_in.get(kind, 0) + n
            self.metrics.upstream_bytes.labels(kind=kind).inc(n)
        if now - self._counters_saved_at.get(session.id, 0.0) >= COUNTERS_SAVE_INTERVAL_S:
            self.save_counters_soon(session)
        if keyframe is not None:
            return keyframe
        return is_keyframe(rec.frames - 1, session.knobs.keyframe_interval)

    # ------------------------------------------------------------------ the map's history
    def removed_objects(self, session: Session) -> list[MapObject]:
        """The session's removed objects (history, from the store), in id order."""
        return self.store.load_removed_objects(session.id)

    def find_object(self, session: Session, object_id: int) -> MapObject | None:
        """An object of the session's present map, else of its history; None if neither."""
        with session._map_lock:
            obj = session.engine.objects.get(object_id)
            if obj is not None and obj.confirmed:
                return obj
        return self.store.load_object(session.id, object_id)

    def changes(self, session: Session, **filters) -> list[Change]:
        """The session's changes from the store (`Store.load_changes` filters)."""
        return self.store.load_changes(session.id, **filters)

    # ------------------------------------------------------------------ counters and storage
    def save_counters_soon(self, session: Session) -> None:
        """Save the session's counters in the background (e.g. when its stream ends)."""
        self._counters_saved_at[session.id] = time.monotonic()
        with contextlib.suppress(RuntimeError):  # shutting down: close() saves them
            self._store_io.submit(self._save_counters, session)

    def _save_counters(self, session: Session, even_if_failing: bool = False) -> None:
        """Write the session's frame and byte counters and its last use (not its map), if it
        is still the resident copy. Under the map lock, so
        a keyframe commit's counters and these land in the order they were taken. Skipped
        while the store refuses writes (unless `even_if_failing`): the next commit or save
        after it recovers carries them."""
        if self.storage.failing and not even_if_failing:
            return
        with session._map_lock:
            if self.resident.get(session.id) is not session:
                return  # unloaded (which saved them) or deleted
            try:
                self.store.update_session(
                    session.id,
                    counters=self._counters(session, False),
                    last_used_at=session.record.last_used_at,
                    epoch=session.epoch,
                )
            except KeyError:
                return  # deleted meanwhile
            except SessionFenced:
                self._drop_taken_over(session)
                return
            except StoreUnavailableError as exc:
                self._store_failed("saving a session's counters", exc)
                return
            self._counters_saved_at[session.id] = time.monotonic()
            self._store_succeeded()

    @staticmethod
    def _counters(session: Session, with_keyframes: bool = True) -> dict[str, int]:
        """The counters a store keeps (absolute values); keyframes only with the map."""
        rec = session.record
        counters = {
            "frames": rec.frames,
            "sightings": rec.sightings,
            "bytes_in": sum(session.bytes_in.values()),
            "bytes_out": sum(session.bytes_out.values()),
        }
        if with_keyframes:
            counters["keyframes"] = rec.keyframes
        return counters

    def _store_failed(self, what: str, exc: BaseException) -> None:
        """Count a failed write; log it if it starts a failure streak (one ERROR a streak)."""
        self.metrics.persist_failures.inc()
        if self.storage.failed():
            log.error(
                "storage failing: %s failed (%s); keyframes are refused with "
                "storage_unavailable and /healthz answers 503 until a write succeeds "
                "(probed every %g s)",
                what,
                exc,
                STORAGE_PROBE_INTERVAL_S,
            )

    def _store_succeeded(self) -> None:
        ended = self.storage.succeeded()
        if ended is not None:
            log.info(
                "storage recovered: writes succeed again after %.1f s and %d failed writes",
                *ended,
            )

    def probe_storage(self) -> bool:
        """While the store refuses writes, probe it (at most every STORAGE_PROBE_INTERVAL_S);
        True when writes work (a successful probe ends the failure streak)."""
        if not self.storage.failing:
            return True
        if not self.storage.probe_due():
            return False
        try:
            self.store.probe()
        except StoreUnavailableError:
            return False
        self._store_succeeded()
        return True

    async def watch_storage(self) -> None:
        """Until cancelled, every STORAGE_PROBE_INTERVAL_S, in the store thread: the server's
        housekeeping (`housekeeping`). (Its name is older than the housekeeping it runs:
        the app starts it at start-up and cancels it at shutdown.)"""
        loop = self._loop = asyncio.get_running_loop()
        while True:
            await asyncio.sleep(STORAGE_PROBE_INTERVAL_S)  # a timer, not synchronisation
            try:
                await loop.run_in_executor(self._store_io, self.housekeeping)
            except RuntimeError:
                return  # the executor shut down: the server is stopping
            except Exception:
                log.exception("housekeeping (store probe, idle unloading, retention) failed")

    def housekeeping(self) -> None:
        """While the store refuses writes: probe it, so /healthz turns 200 again when the
        disk has room even if no keyframe comes. Otherwise: unload the sessions idle for
        idle_unload_s, and apply retention when its check is due."""
        try:
            self.keep_claims()
        except StoreUnavailableError as exc:
            self._store_failed("renewing this shard's claims on its sessions", exc)
        if self.storage.failing:
            self.probe_storage()
            return
        self.unload_idle()
        if self._retention_check_due():
            self.apply_retention()

    def _back_to_durable(self, session: Session, last_pose: np.ndarray | None) -> None:
        """Under the map lock, after a keyframe failed to map or commit: rebuild the session's
        engine from the store, exactly as a restart would. Keeps the knobs and `last_pose`
        (the device pose before the keyframe, which the store does not hold); loses what only
        memory held: unconfirmed candidates (they start again from their next sighting) and
        the set of objects awaiting their next outlier pass. If the
        store cannot be read either, the session is closed (its next use loads it again from
        the store) rather than left showing changes the store lacks."""
        old = session.engine
        try:
            durable = self.store.load_session(session.id)
            stored = self.store.load_delta_log(session.id)
            delta_log = DeltaLog.from_state(stored.state(), self.settings.max_tombstones)
            objects = self.store.load_objects(session.id)
            recent_changes = self.store.load_changes(session.id, limit=RECENT_CHANGES)
        except Exception:
            log.exception(
                "session %s: cannot reload its saved map after a failed keyframe; the session "
                "is closed until the server restarts",
                session.id,
            )
            self.resident.forget(session)
            session._closed = True  # under the map lock; sockets see it and close
            return
        engine = self._engine(session.record, old.knobs)
        engine.restore(
            objects,
            delta_log,
            durable.keyframes,
            durable.next_object_id,
            last_t=durable.last_t,
            recent_changes=recent_changes,
        )
        engine.last_pose = last_pose
        session.engine = engine
        session.record.keyframes = engine.keyframes
        session.record.next_object_id = engine.next_object_id
        session._stored_floor = stored.floor
        # A flush timer may have announced the rolled-back seq; the next one must go out.
        session._published_seq = min(session._published_seq, delta_log.seq)

    async def submit_keyframe(
        self,
        session: Session,
        frame: FrameInput,
        reply: Reply,
        sent: FrameDetections | None = None,
        decode_ms: float = 0.0,
        stream: str | None = None,
    ) -> None:
        """Wait for the session's turn of a mapping worker as its newest keyframe (an older
        one still waiting is acknowledged as dropped); see `RoundRobinScheduler`.

        frame: validated (`MappingEngine.validate_frame`), which returned `sent`;
        decode_ms: what decoding and validating it took; stream: the socket's stream id (a
        keyframe already committed under it is acked from the store, not mapped again)."""
        pending = _Pending(frame, sent, reply, time.perf_counter(), decode_ms, stream)
        if session._mapping:
            older, session._pending = session._pending, pending
            if older is not None:
                await self._drop(session, older)
            return
        session._mapping = True
        task = asyncio.create_task(self._map_loop(session, pending))
        self._map_tasks.add(task)  # a task nobody references may be collected mid-way
        task.add_done_callback(self._map_tasks.discard)

    async def _drop(self, session: Session, older: _Pending) -> None:
        session.dropped += 1
        self.metrics.dropped_frames.inc()
        await older.reply(Ack(older.frame.seq, keyframe=False, dropped=True).pack())

    @staticmethod
    def _newest(session: Session, pending: _Pending) -> tuple[_Pending, _Pending | None]:
        """The keyframe to map once the session's turn comes, and the one it replaces: a
        newer keyframe that arrived while `pending` waited is mapped instead (frames are
        samples: the freshest view is mapped; the stale one is acknowledged as dropped)."""
        newer, session._pending = session._pending, None
        return (pending, None) if newer is None else (newer, pending)

    async def _map_loop(self, session: Session, pending: _Pending | None) -> None:
        try:
            while pending is not None and not session.closed:
                try:
                    async with self.scheduler.turn(session.id) as turn:
                        pending, stale = self._newest(session, pending)
                        mapped = turn.run(self._map_and_persist, session, pending)
                        if stale is not None:  # answered while the worker maps, not before
                            await self._drop(session, stale)
                        mapped = await mapped
                except SessionMoved:
                    await pending.reply(
                        ErrorReply(pending.frame.seq, "session_moved", SessionMoved.MESSAGE).pack()
                    )
                except StorageUnavailable:
                    await pending.reply(
                        ErrorReply(
                            pending.frame.seq, "storage_unavailable", STORAGE_UNAVAILABLE_MESSAGE
                        ).pack()
                    )
                    if session.closed:  # its saved map could not be reloaded
                        session.close()
                except InputError as exc:
                    await pending.reply(ErrorReply(pending.frame.seq, "bad_frame", str(exc)).pack())
                except Exception as exc:  # never lose the ack: report and go on
                    if not isinstance(exc, PersistFailed):  # that one was counted and logged
                        self.metrics.mapping_failures.inc()
                        log.error(
                            "session %s: mapping keyframe %s failed; the map is unchanged",
                            session.id,
                            pending.frame.seq,
                            exc_info=exc,
                        )
                    await pending.reply(
                        ErrorReply(pending.frame.seq, "internal", f"mapping failed: {exc}").pack()
                    )
                    if session.closed:  # its saved map could not be reloaded
                        session.close()
                else:
                    mapped.ack.map_ms = (time.perf_counter() - pending.received_t) * 1e3
                    await pending.reply(mapped.ack.pack())
                    if mapped.keyframe is not None:
                        session.latencies_ms.append(mapped.latency_ms)
                        self.metrics.mapping_latency.observe(mapped.latency_ms / 1e3)
                        session.after_keyframe(mapped.keyframe)
                if session.moved and not session.closed:  # after the reply went out
                    session.close()
                pending, session._pending = session._pending, None
        finally:
            session._mapping = False

    def _map_and_persist(self, session: Session, pending: _Pending) -> _Mapped:
        """In a worker thread: perceive and map the keyframe, then make the change durable
        before the ack, all in one hold of the map lock. Returns the ack and the keyframe's
        mapping latency in ms (the one place it is measured: decode + perception + mapping +
        delta, see `Session.stats`). A keyframe the store says was committed under the same
        (stream, seq) gets its stored ack instead, unmapped (a resend after a shard failure).

        Raises StorageUnavailable, unmapped, while the store refuses writes (a probe first,
        at most every STORAGE_PROBE_INTERVAL_S, rather than mapping and rolling back). If
        mapping or the commit fails, the engine goes back to the store's durable state
        (`_back_to_durable`) before the lock is released: StorageUnavailable when the disk
        refused the commit, PersistFailed for another commit failure, the mapping's own
        exception otherwise; SessionMoved (unmapped, the session dropped here) when another
        map shard has claimed the session."""
        with session._map_lock:
            if session.moved:
                raise SessionMoved(SessionMoved.MESSAGE)
            if session.closed:
                raise InputError("session", "the session was deleted")
            if not self.probe_storage():
                raise StorageUnavailable(StorageHealth.REASON)
            done = self._done_ack(session, pending)
            if done is not None:
                return _Mapped(done, None, 0.0)
            session.sight_waiting()  # the frames since the last keyframe count first
            t_locked = time.perf_counter()  # waiting for a reader of the map is not mapping
            engine, frame = session.engine, pending.frame
            detections = engine.perceive(frame, pending.sent)  # changes nothing in the map
            committing, pose_before = False, engine.last_pose
            try:
                stats = engine.map_keyframe(frame, detections)
                rec = session.record
                rec.keyframes = engine.keyframes
                rec.next_object_id = engine.next_object_id
                # Until set or settled, up is the poses' say; settled, it is saved with the
                # keyframe that settled it (a reload never flips the session's answers).
                inferred_up = None if rec.up else session.up_inference.observe(frame.pose)
                committing = True
                ack = Ack(frame.seq, keyframe=True, update_seq=stats.seq, objects=stats.confirmed)
                self.store.commit_keyframe(
                    KeyframeCommit(
                        session.id,
                        stats.seq,
                        [engine.objects[i] for i in stats.published_ids],
                        stats.removed_ids,
                        counters=self._counters(session),
                        next_object_id=engine.next_object_id,
                        last_used_at=rec.last_used_at,
                        retired=stats.retired,
                        changes=stats.changes,
                        retracted_added=stats.retracted_added,
                        retracted_removed=stats.retracted_removed,
                        last_t=engine.last_t,
                        last_pose=engine.last_pose,
                        epoch=session.epoch,
                        done=None
                        if pending.stream is None
                        else (pending.stream, frame.seq, _ack_record(ack)),
                        inferred_up=inferred_up,
                    )
                )
                if inferred_up is not None:
                    rec.up, rec.up_source = inferred_up, "inferred"
                    log.info("session %s: up is %s (inferred from its poses)", session.id, rec.up)
            except SessionFenced:
                self._drop_taken_over(session, close=False)  # its engine holds unsaved changes
                raise SessionMoved(SessionMoved.MESSAGE) from None
            except BaseException as exc:
                self._back_to_durable(session, pose_before)
                if not committing:
                    raise
                if isinstance(exc, StoreUnavailableError):
                    self._store_failed(f"saving keyframe {frame.seq} of session {session.id}", exc)
                    raise StorageUnavailable(StorageHealth.REASON) from exc
                self.metrics.persist_failures.inc()
                log.error(
                    "session %s: saving keyframe %s failed; its changes were undone",
                    session.id,
                    frame.seq,
                    exc_info=exc,
                )
                raise PersistFailed(f"saving the keyframe failed: {exc}") from exc
            self._counters_saved_at[session.id] = time.monotonic()
            self._store_succeeded()
            if engine.log.floor > session._stored_floor:
                # The log forgot its oldest removals: no subscriber can be sent them any
                # more (it gets a full snapshot), so the store forgets them too.
                try:
                    self.store.trim_tombstones(session.id, engine.log.floor, epoch=session.epoch)
                    session._stored_floor = engine.log.floor
                except SessionFenced:
                    self._drop_taken_over(session, close=False)  # saved: its ack stands
                except StoreUnavailableError as exc:  # the keyframe is saved: retried next time
                    self._store_failed(f"trimming the tombstones of session {session.id}", exc)
            latency_ms = pending.decode_ms + (time.perf_counter() - t_locked) * 1e3
            return _Mapped(ack, stats.keyframe, latency_ms)

    def _done_ack(self, session: Session, pending: _Pending) -> Ack | None:
        """The ack of a keyframe committed before under the same (stream, seq), if the store
        remembers one (`DONE_WINDOW` per session); raises StorageUnavailable if it cannot say."""
        if pending.stream is None:
            return None
        try:
            record = self.store.done_ack(session.id, pending.stream, pending.frame.seq)
        except StoreUnavailableError as exc:
            self._store_failed(f"reading the acks of session {session.id}", exc)
            raise StorageUnavailable(StorageHealth.REASON) from exc
        if record is None:
            return None
        fields = msgpack.unpackb(record)
        return Ack(pending.frame.seq, keyframe=True, **fields)


def _ack_record(ack: Ack) -> bytes:
    """What the store keeps of a committed keyframe's ack, to answer a resend of it."""
    return msgpack.packb({"update_seq": ack.update_seq, "objects": ack.objects})


# ---------------------------------------------------------------------- import checks
def _xyz(values: list[float] | None) -> tuple[float, float, float] | None:
    return None if values is None else (values[0], values[1], values[2])


def _check_imported_history(export: MapExport) -> None:
    """InputError naming the field when an export's history cannot be stored as it is: an id
    both in objects and removed_objects (or twice in removed_objects), a removed object's
    points or a stay beyond MAX_WORLD_M, or a change whose seq is before the one listed
    before it (changes are listed in arrival order). The objects' own ids and points are
    checked by the route."""
    seen = {o.id for o in export.objects}
    for i, o in enumerate(export.removed_objects or []):
        if o.id in seen:
            raise InputError(f"removed_objects[{i}].id", f"{o.id} appears twice")
        seen.add(o.id)
        if np.abs(np.asarray(o.points)).max() > MAX_WORLD_M:
            raise InputError(
                f"removed_objects[{i}].points", f"over {MAX_WORLD_M:g} m from the origin"
            )
    for name, records in (("objects", export.objects), ("removed_objects", export.removed_objects)):
        for i, o in enumerate(records or []):
            for j, stay in enumerate(o.stays or []):
                if np.abs(np.asarray([*stay.centroid, *stay.bbox])).max() > MAX_WORLD_M:
                    raise InputError(
                        f"{name}[{i}].stays[{j}]", f"over {MAX_WORLD_M:g} m from the origin"
                    )
    changes = export.changes or []
    for i in range(1, len(changes)):
        if changes[i].seq < changes[i - 1].seq:
            raise InputError(
                f"changes[{i}].seq",
                f"{changes[i].seq} is before the seq of the change listed before it "
                f"({changes[i - 1].seq}); changes are listed in the order they arrived",
            )
