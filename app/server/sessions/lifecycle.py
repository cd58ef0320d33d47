"""Lifecycle: creating, importing, exporting and deleting sessions; changing their knobs;
reading their history."""

from __future__ import annotations

import itertools
import secrets
import time
import uuid
from collections.abc import Callable

import numpy as np

from app.config import Knobs, knobs_to_dict, updated_knobs
from app.errors import InputError
from app.mapping.deltas import DeltaLog
from app.mapping.export import imported_object, imported_stay
from app.mapping.object import Change, MapObject
from app.mapping.validation import MAX_WORLD_M
from app.perception import UnknownBackendError
from app.protocol.rest import UP_AXES, MapExport
from app.server.metrics import Metrics
from app.server.sessions.claims import Claims
from app.server.sessions.counters import Counters
from app.server.sessions.engines import Engines
from app.server.sessions.residency import Residency
from app.server.sessions.session import Session, hash_token
from app.server.settings import ServerSettings
from app.store import KeyframeCommit, SessionRecord, Store, StoredSessionsLimit


class StoredSessionsFull(RuntimeError):
    """The store holds max_sessions sessions: no session can be created or imported until
    some are deleted. Permanent until then, so not a 503 (which says "retry later")."""


class Lifecycle:
    """Sessions created (resident at once), imported from an export, exported and deleted;
    their knobs changed. `release` ends a use of a session (the manager's)."""

    def __init__(
        self,
        settings: ServerSettings,
        store: Store,
        engines: Engines,
        resident: Residency[Session],
        claims: Claims,
        counters: Counters,
        metrics: Metrics,
        release: Callable[[Session], None],
    ):
        self.settings = settings
        self.store = store
        self.engines = engines
        self.resident = resident
        self.claims = claims
        self.counters = counters
        self.metrics = metrics
        self.release = release

    def create(
        self,
        name: str | None,
        mode: str,
        knob_changes: dict,
        perception: str | None = None,
        up: str | None = None,
        text_tower: str = "minilm",
    ) -> tuple[Session, str]:
        """A new session and its token (the only time the token is shown), resident.

        perception: one of the backends loaded at start (default: the first the server's
        `perception` setting names); UnknownBackendError naming --perception otherwise.
        up: the world axis that is up ("+x", "-x", "+y", "-y", "+z", "-z"; InputError naming
        `up` otherwise); None: inferred from the poses (`Session.up_axis`).
        text_tower: "minilm" or "static" (InputError naming `text_tower` otherwise, and for
        static on a backend with its own text tower); a static session embeds with the
        server's static tower (`Engines.tower_of_new_session`: the first one waits for its
        distillation) and keeps that tower's hash for good.
        Raises StoredSessionsFull past max_sessions stored, and as `acquire` does when the
        resident budget has no room."""
        session, token = self._create(
            name, mode, knob_changes, perception, up, text_tower=text_tower
        )
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
        text_tower: str = "minilm",
    ) -> tuple[Session, str]:
        """`create`, the session left in use (release it); `up_source`: where a given `up`
        came from ("set", or "inferred" by the session an import comes from)."""
        if up is not None and up not in UP_AXES:
            raise InputError("up", f"must be one of {', '.join(UP_AXES)}; got {up!r}")
        knobs = updated_knobs(Knobs(), knob_changes or {})
        perception = perception or self.settings.perception_backends[0]
        if perception not in self.engines.backends:
            raise UnknownBackendError(
                f"perception {perception!r} is not loaded on this server; choose one of "
                f"{', '.join(self.engines.backends)} (a server loads backends with --perception)"
            )
        self._check_room_to_store()  # before making room in memory (or a tower) for nothing
        tower_sha256 = self.engines.tower_of_new_session(text_tower, perception)
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
            text_tower=text_tower,
            tower_sha256=tower_sha256,
        )

        def make() -> Session:
            try:  # the count and the insert in one transaction: never two in the last place
                self.store.create_session(rec, max_sessions=self.settings.max_sessions)
            except StoredSessionsLimit:
                self._check_room_to_store()  # raises StoredSessionsFull with the fix
                raise
            engine = self.engines.engine(rec, knobs)
            engine.restore([], DeltaLog(max_tombstones=self.settings.max_tombstones), 0, 1)
            return Session(rec, engine, epoch=self.claims.claim(sid))

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
        perception = spec.perception if spec.perception in self.engines.backends else None
        session, token = self._create(
            spec.name,
            spec.mode,
            spec.knobs,
            perception,
            spec.up,
            spec.up_source or "set",
            text_tower=spec.text_tower or "minilm",
        )
        try:
            engine = session.engine
            exported = spec.embedding.sha256
            embedded = any(o.embedding for o in [*export.objects, *removed_records])
            if embedded and exported is not None and exported != session.record.tower_sha256:
                raise InputError(
                    "session.embedding.sha256",
                    f"the export was embedded with the static text tower {exported}, but this "
                    f"server's static tower is {session.record.tower_sha256}; start it with "
                    f"--static-tower FILE holding that tower to import it",
                )
            if spec.embedding.dim != engine.encoder.dim:
                raise InputError(
                    "session.embedding.dim",
                    f"{spec.embedding.dim}, but this server embeds with {engine.encoder.model_id} "
                    f"({engine.encoder.dim} dimensions)",
                )
            records = [*export.objects, *removed_records]
            without = [o.label for o in records if o.embedding is None]
            by_label = dict(zip(without, engine.encoder.encode_labels(without), strict=True))
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
            with session.lane.lock:
                counters = session.counters()
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
        with session.lane.lock:
            return (
                session.engine.confirmed_objects(),
                self.store.load_removed_objects(session.id),
                self.store.load_changes(session.id),
            )

    def delete(self, sid: str) -> None:
        """Delete session `sid` with its map, resident or not (its sockets close)."""
        self.resident.remove(sid, lambda session: self.remove(sid, session))
        self.metrics.sessions_stored.set(self.store.count_sessions())

    def remove(self, sid: str, session: Session | None) -> bool:
        """`Residency.remove`'s deleter: session `sid` out of the store, after its resident
        copy `session` (None if not resident) is closed and a keyframe in flight ended."""
        if session is None:
            self.store.delete_session(sid)
            return True
        session.close()
        with session.lane.lock:  # let a keyframe in flight finish first
            self.store.delete_session(sid)
        self.counters.forget(sid)
        return True

    def set_knobs(self, session: Session, changes: dict) -> Knobs:
        with session.lane.lock:
            knobs = updated_knobs(session.knobs, changes)
            self.store.update_session(session.id, knobs=knobs_to_dict(knobs), epoch=session.epoch)
            session.engine.knobs = knobs
            session.record.knobs = knobs_to_dict(knobs)
        return knobs

    # ------------------------------------------------------------------ the map's history
    def removed_objects(self, session: Session) -> list[MapObject]:
        """The session's removed objects (history, from the store), in id order."""
        return self.store.load_removed_objects(session.id)

    def find_object(self, session: Session, object_id: int) -> MapObject | None:
        """An object of the session's present map, else of its history; None if neither."""
        with session.lane.lock:
            obj = session.engine.objects.get(object_id)
            if obj is not None and obj.confirmed:
                return obj
        return self.store.load_object(session.id, object_id)

    def changes(self, session: Session, **filters) -> list[Change]:
        """The session's changes from the store (`Store.load_changes` filters)."""
        return self.store.load_changes(session.id, **filters)


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
