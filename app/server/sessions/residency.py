"""Which sessions are resident (their maps in memory): at most a budget, each loaded once on
first use, unloaded least recently used first, never while busy.

A session lives in the store; being resident is a cache of its engine. `acquire` hands out
a session *in use* (loaded first if it is not resident); `release` ends that use. A session
is busy while it is in use (an open socket, a request being answered) or maps a keyframe,
and a busy session is never unloaded. To load a session while the budget is full, the least
recently used session that is not busy is unloaded first; when every resident session is
busy there is no room (`ResidentSessionsBusy`: the REST answer is 503 with Retry-After).

Loading and unloading run in the calling thread (never the event loop's) and outside the
residency lock, so a slow load holds up only the callers of that one session. While a
session loads, unloads or is deleted it is *moving*: callers for it wait for that to end,
so two requests for the same unloaded session load it once, and a session is never loaded
while its counters are still being saved by the unload before.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from typing import Generic, Protocol, TypeVar


class Resident(Protocol):
    """What residency needs of a session."""

    @property
    def id(self) -> str: ...

    users: int
    """Uses in progress (sockets, requests); counted by `Residency` only."""
    last_used: float
    """time.monotonic() of the last use: least recently used first, idle after a while."""

    @property
    def busy(self) -> bool:
        """In use or mapping a keyframe: never unloaded then."""
        ...

    def touch(self) -> None:
        """Note a use now (sets `last_used`)."""
        ...


S = TypeVar("S", bound=Resident)


class ResidentSessionsBusy(RuntimeError):
    """No room to load or create a session now: every resident session is busy (has an open
    socket, a request or a keyframe in flight). Transient: retry after `retry_after_s`."""

    def __init__(self, budget: int, retry_after_s: int):
        super().__init__(
            f"all {budget} sessions held in memory are in use (open sockets or keyframes in "
            f"flight), so no other session can be loaded now; retry in {retry_after_s} s "
            f"(the server's --max-resident-sessions is {budget})"
        )
        self.retry_after_s = retry_after_s


class Residency(Generic[S]):
    """The resident sessions of one server. Thread-safe.

    load(sid): the session as the store holds it (KeyError if there is none); called at most
    once at a time per id. unload(session, reason): save what only memory holds; raising
    keeps the session resident (and the caller that wanted its room gets the exception)."""

    def __init__(
        self,
        budget: int,
        load: Callable[[str], S],
        unload: Callable[[S, str], None],
        retry_after_s: int,
    ):
        self.budget = budget
        self._load = load
        self._unload = unload
        self._retry_after_s = retry_after_s
        self._lock = threading.Lock()
        self._resident: dict[str, S] = {}
        self._moving: dict[str, Future[None]] = {}
        """Ids loading, being created, unloading or being deleted: done when that ends."""
        self._claimed = 0
        """Slots of the budget held for sessions loading or being created."""

    # ------------------------------------------------------------------ reading
    def get(self, sid: str) -> S | None:
        """The resident session `sid` (None if not resident); neither loads nor uses it."""
        with self._lock:
            return self._resident.get(sid)

    def snapshot(self) -> dict[str, S]:
        """The resident sessions now, by id (a copy)."""
        with self._lock:
            return dict(self._resident)

    def __len__(self) -> int:
        with self._lock:
            return len(self._resident)

    # ------------------------------------------------------------------ use
    def acquire(self, sid: str) -> S:
        """Session `sid` in use (until `release`), loaded first if it is not resident.

        Raises KeyError when the store has no such session, ResidentSessionsBusy when the
        budget is full of busy sessions, or what unloading the session making room raised
        (it then stays resident)."""
        while True:
            with self._lock:
                session = self._resident.get(sid)
                if session is not None:
                    session.users += 1
                    session.touch()
                    return session
                moving = self._moving.get(sid)
                if moving is None:
                    mine, victim = self._claim(sid)
            if moving is not None:
                # Someone else loads (or unloads, or deletes) it: wait, then look again.
                with contextlib.suppress(Exception):
                    moving.result()
                continue
            return self._fill(sid, mine, victim, lambda: self._load(sid), users=1)

    def release(self, session: S) -> None:
        """End one use of `session` (it may be unloaded once no use is left)."""
        with self._lock:
            session.users -= 1
            session.touch()

    def admit(self, sid: str, make: Callable[[], S], users: int = 0) -> S:
        """A new session made by `make()` (which stores it), made resident with `users` uses;
        raises as `acquire` does, or what `make` raised (nothing is left resident then)."""
        with self._lock:
            if sid in self._resident or sid in self._moving:
                raise ValueError(f"session {sid!r} exists")
            mine, victim = self._claim(sid)
        return self._fill(sid, mine, victim, make, users)

    def _claim(self, sid: str) -> tuple[Future[None], S | None]:
        """Under the lock: mark `sid` moving with a slot of the budget held for it, and pick
        the session to unload first (None when the budget has room). ResidentSessionsBusy
        when every resident session is busy."""
        victim = None
        if len(self._resident) + self._claimed >= self.budget:
            idle = [s for s in self._resident.values() if not s.busy]
            if not idle:
                raise ResidentSessionsBusy(self.budget, self._retry_after_s)
            victim = min(idle, key=lambda s: s.last_used)
            del self._resident[victim.id]
            self._moving[victim.id] = Future()
        self._claimed += 1
        mine = self._moving[sid] = Future()
        return mine, victim

    def _fill(
        self, sid: str, mine: Future[None], victim: S | None, make: Callable[[], S], users: int
    ) -> S:
        """Unload `victim` (if any), then make the session of the slot claimed for `sid`."""
        try:
            if victim is not None:
                self._unload_moving(victim, "budget")
            session = make()
        except BaseException:
            with self._lock:
                self._claimed -= 1
                del self._moving[sid]
            mine.set_result(None)
            raise
        with self._lock:
            self._claimed -= 1
            del self._moving[sid]
            session.users = users
            session.touch()
            self._resident[sid] = session
        mine.set_result(None)
        return session

    def _unload_moving(self, session: S, reason: str) -> None:
        """Unload a session already taken out of the resident set and marked moving; if
        `unload` raises, it is put back and the exception goes on."""
        sid = session.id
        try:
            self._unload(session, reason)
        except BaseException:
            with self._lock:
                self._resident[sid] = session
                done = self._moving.pop(sid)
            done.set_result(None)
            raise
        with self._lock:
            done = self._moving.pop(sid)
        done.set_result(None)

    # ------------------------------------------------------------------ leaving memory
    def unload_idle(self, idle_s: float) -> list[str]:
        """Unload every session not busy and unused for `idle_s` seconds; their ids. One
        that cannot be unloaded (its `unload` raised) stays resident and is left out."""
        now = time.monotonic()
        with self._lock:
            idle = [
                s for s in self._resident.values() if not s.busy and now - s.last_used >= idle_s
            ]
            for session in idle:
                del self._resident[session.id]
                self._moving[session.id] = Future()
        unloaded = []
        for session in idle:
            with contextlib.suppress(Exception):  # `unload` reports its own failures
                self._unload_moving(session, "idle")
                unloaded.append(session.id)
        return unloaded

    def remove(
        self,
        sid: str,
        delete: Callable[[S | None], bool],
        only_if: Callable[[S | None], bool] = lambda session: True,
    ) -> bool:
        """Delete session `sid`: `delete(session)` (None when it is not resident) runs while
        nobody can load it, after it left the resident set (whatever its uses: a deleted
        session's sockets close). Skipped (False) when `only_if(session)`, checked under the
        lock, is false; otherwise what `delete` returned."""
        while True:
            with self._lock:
                moving = self._moving.get(sid)
                if moving is None:
                    session = self._resident.get(sid)
                    if not only_if(session):
                        return False
                    self._resident.pop(sid, None)
                    mine = self._moving[sid] = Future()
                    break
            with contextlib.suppress(Exception):
                moving.result()
        try:
            return delete(session)
        finally:
            with self._lock:
                del self._moving[sid]
            mine.set_result(None)

    def forget(self, session: S) -> None:
        """Drop `session` from the resident set without saving anything (it is broken; the
        store's copy loads on its next use); no-op if it is not the resident one."""
        with self._lock:
            if self._resident.get(session.id) is session:
                del self._resident[session.id]
