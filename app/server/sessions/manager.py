"""The session manager: the one object the routes talk to, a façade over the parts that keep
the sessions of a server (each in its own module of this package)."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

from app.config import Knobs
from app.mapping.engine import limit_numpy_threads
from app.mapping.object import Change, MapObject
from app.perception import DEFAULT_BACKEND
from app.perception.base import FrameDetections
from app.protocol import FrameBudget, FrameInput
from app.protocol.rest import MapExport, SessionSummary
from app.semantics import TextEncoder
from app.server.metrics import Metrics
from app.server.scheduler import RoundRobinScheduler
from app.server.sessions import storage as storage_module
from app.server.sessions.claims import Claims
from app.server.sessions.counters import Counters
from app.server.sessions.engines import Engines
from app.server.sessions.lane import Reply
from app.server.sessions.lifecycle import Lifecycle
from app.server.sessions.loading import Loader, list_stored, stored_record
from app.server.sessions.pipeline import KeyframePipeline
from app.server.sessions.residency import Residency
from app.server.sessions.retention import Retention
from app.server.sessions.session import Session
from app.server.sessions.storage import StorageWatch
from app.server.settings import ServerSettings
from app.store import SessionRecord, Store, StoreUnavailableError

log = logging.getLogger("semanticxr")


BUSY_RETRY_AFTER_S = 5
"""Retry-After (seconds) when every resident session is busy: no room to load another."""
SOCKET_LOAD_WORKERS = 4
"""Threads that check sockets' access and load their sessions (off the event loop)."""


T = TypeVar("T")


class SessionManager:
    """All sessions of a server, their persistence and their keyframe pipelines.

    The parts: `resident` (which maps are in memory) with its `loader`, `claims` (map
    shards), `counters`, `storage` (health of the store's writes), `engines` (perception
    backends and engines), `lifecycle` (create, import, export, delete), `retention` and
    `pipeline` (keyframes); the manager owns the thread pools and the housekeeping."""

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
        self.decode_pool = ThreadPoolExecutor(
            max_workers=settings.decode_workers,
            thread_name_prefix="decode",
            initializer=limit_numpy_threads,
        )
        """Frames are decoded apart from mapping: a slow keyframe never delays the acks of
        other frames, and a burst of frames never delays a keyframe's mapping."""
        self.frame_budget = FrameBudget(settings.max_frame_pixels, settings.max_instances_per_frame)
        """What a frame may cost, checked before its pixels are decoded."""
        self._store_io = ThreadPoolExecutor(max_workers=1, thread_name_prefix="store")
        """Counters-only writes, probes, idle unloading and retention: off the event loop,
        out of the mapping pool."""
        self._socket_pool = ThreadPoolExecutor(
            max_workers=SOCKET_LOAD_WORKERS, thread_name_prefix="load"
        )
        """Sockets' access checks and session loads (REST runs them in its own threads)."""
        self.storage = StorageWatch(store, metrics)
        # The loader is made below: it needs the claims and counters, which need `resident`.
        self.resident: Residency[Session] = Residency(
            settings.max_resident_sessions,
            lambda sid: self.loader.load(sid),
            lambda session, reason: self.loader.unload(session, reason),
            BUSY_RETRY_AFTER_S,
        )
        """The sessions whose maps are in memory; every session is in the store."""
        self.claims = Claims(settings, store, self.resident, metrics)
        self.counters = Counters(
            store, self.storage, self.resident, self.claims, metrics, self._store_io
        )
        self.engines = Engines(settings, encoder)
        self.loader = Loader(
            settings, store, self.engines, self.claims, self.counters, self.storage, metrics
        )
        self.lifecycle = Lifecycle(
            settings,
            store,
            self.engines,
            self.resident,
            self.claims,
            self.counters,
            metrics,
            release=self.release,
        )
        self.retention = Retention(settings, store, self.resident, self.lifecycle, metrics)
        self.pipeline = KeyframePipeline(
            settings,
            store,
            self.scheduler,
            self.engines,
            self.resident,
            self.claims,
            self.counters,
            self.storage,
            metrics,
        )

    @property
    def sessions(self) -> dict[str, Session]:
        """The resident sessions, by id (a snapshot; stored sessions: `list_sessions`)."""
        return self.resident.snapshot()

    def restore(self) -> int:
        """At start: delete the sessions past their retention (when it is set) and count the
        stored sessions; returns how many. Loads no map: each loads on its first use."""
        self.retention.apply()
        stored = self.store.count_sessions()
        self.metrics.sessions_stored.set(stored)
        if self.settings.shard_name is not None:
            self.claims.keep()  # gateways may route to this shard from now on
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
            self.counters.save(session, even_if_failing=True)
            self.claims.release(session)
        if self.settings.shard_name is not None:
            with contextlib.suppress(StoreUnavailableError):  # else its heartbeat goes stale
                self.store.forget_shard(self.settings.shard_name)

    # ------------------------------------------------------------------ resident or stored
    def record(self, sid: str) -> SessionRecord | None:
        """Session `sid`'s record (the resident one, else the stored row: no map is read);
        None when there is no such session."""
        return stored_record(self.resident, self.store, sid)

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
        self.counters.used(session)

    def list_sessions(self) -> list[SessionSummary]:
        """Every stored session, oldest first, as `GET /v1/sessions` lists it (`list_stored`)."""
        return list_stored(self.resident, self.store)

    # ------------------------------------------------------------------ lifecycle
    def create(
        self,
        name: str | None,
        mode: str,
        knob_changes: dict,
        perception: str | None = None,
        up: str | None = None,
        text_tower: str = "minilm",
    ) -> tuple[Session, str]:
        """A new session and its token, resident (`Lifecycle.create`)."""
        return self.lifecycle.create(name, mode, knob_changes, perception, up, text_tower)

    def import_session(self, export: MapExport) -> tuple[Session, str]:
        """A new session holding an export's objects and history (`Lifecycle.import_session`)."""
        return self.lifecycle.import_session(export)

    def export_contents(
        self, session: Session
    ) -> tuple[list[MapObject], list[MapObject], list[Change]]:
        """What a JSON export of `session` holds (`Lifecycle.export_contents`)."""
        return self.lifecycle.export_contents(session)

    def delete(self, sid: str) -> None:
        """Delete session `sid` with its map, resident or not (its sockets close)."""
        self.lifecycle.delete(sid)

    def set_knobs(self, session: Session, changes: dict) -> Knobs:
        return self.lifecycle.set_knobs(session, changes)

    # ------------------------------------------------------------------ the map's history
    def removed_objects(self, session: Session) -> list[MapObject]:
        """The session's removed objects (history, from the store), in id order."""
        return self.lifecycle.removed_objects(session)

    def find_object(self, session: Session, object_id: int) -> MapObject | None:
        """An object of the session's present map, else of its history; None if neither."""
        return self.lifecycle.find_object(session, object_id)

    def changes(self, session: Session, **filters) -> list[Change]:
        """The session's changes from the store (`Store.load_changes` filters)."""
        return self.lifecycle.changes(session, **filters)

    # ------------------------------------------------------------------ ingest
    async def in_thread(self, fn: Callable[..., T], *args: object) -> T:
        """`fn(*args)` in a socket thread (access checks and loads of sessions for sockets:
        the event loop only moves bytes)."""
        return await asyncio.get_running_loop().run_in_executor(self._socket_pool, fn, *args)

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

    def keyframe_next(self, session: Session) -> bool:
        """Whether the session's next valid frame is the shared selector's keyframe."""
        return self.counters.keyframe_next(session)

    def count_frame(
        self, session: Session, frame_bytes: dict[str, int], keyframe: bool | None = None
    ) -> bool:
        """Count a valid frame (or sighting); True when it is a keyframe (`Counters.count_frame`)."""
        return self.counters.count_frame(session, frame_bytes, keyframe)

    def save_counters_soon(self, session: Session) -> None:
        """Save the session's counters in the background (e.g. when its stream ends)."""
        self.counters.save_soon(session)

    async def submit_keyframe(
        self,
        session: Session,
        frame: FrameInput,
        reply: Reply,
        sent: FrameDetections | None = None,
        decode_ms: float = 0.0,
        stream: str | None = None,
    ) -> None:
        """Hand a validated keyframe to the keyframe pipeline (`KeyframePipeline.submit`)."""
        await self.pipeline.submit(session, frame, reply, sent, decode_ms, stream)

    async def settle(self, session: Session) -> None:
        """A stream of `session` closed: settle its map (`KeyframePipeline.settle`)."""
        await self.pipeline.settle(session)

    # ------------------------------------------------------------------ housekeeping
    async def watch_storage(self) -> None:
        """Until cancelled, every STORAGE_PROBE_INTERVAL_S, in the store thread: the server's
        housekeeping (`housekeeping`). (Its name is older than the housekeeping it runs:
        the app starts it at start-up and cancels it at shutdown.)"""
        loop = self.claims.loop = asyncio.get_running_loop()
        while True:
            # a timer, not synchronisation
            await asyncio.sleep(storage_module.STORAGE_PROBE_INTERVAL_S)
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
            self.claims.keep()
        except StoreUnavailableError as exc:
            self.storage.write_failed("renewing this shard's claims on its sessions", exc)
        if self.storage.failing:
            self.storage.probe()
            return
        self.resident.unload_idle(self.settings.idle_unload_s)
        if self.retention.due():
            self.retention.apply()
