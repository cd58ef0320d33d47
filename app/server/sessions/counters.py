"""Counters: frames, sightings and bytes counted per session, and saved to the store."""

from __future__ import annotations

import contextlib
import math
import time
from concurrent.futures import ThreadPoolExecutor

from app.keyframes import is_keyframe
from app.perception import DEFAULT_BACKEND
from app.protocol.frame import DETECTIONS_FIELD
from app.server.metrics import Metrics
from app.server.sessions.claims import Claims
from app.server.sessions.residency import Residency
from app.server.sessions.session import Session
from app.server.sessions.storage import StorageWatch
from app.store import SessionFenced, Store, StoreUnavailableError

NO_DETECTIONS_WARNING = (
    "frames arrive without detections, and this session's perception backend (detections) "
    "maps only what the device detects: nothing will be mapped. Run the server with "
    "--perception models (its sessions then detect objects in the pixels), or stream from a "
    "device that sends detections."
)
COUNTERS_SAVE_INTERVAL_S = 1.0
"""Most frames counted but not saved: a counters-only write follows a frame when the
session's counters were last saved longer ago than this (kill -9 loses at most that)."""


LAST_USE_SAVE_INTERVAL_S = 60.0
"""Longest a session's last use (of requests only) waits to be saved while it stays resident."""


class Counters:
    """Frames, sightings and bytes counted per session (the session keeps them), and their
    saving: with each keyframe's commit, or in a counters-only write in the store thread
    when they were last saved more than COUNTERS_SAVE_INTERVAL_S ago (a request's last use:
    LAST_USE_SAVE_INTERVAL_S)."""

    def __init__(
        self,
        store: Store,
        storage: StorageWatch,
        resident: Residency[Session],
        claims: Claims,
        metrics: Metrics,
        store_io: ThreadPoolExecutor,
    ):
        self.store = store
        self.storage = storage
        self.resident = resident
        self.claims = claims
        self.metrics = metrics
        self.store_io = store_io
        """The store thread: counters-only writes run there, off the event loop."""
        self._saved_at: dict[str, float] = {}
        """Session id -> time.monotonic() of its counters' last save."""

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
        now = session.count_frame(frame_bytes, sighting=keyframe is False)
        if DETECTIONS_FIELD not in frame_bytes and session.engine.backend.name == DEFAULT_BACKEND:
            session.warn_once(NO_DETECTIONS_WARNING)
        for kind, n in frame_bytes.items():
            self.metrics.upstream_bytes.labels(kind=kind).inc(n)
        if now - self._saved_at.get(session.id, 0.0) >= COUNTERS_SAVE_INTERVAL_S:
            self.save_soon(session)
        if keyframe is not None:
            return keyframe
        return is_keyframe(session.record.frames - 1, session.knobs.keyframe_interval)

    def used(self, session: Session) -> None:
        """A use of `session` ended: its last use reaches the store within
        LAST_USE_SAVE_INTERVAL_S (frames and keyframes save it sooner)."""
        saved_at = self._saved_at.get(session.id, -math.inf)
        if time.monotonic() - saved_at >= LAST_USE_SAVE_INTERVAL_S:
            self.save_soon(session)

    def saved(self, sid: str) -> None:
        """Session `sid`'s counters were saved now (by a commit or a load)."""
        self._saved_at[sid] = time.monotonic()

    def forget(self, sid: str) -> None:
        """Session `sid` left memory (unloaded or deleted)."""
        self._saved_at.pop(sid, None)

    def save_soon(self, session: Session) -> None:
        """Save the session's counters in the background (e.g. when its stream ends)."""
        self._saved_at[session.id] = time.monotonic()
        with contextlib.suppress(RuntimeError):  # shutting down: close() saves them
            self.store_io.submit(self.save, session)

    def save(self, session: Session, even_if_failing: bool = False) -> None:
        """Write the session's frame and byte counters and its last use (not its map), if it
        is still the resident copy. Under the map lock, so
        a keyframe commit's counters and these land in the order they were taken. Skipped
        while the store refuses writes (unless `even_if_failing`): the next commit or save
        after it recovers carries them."""
        if self.storage.failing and not even_if_failing:
            return
        with session.lane.lock:
            if self.resident.get(session.id) is not session:
                return  # unloaded (which saved them) or deleted
            try:
                self.store.update_session(
                    session.id,
                    counters=session.counters(False),
                    last_used_at=session.record.last_used_at,
                    epoch=session.epoch,
                )
            except KeyError:
                return  # deleted meanwhile
            except SessionFenced:
                self.claims.drop_taken_over(session)
                return
            except StoreUnavailableError as exc:
                self.storage.write_failed("saving a session's counters", exc)
                return
            self._saved_at[session.id] = time.monotonic()
            self.storage.write_succeeded()
