"""A session: its state (the record, the engine, counters, subscribers) and the questions it
answers (statistics, objects, queries, relational queries, deltas); its sightings and its
publications."""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import hmac
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from app.answering.ask import ask, relational_reading
from app.answering.label_knowledge import SERVED_LABEL_TEXTS, served_texts
from app.answering.relevance import Rating, rate_hits
from app.answering.rerank import RERANK_POOL, rerank
from app.answering.things import MapThing, RelationalHit
from app.config import Knobs, knobs_to_dict
from app.mapping.engine import MappingEngine, QueryHit
from app.mapping.held import held_points
from app.mapping.object import MapObject
from app.mapping.places import DEFAULT_UP, UpInference, up_vector
from app.mapping.publish import client_points, update_message
from app.perception.base import FrameDetections
from app.protocol import FrameInput
from app.protocol.frame import FRAME_PARTS
from app.protocol.rest import UPDATES_BYTES, EmbeddingInfo, LatencySummary, SessionStats
from app.relations.index import ObjectGeometry, RelationIndex
from app.semantics import TextEncoder
from app.server.sessions.lane import KeyframeLane
from app.store import SessionRecord

log = logging.getLogger("semanticxr")


FLUSH_AFTER_S = 1.0
"""Longest a confirmed change waits for its publication when keyframes stop coming."""
SIGHTINGS_WAITING = 8
"""Most non-keyframes a session holds for sighting while a keyframe is on its way or a reader
holds the map; beyond it the oldest is forgotten (frames are samples, not a log)."""


def hash_token(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


def token_matches(record: SessionRecord, token: str | None) -> bool:
    """Whether `token` is the session's own (compared in constant time)."""
    return token is not None and hmac.compare_digest(hash_token(token), record.token_hash)


@dataclass
class Session:
    record: SessionRecord
    engine: MappingEngine
    bytes_in: dict[str, int] = field(default_factory=lambda: dict.fromkeys(FRAME_PARTS, 0))
    bytes_out: dict[str, int] = field(default_factory=lambda: {UPDATES_BYTES: 0})
    dropped: int = 0
    latencies_ms: deque = field(default_factory=lambda: deque(maxlen=2000))
    subscribers: int = 0
    streams: int = 0
    """Frame stream sockets open, each until its close has settled and published the map."""
    lane: KeyframeLane = field(default_factory=KeyframeLane)
    """Its lane of the keyframe pipeline; readers of the map take `lane.lock`."""
    _published: asyncio.Event = field(default_factory=asyncio.Event)
    _published_seq: int = 0
    _flush_timer: asyncio.TimerHandle | None = None
    _closed: bool = False
    _fps_window: deque = field(default_factory=lambda: deque(maxlen=60))
    stored_floor: int = 0
    """The delta log floor the store holds (its tombstones at or below it are trimmed)."""
    warnings: list[str] = field(default_factory=list)
    """Problems worth a user's attention, each said once (in the log and in the stats)."""
    _relations: RelationIndex = field(default_factory=RelationIndex)
    """The relation index of the confirmed objects, synced by each relational query."""
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
        return self.users > 0 or self.lane.mapping

    def touch(self) -> None:
        """Note a use now (for idle unloading and for retention, which the store keeps)."""
        self.last_used = time.monotonic()
        self.record.last_used_at = time.time()

    @property
    def closed(self) -> bool:
        """True once the session is deleted (its sockets then close)."""
        return self._closed

    def mark_closed(self) -> None:
        """Closed off the event loop (its saved map could not be reloaded, or another shard
        took it over while no event loop runs): its sockets see `closed` and close, but
        nobody is woken (`close` does that, on the event loop)."""
        self._closed = True

    def count_frame(self, frame_bytes: dict[str, int], sighting: bool) -> float:
        """Count a valid frame received (in `record.frames`; a sighting also in
        `record.sightings`) and its bytes by kind, as a use of the session; returns when
        (time.monotonic())."""
        rec = self.record
        rec.frames += 1
        if sighting:
            rec.sightings += 1
        self.touch()
        now = time.monotonic()
        self._fps_window.append(now)
        for kind, n in frame_bytes.items():
            self.bytes_in[kind] = self.bytes_in.get(kind, 0) + n
        return now

    def counters(self, with_keyframes: bool = True) -> dict[str, int]:
        """The counters a store keeps (absolute values); keyframes only with the map."""
        rec = self.record
        counters = {
            "frames": rec.frames,
            "sightings": rec.sightings,
            "bytes_in": sum(self.bytes_in.values()),
            "bytes_out": sum(self.bytes_out.values()),
        }
        if with_keyframes:
            counters["keyframes"] = rec.keyframes
        return counters

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
        keyframe (docs/protocol.md, "REST"): decode + perception + mapping + delta (its
        commit to the delta log and the store), without the time it queued for a worker."""
        lat = np.asarray(self.latencies_ms) if self.latencies_ms else None
        with self.lane.lock:
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
            streams=self.streams,
            subscribers=self.subscribers,
            embedding=EmbeddingInfo(
                model=self.engine.encoder.model_id,
                dim=self.engine.encoder.dim,
                sha256=self.record.tower_sha256 if self.record.text_tower == "static" else None,
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
        with self.lane.lock:
            return self.engine.confirmed_objects()

    def query(self, text: str, k: int) -> list[QueryHit]:
        return self.rated_query(text, k)[0]

    def rated_query(
        self, text: str, k: int, removed: list[MapObject] | None = None
    ) -> tuple[list[QueryHit], Rating]:
        """The top-k hits, best first, and how well they answer (app.answering.relevance).

        removed: objects of the map's history (state "removed") ranked with the present
        ones (`include=removed`: "where did I leave my laptop")."""
        embedding = self.engine.encoder.encode_query(text)  # outside the lock: the slow part
        with self.lane.lock:
            hits = self.engine.query_embedding(embedding, k)
        if removed:
            scores = np.stack([o.embedding for o in removed]) @ embedding.astype(np.float32)
            hits = [*hits, *(QueryHit(o, float(s)) for o, s in zip(removed, scores, strict=True))]
            hits = sorted(hits, key=lambda h: -h.score)[:k]
        labels = [h.object.label for h in hits]
        return hits, rate_hits(self.engine.encoder, embedding, labels, SERVED_LABEL_TEXTS)

    def reranked_query(
        self, text: str, k: int, teacher: TextEncoder, removed: list[MapObject] | None = None
    ) -> tuple[list[QueryHit], Rating]:
        """`rated_query`'s best RERANK_POOL ranked again and rated by `teacher`, the tower
        the session's static tower was distilled from (app.answering.rerank); each hit's
        score is the teacher's cosine of the question with its label."""
        pool, _ = self.rated_query(text, max(k, RERANK_POOL), removed)
        got = rerank(teacher, text, [h.object.label for h in pool], k, SERVED_LABEL_TEXTS)
        hits = [
            QueryHit(pool[i].object, score) for i, score in zip(got.order, got.scores, strict=True)
        ]
        return hits, got.rating

    def relational_query(
        self,
        text: str,
        k: int,
        asker: np.ndarray | None = None,
        teacher: TextEncoder | None = None,
    ) -> tuple[list[RelationalHit], dict[int, MapObject]] | None:
        """The top-k hits of a question about how things stand ("the mug on the desk",
        app.answering.ask) and the objects they name by id; None for a question to answer
        as plain (`rated_query`). Up is the session's (`up`); the asker stands at `asker`
        (world metres), else at the camera of the newest device pose.

        The relation index is synced to the confirmed objects (id, version) first, each by
        exactly the points a device's local map holds (its client-capped points as the wire
        and the local map store them: `held_points`), so a relation's degree is the same on
        the server and on the device: only objects whose version changed get new bodies,
        and only their pairs are recomputed, when read; a new up axis starts it afresh.

        teacher: answer with this tower instead of the session's (`reranked_query`'s
        teacher): the objects are its embeddings of their labels."""
        reading = relational_reading(text)
        if reading is None:
            return None
        with self.lane.lock:
            objects = [(o, o.version) for o in self.engine.confirmed_objects()]
            pose = self.engine.last_pose
        up = self.up
        viewer = asker if asker is not None or pose is None else np.asarray(pose)[:3, 3]
        encoder = teacher or self.engine.encoder
        if teacher is None:
            things = [MapThing(o.id, o.label, o.embedding) for o, _ in objects]
        else:
            labels = [o.label for o, _ in objects]
            rows = teacher.encode_labels(labels) if labels else []
            things = [
                MapThing(o.id, o.label, row) for (o, _), row in zip(objects, rows, strict=True)
            ]
        max_points = self.knobs.max_object_points_client

        def held(o: MapObject) -> ObjectGeometry:
            return ObjectGeometry(o.label, held_points(client_points(o, max_points)))

        with self._relations_lock:  # the index computes pairs as it is read
            self._relations.sync(objects, up, held)
            hits = ask(
                reading,
                things,
                self._relations,
                encoder,
                viewer,
                k,
                SERVED_LABEL_TEXTS,
            )
        if hits is None:
            return None
        return hits, {o.id: o for o, _ in objects}

    def build_delta(self, since: int | None) -> dict:
        """The update message for a subscriber whose last applied seq is `since`."""
        with self.lane.lock:
            return update_message(self.engine, since, served_texts)

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
        if not self.lane.mapping and self.lane.lock.acquire(blocking=False):
            try:
                self.sight_waiting()
            finally:
                self.lane.lock.release()

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

    def rolled_back(self, seq: int) -> None:
        """The map went back to the store's state at update `seq` (a keyframe failed): a
        flush timer may have announced the rolled-back seq; the next one must go out."""
        self._published_seq = min(self._published_seq, seq)

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
