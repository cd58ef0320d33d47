"""Sessions: one mapping engine each, the keyframe pipeline, update fan-out, persistence.

Threading model: the event loop only moves bytes. Frames are unpacked, decoded and
validated in a small decode pool; keyframes are mapped in the mapping pool, which sessions
share round-robin (`RoundRobinScheduler`: no session waits behind more than one keyframe of
each other session). Each session maps one keyframe at a time (its lane's map lock,
`KeyframeLane.lock`), and readers of
the map (queries, object lists, delta building) take the same lock, so they see whole
keyframes. If keyframes arrive faster than a session maps them, only the newest waits: an
older waiting keyframe is acknowledged as dropped (frames are samples, not a log).

Commit, then publish: a keyframe's changes are visible only once the store has them. The
keyframe maps and commits inside one hold of the map lock; if the commit (or the mapping)
fails, the engine is put back to the store's durable state before the lock is released, so
no reader ever sees a change the store lacks and no seq is reused for other contents.
While the store refuses writes (disk full, I/O error) keyframes get `storage_unavailable`
without being mapped, queries keep answering from the durable map, and the store is probed
about once a second until it takes writes again (`StorageWatch`, `/healthz`).

Stored versus resident: sessions live in the store, and only the maps in use are in memory
(`residency`). Start-up loads no map; a session loads on its first use (a request
or a socket) through the same path a restart took (`Loader.restored`), and is unloaded (its
counters and last use saved) after idle_unload_s without use, or when the resident budget
(max_resident_sessions) needs room, least recently used first, never while a socket is open
or a keyframe is in flight. Unloading and loading lose what a restart loses, nothing more:
the map and the delta log are durable at every commit, so deltas resume by seq. Retention
(session_retention_days, off by default) deletes sessions unused for longer, at start and
then periodically.

The modules, one concept each; `SessionManager` (manager.py) composes them and is what the
routes talk to:
- session.py: a session's state and the questions it answers (stats, objects, queries,
  relational queries, deltas), its sightings and publications;
- lane.py: a session's lane of the keyframe pipeline (the map lock, the pending keyframe);
- pipeline.py: the keyframe pipeline (map, commit, acknowledge; back to the durable map);
- lifecycle.py: create, import, export, delete, knobs, the map's history;
- residency.py, loading.py, claims.py, retention.py: which maps are in memory, how they
  load and unload, map shards' claims on sessions, and retention;
- counters.py: frames, sightings and bytes counted and saved;
- storage.py: whether the store takes writes, and its probes;
- engines.py: the perception backends and the mapping engine of each session.
"""

from app.server.sessions.claims import SessionMoved
from app.server.sessions.counters import (
    COUNTERS_SAVE_INTERVAL_S,
    LAST_USE_SAVE_INTERVAL_S,
    NO_DETECTIONS_WARNING,
)
from app.server.sessions.lane import Reply
from app.server.sessions.lifecycle import StoredSessionsFull
from app.server.sessions.manager import BUSY_RETRY_AFTER_S, SOCKET_LOAD_WORKERS, SessionManager
from app.server.sessions.pipeline import STORAGE_UNAVAILABLE_MESSAGE, PersistFailed
from app.server.sessions.residency import Residency, ResidentSessionsBusy
from app.server.sessions.retention import RETENTION_CHECK_MAX_INTERVAL_S
from app.server.sessions.session import (
    FLUSH_AFTER_S,
    SIGHTINGS_WAITING,
    Session,
    hash_token,
    token_matches,
)
from app.server.sessions.storage import (
    STORAGE_PROBE_INTERVAL_S,
    STORAGE_RETRY_AFTER_S,
    StorageHealth,
    StorageUnavailable,
)

__all__ = [
    "BUSY_RETRY_AFTER_S",
    "COUNTERS_SAVE_INTERVAL_S",
    "FLUSH_AFTER_S",
    "LAST_USE_SAVE_INTERVAL_S",
    "NO_DETECTIONS_WARNING",
    "RETENTION_CHECK_MAX_INTERVAL_S",
    "SIGHTINGS_WAITING",
    "SOCKET_LOAD_WORKERS",
    "STORAGE_PROBE_INTERVAL_S",
    "STORAGE_RETRY_AFTER_S",
    "STORAGE_UNAVAILABLE_MESSAGE",
    "PersistFailed",
    "Reply",
    "Residency",
    "ResidentSessionsBusy",
    "Session",
    "SessionManager",
    "SessionMoved",
    "StorageHealth",
    "StorageUnavailable",
    "StoredSessionsFull",
    "hash_token",
    "token_matches",
]
