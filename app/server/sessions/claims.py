"""Claims on sessions (map shards): each write is conditional on this shard's epoch."""

from __future__ import annotations

import asyncio
import contextlib
import logging

from app.server.metrics import Metrics
from app.server.sessions.residency import Residency
from app.server.sessions.session import Session
from app.server.settings import ServerSettings
from app.store import Store, StoreUnavailableError

log = logging.getLogger("semanticxr")


class SessionMoved(RuntimeError):
    """This map shard lost its claim on a session (another shard claimed it: this one hung or
    was cut off for longer than its lease). The session is dropped here, unsaved changes
    included; the gateway sends its frames to the new owner."""

    MESSAGE = (
        "this map shard no longer holds the session (another shard took it over); the "
        "keyframe was not mapped here: reconnect (a gateway does so by itself) and resend it"
    )


class Claims:
    """On a map shard: this shard's claims on the sessions it holds, in the store (their
    epochs fence any earlier owner's writes), renewed every second; the sessions another
    shard took are dropped here. A standalone server (no shard name) claims nothing."""

    def __init__(
        self, settings: ServerSettings, store: Store, resident: Residency[Session], metrics: Metrics
    ):
        self.settings = settings
        self.store = store
        self.resident = resident
        self.metrics = metrics
        self.loop: asyncio.AbstractEventLoop | None = None
        """The server's event loop (set when housekeeping starts): sessions another shard
        took over are closed on it."""

    def claim(self, sid: str) -> int | None:
        """On a map shard: claim session `sid` in the store (its epoch), fencing any earlier
        owner's writes; SessionHeld when a live shard holds it. None on a standalone server."""
        name = self.settings.shard_name
        if name is None:
            return None
        return self.store.claim_session(sid, name, self.settings.shard_lease_s)

    def release(self, session: Session) -> None:
        """Let another shard take `session` at once (it was saved and unloaded here)."""
        if session.epoch is not None:
            with contextlib.suppress(StoreUnavailableError):  # then its lease runs out
                self.store.release_session(session.id, self.settings.shard_name, session.epoch)

    def drop_taken_over(self, session: Session, close: bool = True) -> None:
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
        if self.loop is not None and not self.loop.is_closed():
            self.loop.call_soon_threadsafe(session.close)
        else:
            session.mark_closed()

    def keep(self) -> None:
        """On a map shard, every second: say it is alive (with the address gateways reach it
        at) and renew the leases of its resident sessions; drop those another shard took."""
        name = self.settings.shard_name
        if name is None:
            return
        resident = self.resident.snapshot()
        self.store.heartbeat_shard(name, self.settings.shard_address)
        epochs = {sid: s.epoch for sid, s in resident.items() if s.epoch is not None}
        for sid in self.store.renew_leases(name, epochs, self.settings.shard_lease_s):
            self.drop_taken_over(resident[sid])
