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
from collections import OrderedDict

from app.store import SessionRecord, ShardRecord, Store, StoreUnavailableError

DIRECTORY_TTL_S = 0.5
"""How long a gateway trusts its list of live shards before reading it again."""
OWNERS_KEPT = 100_000
"""Sessions whose last route a gateway remembers (for when the store cannot be read)."""
READ_POLL_S = 0.02
"""How often a caller that wants a fresh list checks whether the next read is done."""
FRESH_WAIT_S = 1.0
"""How long past DIRECTORY_TTL_S a caller waits for a read that started after it asked
(a read while the database is down waits out the store's connect timeout, 5 s by default)."""

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
    """The live shards, as the store lists them. A gateway runs `run` in the background, which
    reads them every DIRECTORY_TTL_S (in a thread: the store's calls block, for up to its
    connect timeout while the database is down), so no relay waits on the store to learn
    where shards are; without it, `live` reads when its list is older than DIRECTORY_TTL_S.
    While the store cannot be read, the last list read stands (the shards keep serving what
    they hold; they cannot commit either), and sessions go where rendezvous puts them."""

    def __init__(self, store: Store, max_age_s: float):
        self.store = store
        self.max_age_s = max_age_s
        self._live: dict[str, str] = {}
        self._read_at = -float("inf")
        """When the last finished read (successful or not) started: what it says is as of then."""
        self._running = False
        self._turn = itertools.count()
        self._owners: OrderedDict[str, str] = OrderedDict()
        """The shard each recently routed session went to, newest last: where it goes while
        the store cannot be read."""
        self.store_ok = True
        """False while the store cannot be read (its last read failed)."""

    async def refresh(self) -> None:
        """Read the live shards once (in a thread)."""
        started = time.monotonic()
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
        finally:
            self._read_at = started

    async def run(self) -> None:
        """Refresh every DIRECTORY_TTL_S until cancelled."""
        self._running = True
        try:
            while True:
                try:
                    await self.refresh()
                except Exception:  # a bug in one read must not stop the next
                    log.exception("reading the live shards failed")
                await asyncio.sleep(DIRECTORY_TTL_S)  # a timer, not synchronisation
        finally:
            self._running = False

    async def fresh_read(self) -> bool:
        """Wait for a read that starts after this call; False when none has finished within
        DIRECTORY_TTL_S + FRESH_WAIT_S (with `run` going): the store is slow or down, and a
        read that started before the call (it may have answered just before the database
        went away) says nothing of now."""
        asked = time.monotonic()
        if not self._running:
            await self.refresh()
            return True
        give_up = asked + DIRECTORY_TTL_S + FRESH_WAIT_S
        while self._read_at < asked:
            if time.monotonic() >= give_up:
                return False
            await asyncio.sleep(READ_POLL_S)
        return True

    async def live(self, fresh: bool = False) -> dict[str, str]:
        """Live shards' addresses by name, as last read; `fresh`: after a read that started
        after this call (`fresh_read`), or as last read if none finished in time."""
        if fresh:
            await self.fresh_read()
        elif not self._running and time.monotonic() - self._read_at > DIRECTORY_TTL_S:
            await self.refresh()
        return dict(self._live)

    async def route(self, session_id: str, fresh: bool = False) -> tuple[str, str]:
        """(name, address) of the shard that serves `session_id`; NoLiveShard if none.
        An unknown session goes where rendezvous puts it (the shard then answers 404)."""
        live = await self.live(fresh)
        if not live:
            raise NoLiveShard(self.max_age_s)
        try:
            record = await asyncio.to_thread(self.store.load_session, session_id)
        except KeyError:
            record = None
        except StoreUnavailableError:  # the owner it had when the store last answered
            owner = self._owners.get(session_id)
            name = owner if owner in live else rendezvous(session_id, sorted(live))
            return name, live[name]
        name = owner_if_live(record, live, time.time()) or rendezvous(session_id, sorted(live))
        self._owners[session_id] = name
        self._owners.move_to_end(session_id)
        if len(self._owners) > OWNERS_KEPT:
            self._owners.popitem(last=False)
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
