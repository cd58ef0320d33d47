"""Storage health: whether the store takes writes, failure streaks and the probes that end them."""

from __future__ import annotations

import logging
import math
import threading
import time

from app.server.metrics import Metrics
from app.store import Store, StoreUnavailableError

log = logging.getLogger("semanticxr")


STORAGE_PROBE_INTERVAL_S = 1.0
"""While the store refuses writes, how often it is probed (by keyframes and a timer)."""
STORAGE_RETRY_AFTER_S = 2
"""Retry-After (seconds) when the store cannot save the session that would make room."""


class StorageUnavailable(RuntimeError):
    """A keyframe refused unmapped because the store cannot save now (`storage_unavailable`)."""


class StorageHealth:
    """Whether the store takes writes; a failure streak runs from the first failed write to
    the next successful one (a commit or a probe). Thread-safe."""

    REASON = "storage unavailable: the server cannot save changes (disk full, I/O error or database down)"
    """What /healthz says while a streak lasts (details, such as paths, go to the log only)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._failing_since: float | None = None
        self._failures = 0
        self._last_probe = -math.inf

    @property
    def failing(self) -> bool:
        return self._failing_since is not None

    @property
    def reason(self) -> str | None:
        """None while writes succeed."""
        return self.REASON if self.failing else None

    def failed(self) -> bool:
        """Record a failed write; True when it starts a streak."""
        with self._lock:
            self._failures += 1
            if self._failing_since is not None:
                return False
            self._failing_since = time.monotonic()
            self._last_probe = self._failing_since
            return True

    def succeeded(self) -> tuple[float, int] | None:
        """Record a successful write; (streak seconds, failed writes) when it ends a streak."""
        with self._lock:
            if self._failing_since is None:
                return None
            ended = (time.monotonic() - self._failing_since, self._failures)
            self._failing_since, self._failures = None, 0
            return ended

    def probe_due(self) -> bool:
        """True (and the probe clock restarts) when failing and the last probe is older than
        STORAGE_PROBE_INTERVAL_S."""
        with self._lock:
            now = time.monotonic()
            if self._failing_since is None or now - self._last_probe < STORAGE_PROBE_INTERVAL_S:
                return False
            self._last_probe = now
            return True


class StorageWatch(StorageHealth):
    """The store's health as the sessions see it: every write that fails or succeeds is
    reported here (a failed one counted; the first of a streak logged), and while writes
    fail the store is probed, at most every STORAGE_PROBE_INTERVAL_S. Thread-safe."""

    def __init__(self, store: Store, metrics: Metrics):
        super().__init__()
        self.store = store
        self.metrics = metrics

    def write_failed(self, what: str, exc: BaseException) -> None:
        """Count a failed write; log it if it starts a failure streak (one ERROR a streak)."""
        self.metrics.persist_failures.inc()
        if self.failed():
            log.error(
                "storage failing: %s failed (%s); keyframes are refused with "
                "storage_unavailable and /healthz answers 503 until a write succeeds "
                "(probed every %g s)",
                what,
                exc,
                STORAGE_PROBE_INTERVAL_S,
            )

    def write_succeeded(self) -> None:
        ended = self.succeeded()
        if ended is not None:
            log.info(
                "storage recovered: writes succeed again after %.1f s and %d failed writes",
                *ended,
            )

    def probe(self) -> bool:
        """While the store refuses writes, probe it (at most every STORAGE_PROBE_INTERVAL_S);
        True when writes work (a successful probe ends the failure streak)."""
        if not self.failing:
            return True
        if not self.probe_due():
            return False
        try:
            self.store.probe()
        except StoreUnavailableError:
            return False
        self.write_succeeded()
        return True
