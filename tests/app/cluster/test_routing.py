"""Routing sessions to map shards without Ray: rendezvous hashing (deterministic, moves only a
dead shard's sessions, spreads evenly), the live-owner rule, and the shard directory over a
real SQLite store (live owner first, else rendezvous over the shards that beat lately)."""

from __future__ import annotations

import asyncio
import contextlib
import random
import threading
import time
import uuid
from collections import Counter

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.cluster.routing import (
    NoLiveShard,
    ShardDirectory,
    owner_if_live,
    rendezvous,
    rendezvous_weight,
)
from app.cluster.shards import shard_names
from app.store import SessionRecord, Store, StoreUnavailableError, open_store, sqlite_url

MAX_AGE_S = 5.0
"""How fresh a heartbeat must be for the directory to count its shard live."""
LEASE_S = 30.0
NOW = 1_700_000_000.0
"""A unix time the unit tests pass as `now` (nothing here reads the clock but the store)."""

FEW = settings(max_examples=100, deadline=None)
session_ids = st.text(min_size=1, max_size=24)
shard_sets = st.sets(st.text(min_size=1, max_size=12), min_size=2, max_size=8)


def session_id_list(n: int, seed: int = 0) -> list[str]:
    """`n` session ids shaped like the server's (16 hex digits of a uuid4), reproducibly."""
    rng = random.Random(seed)
    return [uuid.UUID(int=rng.getrandbits(128), version=4).hex[:16] for _ in range(n)]


def record(sid: str = "s1", **changes) -> SessionRecord:
    values = dict(
        session_id=sid,
        name=f"name of {sid}",
        mode="semanticxr",
        knobs={},
        token_hash="sha256:abc",
        created_at=NOW - 100,
    )
    values.update(changes)
    return SessionRecord(**values)


# ---------------------------------------------------------------------- rendezvous
def test_a_weight_is_the_same_in_every_process_and_release():
    # Gateways of different processes (and releases, during an upgrade) must agree: the
    # weight is a keyed hash of the names, never Python's per-process hash().
    assert rendezvous_weight("0123456789abcdef", "mapshard-0") == 13281013781508759143
    assert rendezvous_weight("0123456789abcdef", "mapshard-1") == 3654242392500149947


@FEW
@given(sid=session_ids, shards=shard_sets, order_seed=st.integers(0, 2**32))
def test_rendezvous_is_deterministic_whatever_the_order_of_the_shards(sid, shards, order_seed):
    listed = sorted(shards)
    shuffled = list(shards)
    random.Random(order_seed).shuffle(shuffled)
    picked = rendezvous(sid, listed)
    assert picked in shards
    assert rendezvous(sid, listed) == picked  # stable across calls
    assert rendezvous(sid, shuffled) == picked  # and across the order gateways list them in


@FEW
@given(sids=st.lists(session_ids, min_size=1, max_size=50), shards=shard_sets, data=st.data())
def test_removing_a_shard_moves_only_the_sessions_it_served(sids, shards, data):
    gone = data.draw(st.sampled_from(sorted(shards)))
    left = sorted(shards - {gone})
    for sid in sids:
        before = rendezvous(sid, sorted(shards))
        after = rendezvous(sid, left)
        if before != gone:
            assert after == before, sid
        else:
            assert after in left


@FEW
@given(sids=st.lists(session_ids, min_size=1, max_size=50), shards=shard_sets, new=st.text())
def test_adding_a_shard_moves_sessions_only_onto_it(sids, shards, new):
    grown = sorted(shards | {new})
    for sid in sids:
        after = rendezvous(sid, grown)
        assert after in (rendezvous(sid, sorted(shards)), new), sid


def test_two_thousand_sessions_spread_roughly_evenly_over_four_shards():
    shards = shard_names(4)
    spread = Counter(rendezvous(sid, shards) for sid in session_id_list(2_000))
    assert sorted(spread) == shards
    shares = {shard: n / 2_000 for shard, n in spread.items()}
    assert all(0.15 <= share <= 0.35 for share in shares.values()), shares


# ---------------------------------------------------------------------- the live owner
LIVE = {"shard-a": "http://a", "shard-b": "http://b"}


def test_a_live_owner_with_its_lease_running_keeps_its_session():
    held = record(owner="shard-a", epoch=3, lease_until=NOW + 1)
    assert owner_if_live(held, LIVE, NOW) == "shard-a"


@pytest.mark.parametrize(
    "rec",
    [
        pytest.param(record(owner="shard-a", epoch=3, lease_until=NOW - 1), id="lease passed"),
        pytest.param(record(owner="shard-a", epoch=3, lease_until=NOW), id="lease ends now"),
        pytest.param(record(owner="shard-c", epoch=3, lease_until=NOW + 1), id="owner not live"),
        pytest.param(record(owner=None, epoch=3, lease_until=None), id="no owner"),
        pytest.param(record(owner="shard-a", epoch=3, lease_until=None), id="no lease"),
        pytest.param(None, id="no session"),
    ],
)
def test_a_session_has_no_live_owner_when(rec):
    assert owner_if_live(rec, LIVE, NOW) is None


# ---------------------------------------------------------------------- the directory
@pytest.fixture
def store(tmp_path):
    with open_store(sqlite_url(tmp_path / "semanticxr.db")) as store:
        yield store


def beat(store: Store, *names: str, age_s: float = 0.0) -> None:
    for name in names:
        store.heartbeat_shard(name, f"http://{name}:8000", now=time.time() - age_s)


def route(directory: ShardDirectory, sid: str) -> tuple[str, str]:
    return asyncio.run(directory.route(sid, fresh=True))


def other(shard: str) -> str:
    return "shard-b" if shard == "shard-a" else "shard-a"


def test_the_directory_routes_a_session_to_its_live_owner_over_rendezvous(store):
    beat(store, "shard-a", "shard-b")
    store.create_session(record("s1"))
    unowned = rendezvous("s1", ["shard-a", "shard-b"])
    store.claim_session("s1", other(unowned), LEASE_S)
    assert route(ShardDirectory(store, MAX_AGE_S), "s1") == (
        other(unowned),
        f"http://{other(unowned)}:8000",
    )


def test_a_session_whose_lease_ran_out_goes_where_rendezvous_puts_it(store):
    beat(store, "shard-a", "shard-b")
    store.create_session(record("s1"))
    unowned = rendezvous("s1", ["shard-a", "shard-b"])
    store.claim_session("s1", other(unowned), LEASE_S, now=time.time() - 2 * LEASE_S)
    assert route(ShardDirectory(store, MAX_AGE_S), "s1")[0] == unowned


def test_a_session_whose_owner_stopped_beating_goes_to_a_live_shard(store):
    beat(store, "shard-a", "shard-b")
    beat(store, "shard-c", age_s=2 * MAX_AGE_S)
    store.create_session(record("s1"))
    store.claim_session("s1", "shard-c", LEASE_S)  # its lease runs, its heartbeat is stale
    assert route(ShardDirectory(store, MAX_AGE_S), "s1")[0] == rendezvous(
        "s1", ["shard-a", "shard-b"]
    )


def test_sessions_without_an_owner_go_where_rendezvous_puts_them_among_live_shards(store):
    beat(store, "shard-a", "shard-b", "shard-c")
    directory = ShardDirectory(store, MAX_AGE_S)
    sids = session_id_list(30)
    for sid in sids[:15]:  # stored without an owner; the rest unknown (the shard says 404)
        store.create_session(record(sid))
    routes = {sid: route(directory, sid) for sid in sids}
    live = ["shard-a", "shard-b", "shard-c"]
    assert routes == {
        sid: (rendezvous(sid, live), f"http://{rendezvous(sid, live)}:8000") for sid in sids
    }


def test_a_shard_whose_heartbeat_is_older_than_max_age_is_not_live(store):
    beat(store, "shard-a")
    beat(store, "shard-old", age_s=MAX_AGE_S + 1)
    directory = ShardDirectory(store, MAX_AGE_S)
    assert asyncio.run(directory.live(fresh=True)) == {"shard-a": "http://shard-a:8000"}
    assert all(route(directory, sid)[0] == "shard-a" for sid in session_id_list(20))


def test_without_a_live_shard_routing_raises_no_live_shard(store):
    beat(store, "shard-old", age_s=MAX_AGE_S + 1)
    directory = ShardDirectory(store, MAX_AGE_S)
    with pytest.raises(NoLiveShard, match="no map shard is alive"):
        route(directory, "s1")
    with pytest.raises(NoLiveShard):
        asyncio.run(directory.any())


def test_a_forgotten_shard_is_routed_around_at_once(store):
    beat(store, "shard-a", "shard-b")
    store.create_session(record("s1"))
    store.claim_session("s1", "shard-a", LEASE_S)
    directory = ShardDirectory(store, MAX_AGE_S)
    assert route(directory, "s1")[0] == "shard-a"
    store.forget_shard("shard-a")  # a graceful stop: its claims let go
    assert route(directory, "s1")[0] == "shard-b"


class FlakyStore:
    """A real store whose shard registry can be made unreadable (a database down)."""

    def __init__(self, store: Store):
        self.store = store
        self.down = False

    def live_shards(self, max_age_s: float):
        if self.down:
            raise StoreUnavailableError("the database is down")
        return self.store.live_shards(max_age_s)

    def load_session(self, sid: str) -> SessionRecord:
        if self.down:
            raise StoreUnavailableError("the database is down")
        return self.store.load_session(sid)


def test_while_the_store_cannot_be_read_the_last_list_of_shards_stands(store):
    beat(store, "shard-a", "shard-b")
    flaky = FlakyStore(store)
    directory = ShardDirectory(flaky, MAX_AGE_S)  # type: ignore[arg-type]
    listed = asyncio.run(directory.live(fresh=True))
    flaky.down = True
    assert asyncio.run(directory.live(fresh=True)) == listed
    assert not directory.store_ok
    assert route(directory, "s1")[0] == rendezvous("s1", ["shard-a", "shard-b"])
    flaky.down = False
    asyncio.run(directory.live(fresh=True))
    assert directory.store_ok


def test_while_the_store_cannot_be_read_a_session_goes_to_the_owner_it_was_last_routed_to(
    store,
):
    beat(store, "shard-a", "shard-b")
    store.create_session(record("s1"))
    owner = other(rendezvous("s1", ["shard-a", "shard-b"]))
    store.claim_session("s1", owner, LEASE_S)
    flaky = FlakyStore(store)
    directory = ShardDirectory(flaky, MAX_AGE_S)  # type: ignore[arg-type]
    assert route(directory, "s1")[0] == owner
    flaky.down = True
    assert route(directory, "s1")[0] == owner  # not where rendezvous would put it


class GatedStore(FlakyStore):
    """A FlakyStore whose reads of the live shards answer as of their start, but return only
    once the test opens a gate."""

    def __init__(self, store: Store):
        super().__init__(store)
        self.reading = threading.Event()
        self.gate = threading.Event()

    def live_shards(self, max_age_s: float):
        self.reading.set()
        try:
            return super().live_shards(max_age_s)
        finally:
            self.gate.wait(10)


def fresh_read_while_reading(gated: GatedStore, then) -> tuple[bool, bool]:
    """With the directory's reader going and a read waiting at the gate: ask for a fresh
    read, do `then()`, open the gate; (the ask's answer, store_ok after it)."""

    async def scenario() -> tuple[bool, bool]:
        directory = ShardDirectory(gated, MAX_AGE_S)  # type: ignore[arg-type]
        reader = asyncio.create_task(directory.run())
        try:
            await asyncio.to_thread(gated.reading.wait, 10)  # a read is in flight
            asked = asyncio.create_task(directory.fresh_read())
            await asyncio.sleep(0)  # the ask starts before the read in flight ends
            then()
            gated.gate.set()
            return await asked, directory.store_ok
        finally:
            gated.gate.set()
            reader.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await reader

    return asyncio.run(scenario())


def test_a_fresh_read_is_one_that_started_after_the_ask(store):
    """The database goes down while a read that began before it is in flight: that read
    answers, but a fresh read is the next one, which finds the store down (a gateway's
    /healthz then says 503 at once)."""
    beat(store, "shard-a")
    gated = GatedStore(store)

    def database_down() -> None:
        gated.down = True

    answered, store_ok = fresh_read_while_reading(gated, database_down)
    assert answered and not store_ok


def test_a_fresh_read_that_does_not_answer_in_time_says_so(store):
    """Reads that wait out the store's connect timeout: the ask gives up, answering False
    (the store is not answering now), whatever the last read said."""
    beat(store, "shard-a")
    gated = GatedStore(store)

    async def scenario() -> tuple[bool, bool]:
        directory = ShardDirectory(gated, MAX_AGE_S)  # type: ignore[arg-type]
        reader = asyncio.create_task(directory.run())
        try:
            await asyncio.to_thread(gated.reading.wait, 10)  # the reader's read is stuck
            return await directory.fresh_read(), directory.store_ok
        finally:
            gated.gate.set()
            reader.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await reader

    answered, store_ok = asyncio.run(scenario())
    assert not answered and store_ok
