"""Stored versus resident: loading a session's map on first use, unloading it when idle or
when the resident budget needs room, and listing stored sessions."""

from __future__ import annotations

import contextlib
import logging
import time

import numpy as np

from app.config import Knobs, updated_knobs
from app.mapping.deltas import DeltaLog
from app.mapping.engine import RECENT_CHANGES, MappingEngine
from app.mapping.places import DEFAULT_UP
from app.protocol.rest import SessionSummary
from app.server.metrics import Metrics
from app.server.sessions.claims import Claims
from app.server.sessions.counters import Counters
from app.server.sessions.engines import Engines
from app.server.sessions.residency import Residency
from app.server.sessions.session import Session
from app.server.sessions.storage import StorageWatch
from app.server.settings import ServerSettings
from app.store import SessionFenced, SessionRecord, Store, StoreUnavailableError

log = logging.getLogger("semanticxr")


class Loader:
    """`Residency`'s loader and unloader: a session's map read from the store on its first
    use (through the path a restart takes), and what only memory holds saved when it
    leaves memory."""

    def __init__(
        self,
        settings: ServerSettings,
        store: Store,
        engines: Engines,
        claims: Claims,
        counters: Counters,
        storage: StorageWatch,
        metrics: Metrics,
    ):
        self.settings = settings
        self.store = store
        self.engines = engines
        self.claims = claims
        self.counters = counters
        self.storage = storage
        self.metrics = metrics

    def restored(self, rec: SessionRecord) -> Session:
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
        engine = self.engines.engine(rec, updated_knobs(Knobs(), rec.knobs))
        self.restore_engine(engine, rec, log)
        return Session(rec, engine, stored_floor=floor)

    def restore_engine(self, engine: MappingEngine, rec: SessionRecord, log: DeltaLog) -> None:
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

    def load(self, sid: str) -> Session:
        """`Residency`'s loader (in the caller's thread): the stored session; KeyError if none."""
        t0 = time.perf_counter()
        epoch = self.claims.claim(sid)  # first: what loads next is final (older owners are fenced)
        session = self.restored(self.store.load_session(sid))
        session.epoch = epoch
        session.touch()
        # Retention counts from this use, even if the server is killed before the next save
        # (and while the store refuses writes, from the last use it holds).
        with contextlib.suppress(StoreUnavailableError):
            self.store.update_session(sid, last_used_at=session.record.last_used_at, epoch=epoch)
            self.counters.saved(sid)
        self.metrics.session_loads.inc()
        self.metrics.session_load_latency.observe(time.perf_counter() - t0)
        return session

    def unload(self, session: Session, reason: str) -> None:
        """`Residency`'s unloader: save what only memory holds (frame and byte counters, last
        use; the map and delta log are saved at every commit) and let the session go.
        StoreUnavailableError (it stays resident) when the store refuses the write."""
        with session.lane.lock:  # after a counters save in flight, never before it
            try:
                self.store.update_session(
                    session.id,
                    counters=session.counters(False),
                    last_used_at=session.record.last_used_at,
                    epoch=session.epoch,
                )
            except (KeyError, SessionFenced):
                pass  # deleted or taken over meanwhile: nothing left to save here
            except StoreUnavailableError as exc:
                self.storage.write_failed(f"saving session {session.id} to unload it", exc)
                raise
            else:
                self.storage.write_succeeded()
        self.claims.release(session)
        self.counters.forget(session.id)
        self.metrics.session_unloads.labels(reason=reason).inc()
        log.info(
            "session %s unloaded from memory (%s); it loads again on its next use",
            session.id,
            "unused for --idle-unload-s" if reason == "idle" else "room for another",
        )


def stored_record(resident: Residency[Session], store: Store, sid: str) -> SessionRecord | None:
    """Session `sid`'s record (the resident one, else the stored row: no map is read);
    None when there is no such session."""
    session = resident.get(sid)
    if session is not None:
        return session.record
    try:
        return store.load_session(sid)
    except KeyError:
        return None


def list_stored(resident: Residency[Session], store: Store) -> list[SessionSummary]:
    """Every stored session, oldest first, as `GET /v1/sessions` lists it: a resident one
    with its live figures, the others from their stored rows (no map is loaded);
    `resident` says which."""
    listed = []
    for entry in store.list_stored():
        rec = entry.record
        session = resident.get(rec.session_id)
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
