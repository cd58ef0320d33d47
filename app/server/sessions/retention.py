"""Retention: sessions unused for longer than session_retention_days are deleted."""

from __future__ import annotations

import logging
import math
import time

from app.server.metrics import Metrics
from app.server.sessions.lifecycle import Lifecycle
from app.server.sessions.loading import stored_record
from app.server.sessions.residency import Residency
from app.server.sessions.session import Session
from app.server.settings import ServerSettings
from app.store import Store

log = logging.getLogger("semanticxr")


RETENTION_CHECK_MAX_INTERVAL_S = 600.0
"""Retention is checked every tenth of the retention period, at least this often."""


class Retention:
    """Deleting the sessions past their retention (session_retention_days; off when unset),
    at start and then periodically."""

    def __init__(
        self,
        settings: ServerSettings,
        store: Store,
        resident: Residency[Session],
        lifecycle: Lifecycle,
        metrics: Metrics,
    ):
        self.settings = settings
        self.store = store
        self.resident = resident
        self.lifecycle = lifecycle
        self.metrics = metrics
        self._due = -math.inf
        """time.monotonic() at which retention is next checked."""

    def apply(self) -> list[str]:
        """Delete every session unused (no frames, requests or sockets) for longer than
        session_retention_days, each logged and counted; their ids. Does nothing when
        retention is off (unset). A resident session counts by its use in memory, and one
        in use is never deleted."""
        days = self.settings.session_retention_days
        if days is None:
            return []
        period_s = days * 86_400.0
        self._due = time.monotonic() + min(RETENTION_CHECK_MAX_INTERVAL_S, period_s / 10)
        cutoff = time.time() - period_s

        def still_idle(session: Session | None) -> bool:
            return session is None or (
                not session.busy and (session.record.last_used_at or 0.0) < cutoff
            )

        def delete_if_unused(session: Session | None, sid: str) -> bool:
            if session is None:  # nobody can load it now: its stored last use is final
                rec = stored_record(self.resident, self.store, sid)
                if rec is None or (rec.last_used_at or 0.0) >= cutoff:
                    return False
            self.lifecycle.remove(sid, session)
            return True

        deleted = []
        for sid in self.store.idle_sessions(cutoff):
            if self.resident.remove(
                sid, lambda session, sid=sid: delete_if_unused(session, sid), still_idle
            ):
                deleted.append(sid)
                self.metrics.sessions_expired.inc()
                log.info(
                    "session %s deleted: unused for over %g days (--session-retention-days)",
                    sid,
                    days,
                )
        if deleted:
            self.metrics.sessions_stored.set(self.store.count_sessions())
        return deleted

    def due(self) -> bool:
        """Whether retention is on and its next check is due."""
        return self.settings.session_retention_days is not None and time.monotonic() >= self._due
