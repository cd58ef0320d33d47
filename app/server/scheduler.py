"""Fair mapping: keyframes of all sessions share the mapping workers round-robin.

docs/architecture.md, "Fairness": mapping work is round-robin across sessions with a pending
keyframe, so no session waits behind more than one keyframe of each other session. Each
session asks for a worker for one keyframe at a time (`KeyframePipeline._map_loop`), and
sessions are served in the order they started waiting; a session that has just been served
waits again behind every session already waiting. One session's slow keyframe holds one
worker; the others keep taking turns on the rest.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections import OrderedDict, deque
from collections.abc import AsyncIterator, Awaitable, Callable, Hashable
from concurrent.futures import Executor
from typing import TypeVar

T = TypeVar("T")


class Turn:
    """A worker held for one key: `run` its job there."""

    def __init__(self, pool: Executor):
        self._pool = pool
        self.job: asyncio.Future | None = None

    def run(self, fn: Callable[..., T], *args) -> Awaitable[T]:
        """Start fn(*args) in a worker thread now; await the result. Cancelling the waiter
        does not stop the job: the worker stays taken until it ends (the pool has no more
        threads than workers)."""
        self.job = asyncio.get_running_loop().run_in_executor(self._pool, fn, *args)
        return asyncio.shield(self.job)


class RoundRobinScheduler:
    """At most `workers` jobs of `pool` at once, at most one per key, granted round-robin
    over the keys waiting. Use from one event loop."""

    def __init__(self, pool: Executor, workers: int):
        self.pool = pool
        self.workers = workers
        self._running: set[Hashable] = set()
        self._waiting: OrderedDict[Hashable, deque[asyncio.Future]] = OrderedDict()
        """Keys in turn order, each with its waiters (a session has one at a time)."""

    @property
    def waiting(self) -> list[Hashable]:
        """The keys waiting for a worker, next first."""
        return list(self._waiting)

    @contextlib.asynccontextmanager
    async def turn(self, key: Hashable) -> AsyncIterator[Turn]:
        """Wait for `key`'s turn, then hold one worker until the block ends (or, if the block
        is left while its job still runs, e.g. cancelled, until that job ends)."""
        await self._acquire(key)
        turn = Turn(self.pool)
        try:
            yield turn
        finally:
            if turn.job is not None and not turn.job.done():
                turn.job.add_done_callback(lambda _: self._release(key))
            else:
                self._release(key)

    async def run(self, key: Hashable, fn: Callable[..., T], *args) -> T:
        """fn(*args) in the pool once it is `key`'s turn; its result or exception."""
        async with self.turn(key) as turn:
            return await turn.run(fn, *args)

    async def _acquire(self, key: Hashable) -> None:
        turn = asyncio.get_running_loop().create_future()
        self._waiting.setdefault(key, deque()).append(turn)
        self._grant()
        try:
            await turn
        except asyncio.CancelledError:
            if turn.done() and not turn.cancelled():
                self._release(key)  # granted as it was cancelled: pass the turn on
            else:
                self._forget(key, turn)
            raise

    def _grant(self) -> None:
        """Give free workers to the keys waiting longest that are not running already."""
        for key in list(self._waiting):
            if len(self._running) >= self.workers:
                return
            if key in self._running:
                continue
            waiters = self._waiting.pop(key)
            turn = waiters.popleft()
            if waiters:  # a second job of the same key goes to the back of the line
                self._waiting[key] = waiters
            if turn.cancelled():  # its caller is gone (it forgets itself when it resumes)
                continue
            self._running.add(key)
            turn.set_result(None)

    def _release(self, key: Hashable) -> None:
        self._running.discard(key)
        self._grant()

    def _forget(self, key: Hashable, turn: asyncio.Future) -> None:
        waiters = self._waiting.get(key)
        if waiters is not None and turn in waiters:
            waiters.remove(turn)
            if not waiters:
                del self._waiting[key]
