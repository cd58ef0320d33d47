"""Sessions: one mapping engine each, the keyframe pipeline, update fan-out, persistence.

Threading model: the event loop only moves bytes. Decoding and mapping run in a shared
thread pool; each session maps one keyframe at a time (`_map_lock`), and readers of the map
(queries, object lists, delta building) take the same lock, so they see whole keyframes.
If keyframes arrive faster than a session maps them, only the newest waits: an older
waiting keyframe is acknowledged as dropped (frames are samples, not a log).
"""

from __future__ import annotations

import asyncio
import hashlib
import hmac
import secrets
import threading
import time
import uuid
from collections import deque
from collections.abc import Awaitable, Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import TypeVar

import numpy as np

from app.config import Knobs, knobs_to_dict, updated_knobs
from app.errors import InputError
from app.mapping.deltas import DeltaLog
from app.mapping.engine import IntegrationStats, MappingEngine, QueryHit
from app.mapping.object import MapObject
from app.mapping.publish import update_message
from app.perception import DEFAULT_BACKEND, BackendOptions, UnknownBackendError, make_backend
from app.perception.base import FrameDetections, PerceptionBackend
from app.protocol import Ack, ErrorReply, FrameInput
from app.semantics import TextEncoder
from app.server.metrics import Metrics
from app.server.settings import ServerSettings
from app.store import SessionRecord, Store

Reply = Callable[[dict], Awaitable[None]]
FLUSH_AFTER_S = 1.0
"""Longest a confirmed change waits for its publication when keyframes stop coming."""


T = TypeVar("T")


def hash_token(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


@dataclass
class _Pending:
    frame: FrameInput
    sent: FrameDetections | None
    """The detections the device sent, as validated (the backend's `sent`)."""
    reply: Reply
    received_t: float
    decode_ms: float
    """Time the frame took to decode and validate (part of its mapping latency)."""


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
        return token is not None and hmac.compare_digest(hash_token(token), self.record.token_hash)

    # ------------------------------------------------------------------ reading
    def stats(self) -> dict:
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
        return {
            "session_id": self.id,
            "name": self.record.name,
            "mode": self.engine.mode,
            "perception": self.record.perception,
            "created_at": self.record.created_at,
            "frames": self.record.frames,
            "keyframes": self.engine.keyframes,
            "dropped_frames": self.dropped,
            "objects": confirmed,
            "fps": fps,
            "bytes_in": dict(self.bytes_in, total=sum(self.bytes_in.values())),
            "bytes_out": dict(self.bytes_out, total=sum(self.bytes_out.values())),
            "mapping_latency_ms": {
                "p50": float(np.percentile(lat, 50)) if lat is not None else None,
                "p95": float(np.percentile(lat, 95)) if lat is not None else None,
            },
            "update_seq": seq,
            "subscribers": self.subscribers,
            "embedding": {"model": self.engine.encoder.model_id, "dim": self.engine.encoder.dim},
            "knobs": knobs_to_dict(self.knobs),
        }

    def objects(self) -> list[MapObject]:
        with self._map_lock:
            return self.engine.confirmed_objects()

    def query(self, text: str, k: int) -> list[QueryHit]:
        embedding = self.engine.encoder.encode_query(text)  # outside the lock: the slow part
        with self._map_lock:
            return self.engine.query_embedding(embedding, k)

    def build_delta(self, since: int | None) -> dict:
        """The update message for a subscriber whose last applied seq is `since`."""
        with self._map_lock:
            return update_message(self.engine, since)

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
        self._closed = True
        self._publish()


class SessionManager:
    """All sessions of a server, their persistence and their keyframe pipelines."""

    def __init__(
        self, settings: ServerSettings, store: Store, encoder: TextEncoder, metrics: Metrics
    ):
        self.settings = settings
        self.store = store
        self.encoder = encoder
        self.metrics = metrics
        self.pool = ThreadPoolExecutor(
            max_workers=settings.mapping_workers, thread_name_prefix="map"
        )
        self.sessions: dict[str, Session] = {}
        self._lock = threading.Lock()
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
        return MappingEngine(encoder, knobs, mode=rec.mode, backend=backend)

    def restore(self) -> int:
        """Load every persisted session with its confirmed objects; returns how many.

        A stored log with more than max_tombstones (a smaller setting, or a database from
        before tombstones were trimmed) is trimmed now, in memory and in the store."""
        for rec in self.store.list_sessions():
            stored = self.store.load_delta_log(rec.session_id)
            log = DeltaLog.from_state(stored.state(), self.settings.max_tombstones)
            if log.floor > stored.floor:
                self.store.trim_tombstones(rec.session_id, log.floor)
            # A backend only restored sessions use is loaded too (at start, like the others).
            engine = self._engine(rec, updated_knobs(Knobs(), rec.knobs))
            engine.restore(
                self.store.load_objects(rec.session_id), log, rec.keyframes, rec.next_object_id
            )
            self.sessions[rec.session_id] = Session(rec, engine, _stored_floor=log.floor)
        return len(self.sessions)

    def close(self) -> None:
        for session in self.sessions.values():
            session.close()
        self.pool.shutdown(wait=True, cancel_futures=True)

    # ------------------------------------------------------------------ lifecycle
    def create(
        self, name: str | None, mode: str, knob_changes: dict, perception: str | None = None
    ) -> tuple[Session, str]:
        """A new session and its token (the only time the token is shown).

        perception: one of the backends loaded at start (default: the first the server's
        `perception` setting names); UnknownBackendError naming --perception otherwise."""
        knobs = updated_knobs(Knobs(), knob_changes or {})
        perception = perception or self.settings.perception_backends[0]
        if perception not in self.backends:
            raise UnknownBackendError(
                f"perception {perception!r} is not loaded on this server; choose one of "
                f"{', '.join(self.backends)} (a server loads backends with --perception)"
            )
        with self._lock:
            if len(self.sessions) >= self.settings.max_sessions:
                raise OverflowError(
                    f"the server holds its maximum of {self.settings.max_sessions} sessions"
                )
            token = secrets.token_urlsafe(24)
            sid = uuid.uuid4().hex[:16]
            rec = SessionRecord(
                session_id=sid,
                name=name or f"session-{sid[:6]}",
                mode=mode,
                knobs=knobs_to_dict(knobs),
                token_hash=hash_token(token),
                created_at=time.time(),
                perception=perception,
            )
            self.store.create_session(rec)
            engine = self._engine(rec, knobs)
            engine.restore([], DeltaLog(max_tombstones=self.settings.max_tombstones), 0, 1)
            session = Session(rec, engine)
            self.sessions[sid] = session
        return session, token

    def delete(self, sid: str) -> None:
        with self._lock:
            session = self.sessions.pop(sid)
        session.close()
        with session._map_lock:  # let a keyframe in flight finish first
            self.store.delete_session(sid)

    def set_knobs(self, session: Session, changes: dict) -> Knobs:
        with session._map_lock:
            knobs = updated_knobs(session.knobs, changes)
            self.store.update_session(session.id, knobs=knobs_to_dict(knobs))
            session.engine.knobs = knobs
            session.record.knobs = knobs_to_dict(knobs)
        return knobs

    # ------------------------------------------------------------------ ingest
    async def decode(self, decode: Callable[[], T]) -> T:
        """Run a frame's decoding and validation in the worker pool."""
        return await asyncio.get_running_loop().run_in_executor(self.pool, decode)

    def count_frame(self, session: Session, frame_bytes: dict[str, int]) -> bool:
        """Count a valid frame; True when it is a keyframe."""
        rec = session.record
        rec.frames += 1
        session._fps_window.append(time.monotonic())
        for kind, n in frame_bytes.items():
            session.bytes_in[kind] = session.bytes_in.get(kind, 0) + n
            self.metrics.inc("semanticxr_bytes_in_total", n, kind=kind)
        return (rec.frames - 1) % session.knobs.keyframe_interval == 0

    async def submit_keyframe(
        self,
        session: Session,
        frame: FrameInput,
        reply: Reply,
        sent: FrameDetections | None = None,
        decode_ms: float = 0.0,
    ) -> None:
        """Map now, or wait as the newest keyframe (acknowledging any older one as dropped).

        frame: validated (`MappingEngine.validate_frame`), which returned `sent`;
        decode_ms: what decoding and validating it took."""
        pending = _Pending(frame, sent, reply, time.perf_counter(), decode_ms)
        if session._mapping:
            older, session._pending = session._pending, pending
            if older is not None:
                session.dropped += 1
                self.metrics.inc("semanticxr_dropped_frames_total")
                await older.reply(Ack(older.frame.seq, keyframe=False, dropped=True).pack())
            return
        session._mapping = True
        asyncio.create_task(self._map_loop(session, pending))

    async def _map_loop(self, session: Session, pending: _Pending | None) -> None:
        loop = asyncio.get_running_loop()
        try:
            while pending is not None and not session.closed:
                try:
                    stats, latency_ms = await loop.run_in_executor(
                        self.pool, self._map_and_persist, session, pending
                    )
                except InputError as exc:
                    await pending.reply(ErrorReply(pending.frame.seq, "bad_frame", str(exc)).pack())
                except Exception as exc:  # never lose the ack: report and go on
                    await pending.reply(
                        ErrorReply(pending.frame.seq, "internal", f"mapping failed: {exc}").pack()
                    )
                else:
                    map_ms = (time.perf_counter() - pending.received_t) * 1e3
                    session.latencies_ms.append(latency_ms)
                    self.metrics.observe_ms("semanticxr_mapping_latency_ms", latency_ms)
                    await pending.reply(
                        Ack(
                            pending.frame.seq,
                            keyframe=True,
                            map_ms=map_ms,
                            update_seq=stats.seq,
                            objects=stats.confirmed,
                        ).pack()
                    )
                    session.after_keyframe(stats.keyframe)
                pending, session._pending = session._pending, None
        finally:
            session._mapping = False

    def _map_and_persist(
        self, session: Session, pending: _Pending
    ) -> tuple[IntegrationStats, float]:
        """In a worker thread: perceive and map the keyframe, then make the change durable
        before the ack. Returns the stats and the keyframe's mapping latency in ms (the one
        place it is measured: decode + perception + mapping + delta, see `Session.stats`)."""
        with session._map_lock:
            if session.closed:
                raise InputError("session", "the session was deleted")
            t_locked = time.perf_counter()  # waiting for a reader of the map is not mapping
            engine, frame = session.engine, pending.frame
            stats = engine.map_keyframe(frame, engine.perceive(frame, pending.sent))
            rec = session.record
            rec.keyframes = engine.keyframes
            rec.next_object_id = engine.next_object_id
            self.store.commit_keyframe(
                session.id,
                stats.seq,
                [engine.objects[i] for i in stats.published_ids],
                stats.removed_ids,
                counters={
                    "frames": rec.frames,
                    "keyframes": rec.keyframes,
                    "bytes_in": sum(session.bytes_in.values()),
                    "bytes_out": sum(session.bytes_out.values()),
                },
                next_object_id=engine.next_object_id,
            )
            if engine.log.floor > session._stored_floor:
                # The log forgot its oldest removals: no subscriber can be sent them any
                # more (it gets a full snapshot), so the store forgets them too.
                self.store.trim_tombstones(session.id, engine.log.floor)
                session._stored_floor = engine.log.floor
            latency_ms = pending.decode_ms + (time.perf_counter() - t_locked) * 1e3
            return stats, latency_ms
