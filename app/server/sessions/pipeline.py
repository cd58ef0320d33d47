"""The keyframe pipeline: each keyframe waits for its session's turn of a mapping worker, is
mapped and committed in one hold of the map lock, and is acknowledged."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from typing import NamedTuple

import msgpack
import numpy as np

from app.errors import InputError
from app.mapping.deltas import DeltaLog
from app.mapping.engine import RECENT_CHANGES
from app.mapping.stats import IntegrationStats
from app.perception.base import FrameDetections
from app.protocol import Ack, ErrorReply, FrameInput
from app.server.metrics import Metrics
from app.server.scheduler import RoundRobinScheduler
from app.server.sessions.claims import Claims, SessionMoved
from app.server.sessions.counters import Counters
from app.server.sessions.engines import Engines
from app.server.sessions.lane import PendingKeyframe, Reply
from app.server.sessions.residency import Residency
from app.server.sessions.session import Session
from app.server.sessions.storage import StorageHealth, StorageUnavailable, StorageWatch
from app.server.settings import ServerSettings
from app.store import KeyframeCommit, SessionFenced, Store, StoreUnavailableError

log = logging.getLogger("semanticxr")


STORAGE_UNAVAILABLE_MESSAGE = (
    "the server cannot save the map now (storage unavailable), so it did not map this "
    "keyframe; the map so far is safe and queries still work; retry later"
)


class PersistFailed(RuntimeError):
    """A keyframe mapped but not saved for a reason other than the storage (a bug); the map
    was put back to its durable state."""


class _Mapped(NamedTuple):
    ack: Ack
    keyframe: int | None
    """The session's keyframe count after it (None: answered from the store, not mapped)."""
    latency_ms: float


class KeyframePipeline:
    """Keyframes mapped, committed and acknowledged: each waits in its session's lane
    (`KeyframeLane`) for the session's turn of a mapping worker (`RoundRobinScheduler`),
    then maps and commits in one hold of the lane's map lock."""

    def __init__(
        self,
        settings: ServerSettings,
        store: Store,
        scheduler: RoundRobinScheduler,
        engines: Engines,
        resident: Residency[Session],
        claims: Claims,
        counters: Counters,
        storage: StorageWatch,
        metrics: Metrics,
    ):
        self.settings = settings
        self.store = store
        self.scheduler = scheduler
        self.engines = engines
        self.resident = resident
        self.claims = claims
        self.counters = counters
        self.storage = storage
        self.metrics = metrics
        self._tasks: set[asyncio.Task] = set()
        """The map loops running (a task nobody references may be collected mid-way)."""

    async def submit(
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
        pending = PendingKeyframe(frame, sent, reply, time.perf_counter(), decode_ms, stream)
        if session.lane.mapping:
            older, session.lane.pending = session.lane.pending, pending
            if older is not None:
                await self._drop(session, older)
            return
        session.lane.mapping = True
        task = asyncio.create_task(self._map_loop(session, pending))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _drop(self, session: Session, older: PendingKeyframe) -> None:
        session.dropped += 1
        self.metrics.dropped_frames.inc()
        await older.reply(Ack(older.frame.seq, keyframe=False, dropped=True).pack())

    @staticmethod
    def _newest(
        session: Session, pending: PendingKeyframe
    ) -> tuple[PendingKeyframe, PendingKeyframe | None]:
        """The keyframe to map once the session's turn comes, and the one it replaces: a
        newer keyframe that arrived while `pending` waited is mapped instead (frames are
        samples: the freshest view is mapped; the stale one is acknowledged as dropped)."""
        newer, session.lane.pending = session.lane.pending, None
        return (pending, None) if newer is None else (newer, pending)

    async def _map_loop(self, session: Session, pending: PendingKeyframe | None) -> None:
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
                pending, session.lane.pending = session.lane.pending, None
        finally:
            session.lane.mapping = False

    def _map_and_persist(self, session: Session, pending: PendingKeyframe) -> _Mapped:
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
        with session.lane.lock:
            if session.moved:
                raise SessionMoved(SessionMoved.MESSAGE)
            if session.closed:
                raise InputError("session", "the session was deleted")
            if not self.storage.probe():
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
                ack = Ack(
                    frame.seq,
                    keyframe=True,
                    update_seq=stats.seq,
                    objects=stats.confirmed,
                    doubted=engine.changes.doubted_places().tolist()
                    if engine.knobs.negative_evidence
                    else None,
                )
                self.store.commit_keyframe(
                    _map_commit(
                        session,
                        stats,
                        retired=stats.retired,
                        changes=stats.changes,
                        retracted_removed=stats.retracted_removed,
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
                # its engine holds unsaved changes: the session is dropped here
                self.claims.drop_taken_over(session, close=False)
                raise SessionMoved(SessionMoved.MESSAGE) from None
            except BaseException as exc:
                self._back_to_durable(session, pose_before)
                if not committing:
                    raise
                if isinstance(exc, StoreUnavailableError):
                    self.storage.write_failed(
                        f"saving keyframe {frame.seq} of session {session.id}", exc
                    )
                    raise StorageUnavailable(StorageHealth.REASON) from exc
                self.metrics.persist_failures.inc()
                log.error(
                    "session %s: saving keyframe %s failed; its changes were undone",
                    session.id,
                    frame.seq,
                    exc_info=exc,
                )
                raise PersistFailed(f"saving the keyframe failed: {exc}") from exc
            self.counters.saved(session.id)
            self.storage.write_succeeded()
            if engine.log.floor > session.stored_floor:
                # The log forgot its oldest removals: no subscriber can be sent them any
                # more (it gets a full snapshot), so the store forgets them too.
                try:
                    self.store.trim_tombstones(session.id, engine.log.floor, epoch=session.epoch)
                    session.stored_floor = engine.log.floor
                except SessionFenced:
                    self.claims.drop_taken_over(session, close=False)  # saved: its ack stands
                except StoreUnavailableError as exc:  # the keyframe is saved: retried next time
                    self.storage.write_failed(
                        f"trimming the tombstones of session {session.id}", exc
                    )
            latency_ms = pending.decode_ms + (time.perf_counter() - t_locked) * 1e3
            return _Mapped(ack, stats.keyframe, latency_ms)

    async def settle(self, session: Session) -> None:
        """Once a stream has closed: settle the session's map (`MappingEngine.settle`: the
        strays clean-up had not yet visited leave, duplicates merge), commit what changed
        and publish it. In a worker thread under the map lock, after any keyframe in flight;
        a failed commit puts the engine back to the store's state, as for a keyframe."""
        with contextlib.suppress(RuntimeError):  # no loop or executor: the server is stopping
            await asyncio.to_thread(self._settle_and_persist, session)
            session.flush()

    def _settle_and_persist(self, session: Session) -> None:
        with session.lane.lock:
            if session.moved or session.closed or not self.storage.probe():
                return
            engine = session.engine
            pose = engine.last_pose
            try:
                stats = engine.settle()
                if not stats.published_ids and not stats.removed_ids:
                    return
                self.store.commit_keyframe(_map_commit(session, stats))
            except SessionFenced:
                self.claims.drop_taken_over(session, close=False)
            except Exception:
                log.exception("session %s: settling its map failed; undone", session.id)
                self._back_to_durable(session, pose)
            else:
                self.counters.saved(session.id)

    def _done_ack(self, session: Session, pending: PendingKeyframe) -> Ack | None:
        """The ack of a keyframe committed before under the same (stream, seq), if the store
        remembers one (`DONE_WINDOW` per session); raises StorageUnavailable if it cannot say."""
        if pending.stream is None:
            return None
        try:
            record = self.store.done_ack(session.id, pending.stream, pending.frame.seq)
        except StoreUnavailableError as exc:
            self.storage.write_failed(f"reading the acks of session {session.id}", exc)
            raise StorageUnavailable(StorageHealth.REASON) from exc
        if record is None:
            return None
        fields = msgpack.unpackb(record)
        return Ack(pending.frame.seq, keyframe=True, **fields)

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
            session.mark_closed()  # under the map lock; sockets see it and close
            return
        engine = self.engines.engine(session.record, old.knobs)
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
        session.stored_floor = stored.floor
        session.rolled_back(delta_log.seq)


def _map_commit(session: Session, stats: IntegrationStats, **more) -> KeyframeCommit:
    """The store commit of what a keyframe or a settle changed in the session's map: the
    published objects, the removed ids, the counters and the engine's state; `more`: the
    keyframe's own fields (its ack, retirements, changes, up)."""
    engine = session.engine
    return KeyframeCommit(
        session.id,
        stats.seq,
        [engine.objects[i] for i in stats.published_ids],
        stats.removed_ids,
        counters=session.counters(),
        next_object_id=engine.next_object_id,
        last_used_at=session.record.last_used_at,
        retracted_added=stats.retracted_added,
        last_t=engine.last_t,
        last_pose=engine.last_pose,
        epoch=session.epoch,
        **more,
    )


def _ack_record(ack: Ack) -> bytes:
    """What the store keeps of a committed keyframe's ack, to answer a resend of it."""
    return msgpack.packb({"update_seq": ack.update_seq, "objects": ack.objects})
