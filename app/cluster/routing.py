"""Which map shard serves a session: its live owner, else rendezvous hashing over live shards.

A shard is live while its heartbeat in the store is fresh (shards beat every second). A live
owner keeps its session (its lease says so); a session without one goes to the live shard
with the highest rendezvous weight for its id, so every gateway picks the same shard without
talking to the others, and a shard's death moves only its own sessions.
"""

from __future__ import annotations

import asyncio
import hashlib
import itertools
import logging
import time

from app.store import SessionRecord, ShardRecord, Store, StoreUnavailableError

DIRECTORY_TTL_S = 0.5
"""How long a gateway trusts its list of live shards before reading it again."""

log = logging.getLogger("semanticxr.gateway")


class NoLiveShard(RuntimeError):
    """No map shard has a fresh heartbeat: nothing can serve a session now (503)."""

    def __init__(self, max_age_s: float):
        super().__init__(
            f"no map shard is alive (none beat in the last {max_age_s:g} s); they may be "
            f"starting or restarting: retry shortly"
        )


def rendezvous_weight(session_id: str, shard: str) -> int:
    """The weight of `shard` for `session_id` (highest wins): stable across processes."""
    digest = hashlib.blake2b(f"{shard}\0{session_id}".encode(), digest_size=8).digest()
    return int.from_bytes(digest, "big")


def rendezvous(session_id: str, shards: list[str]) -> str:
    """The shard, among `shards` (non-empty), that serves `session_id` when none owns it."""
    return max(shards, key=lambda shard: rendezvous_weight(session_id, shard))


def owner_if_live(record: SessionRecord | None, live: dict[str, str], now: float) -> str | None:
    """The session's owner when it is live and its lease still runs, else None."""
    if record is None or record.owner is None or record.owner not in live:
        return None
    return record.owner if (record.lease_until or 0.0) > now else None


class ShardDirectory:
    """The live shards, as the store lists them, read at most every DIRECTORY_TTL_S (from a
    thread: the store's calls block). While the store cannot be read, the last list read
    stands (the shards keep serving what they hold; they cannot commit either), and
    sessions go where rendezvous puts them."""

    def __init__(self, store: Store, max_age_s: float):
        self.store = store
        self.max_age_s = max_age_s
        self._live: dict[str, str] = {}
        self._read_at = -float("inf")
        self._lock = asyncio.Lock()
        self._turn = itertools.count()
        self.store_ok = True
        """False while the store cannot be read (its last read failed)."""

    async def live(self, fresh: bool = False) -> dict[str, str]:
        """Live shards' addresses by name (read again when older than DIRECTORY_TTL_S, or
        `fresh`)."""
        async with self._lock:
            if fresh or time.monotonic() - self._read_at > DIRECTORY_TTL_S:
                try:
                    shards: list[ShardRecord] = await asyncio.to_thread(
                        self.store.live_shards, self.max_age_s
                    )
                except StoreUnavailableError as exc:
                    if self.store_ok:
                        log.warning("cannot read the live shards (%s); using the last list", exc)
                    self.store_ok = False
                else:
                    self._live = {s.name: s.url for s in shards}
                    self.store_ok = True
                self._read_at = time.monotonic()
            return dict(self._live)

    async def route(self, session_id: str, fresh: bool = False) -> tuple[str, str]:
        """(name, address) of the shard that serves `session_id`; NoLiveShard if none.
        An unknown session goes where rendezvous puts it (the shard then answers 404)."""
        live = await self.live(fresh)
        if not live:
            raise NoLiveShard(self.max_age_s)
        try:
            record = await asyncio.to_thread(self.store.load_session, session_id)
        except (KeyError, StoreUnavailableError):
            record = None
        name = owner_if_live(record, live, time.time()) or rendezvous(session_id, sorted(live))
        return name, live[name]

    async def any(self) -> tuple[str, str]:
        """A live shard for requests about no session in particular (round robin)."""
        live = await self.live()
        if not live:
            live = await self.live(fresh=True)
            if not live:
                raise NoLiveShard(self.max_age_s)
        names = sorted(live)
        name = names[next(self._turn) % len(names)]
        return name, live[name]

    async def is_live(self, name: str) -> bool:
        return name in await self.live()
