"""The session manager: all sessions of a server."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

from app.mapping.engine import limit_numpy_threads
from app.perception import DEFAULT_BACKEND
from app.perception.base import FrameDetections, PerceptionBackend
from app.protocol import FrameBudget, FrameInput
from app.semantics import TextEncoder
from app.server.metrics import Metrics
from app.server.scheduler import RoundRobinScheduler
from app.server.sessions import storage
from app.server.sessions.claims import ClaimsMixin
from app.server.sessions.counters import CountersMixin
from app.server.sessions.engines import EnginesMixin
from app.server.sessions.lifecycle import LifecycleMixin
from app.server.sessions.loading import LoadingMixin
from app.server.sessions.pipeline import PipelineMixin
from app.server.sessions.residency import Residency
from app.server.sessions.retention import RetentionMixin
from app.server.sessions.session import Session
from app.server.sessions.storage import StorageHealth, StorageMixin
from app.server.settings import ServerSettings
from app.store import Store, StoreUnavailableError

log = logging.getLogger("semanticxr")


BUSY_RETRY_AFTER_S = 5
"""Retry-After (seconds) when every resident session is busy: no room to load another."""
STORAGE_RETRY_AFTER_S = 2
"""Retry-After (seconds) when the store cannot save the session that would make room."""
SOCKET_LOAD_WORKERS = 4
"""Threads that check sockets' access and load their sessions (off the event loop)."""


T = TypeVar("T")


class SessionManager(
    LoadingMixin,
    ClaimsMixin,
    RetentionMixin,
    LifecycleMixin,
    CountersMixin,
    StorageMixin,
    PipelineMixin,
    EnginesMixin,
):
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

    async def watch_storage(self) -> None:
        """Until cancelled, every STORAGE_PROBE_INTERVAL_S, in the store thread: the server's
        housekeeping (`housekeeping`). (Its name is older than the housekeeping it runs:
        the app starts it at start-up and cancels it at shutdown.)"""
        loop = self._loop = asyncio.get_running_loop()
        while True:
            await asyncio.sleep(storage.STORAGE_PROBE_INTERVAL_S)  # a timer, not synchronisation
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
