"""Counters: frames, sightings and bytes counted per session, and saved to the store."""

from __future__ import annotations

import contextlib
import time

from app.keyframes import is_keyframe
from app.perception import DEFAULT_BACKEND
from app.server.sessions.session import Session
from app.store import SessionFenced, StoreUnavailableError

NO_DETECTIONS_WARNING = (
    "frames arrive without detections, and this session's perception backend (detections) "
    "maps only what the device detects: nothing will be mapped. Run the server with "
    "--perception models (its sessions then detect objects in the pixels), or stream from a "
    "device that sends detections."
)
COUNTERS_SAVE_INTERVAL_S = 1.0
"""Most frames counted but not saved: a counters-only write follows a frame when the
session's counters were last saved longer ago than this (kill -9 loses at most that)."""


class CountersMixin:
    """Counting frames and saving the counters."""

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
