"""Map shards in the stores (schema 5): owners, epochs and leases fence a session's writes to
the shard that last claimed it; acks remembered per (stream, seq); the shard registry; a
creation counted against max_sessions in its own transaction. Tests taking `store` or
`store_url` run against each store (conftest.py: a real SQLite file and a real PostgreSQL
database). Times are passed as `now=`: nothing here reads or waits on the clock."""

from __future__ import annotations

import sqlite3
import threading
from collections.abc import Callable
from pathlib import Path

import pytest
from test_store import everything, make_object, query, record, seeded

from app.mapping.object import Change
from app.store import (
    DONE_WINDOW,
    KeyframeCommit,
    SessionFenced,
    SessionHeld,
    ShardRecord,
    Store,
    StoredSessionsLimit,
    open_store,
    postgres,
    sqlite,
)
from app.store.dialect import POSTGRES, SQLITE
from app.store.schema import statements

LEASE_S = 10.0
T0 = 1_000.0
"""The unix time claims are made at (passed as `now`)."""
ROUNDS = 5
"""How many times a concurrency test races: a race can go the safe way by chance."""


def observable(store: Store, sid: str = "s1") -> tuple:
    """Everything a write to session `sid` could change."""
    return (
        everything(store),
        store.load_changes(sid),
        [o.id for o in store.load_removed_objects(sid)],
        store.done_ack(sid, "stream", 1),
    )


def run_together(calls: list[Callable[[], object]]) -> list[object]:
    """Each call in a thread of its own, all released at once; each one's result or the
    exception it raised, in the order of `calls`."""
    start = threading.Barrier(len(calls))
    results: list[object] = [None] * len(calls)

    def run(i: int) -> None:
        start.wait(timeout=10)
        try:
            results[i] = calls[i]()
        except BaseException as exc:  # returned: the test asserts on it
            results[i] = exc

    threads = [threading.Thread(target=run, args=(i,)) for i in range(len(calls))]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=30)
    assert not any(thread.is_alive() for thread in threads)
    return results


# ---------------------------------------------------------------------- claims
def test_a_free_session_is_claimed_at_epoch_1_with_a_lease(store):
    store.create_session(record("s1"))
    assert store.claim_session("s1", "shard-a", LEASE_S, now=T0) == 1
    rec = store.load_session("s1")
    assert (rec.owner, rec.epoch, rec.lease_until) == ("shard-a", 1, T0 + LEASE_S)


def test_a_live_lease_refuses_another_owner_naming_the_holder(store):
    store.create_session(record("s1"))
    store.claim_session("s1", "shard-a", LEASE_S, now=T0)
    before = store.load_session("s1")
    with pytest.raises(SessionHeld) as held:
        store.claim_session("s1", "shard-b", LEASE_S, now=T0 + LEASE_S)  # the lease's last instant
    assert (held.value.session_id, held.value.owner, held.value.lease_until) == (
        "s1",
        "shard-a",
        T0 + LEASE_S,
    )
    assert store.load_session("s1") == before


def test_once_the_lease_has_passed_another_owner_claims_at_the_next_epoch(store):
    store.create_session(record("s1"))
    store.claim_session("s1", "shard-a", LEASE_S, now=T0)
    assert store.claim_session("s1", "shard-b", LEASE_S, now=T0 + LEASE_S + 0.5) == 2
    rec = store.load_session("s1")
    assert (rec.owner, rec.epoch, rec.lease_until) == ("shard-b", 2, T0 + 2 * LEASE_S + 0.5)


def test_the_same_owner_claiming_again_bumps_the_epoch(store):
    """A restarted shard fences its previous incarnation."""
    store.create_session(record("s1"))
    assert store.claim_session("s1", "shard-a", LEASE_S, now=T0) == 1
    assert store.claim_session("s1", "shard-a", LEASE_S, now=T0 + 1) == 2
    with pytest.raises(SessionFenced):
        store.update_session("s1", name="from the old incarnation", epoch=1)


def test_two_owners_claiming_one_free_session_at_once_one_wins(store_url):
    """Two stores on one database, as two shards would be; a race lost by chance is raced
    again (ROUNDS sessions)."""
    with open_store(store_url) as one, open_store(store_url) as other:
        for round_ in range(ROUNDS):
            sid = f"s{round_}"
            one.create_session(record(sid))
            results = run_together(
                [
                    lambda sid=sid: one.claim_session(sid, "shard-a", LEASE_S, now=T0),
                    lambda sid=sid: other.claim_session(sid, "shard-b", LEASE_S, now=T0),
                ]
            )
            (won,) = [r for r in results if not isinstance(r, BaseException)]
            (lost,) = [r for r in results if isinstance(r, BaseException)]
            assert won == 1 and isinstance(lost, SessionHeld), results
            winner = "shard-a" if results[0] == 1 else "shard-b"
            assert lost.owner == winner
            assert (one.load_session(sid).owner, one.load_session(sid).epoch) == (winner, 1)


@pytest.mark.parametrize("lease_s", [0.0, -1.0, float("nan"), float("inf")])
def test_a_lease_that_is_not_a_positive_time_is_refused(store, lease_s):
    store.create_session(record("s1"))
    with pytest.raises(ValueError, match="lease_s"):
        store.claim_session("s1", "shard-a", lease_s, now=T0)
    assert store.load_session("s1").epoch == 0


# ---------------------------------------------------------------------- fenced writes
def test_a_commit_at_a_stale_epoch_is_fenced_and_changes_nothing(store):
    seeded(store)
    store.claim_session("s1", "shard-a", LEASE_S, now=T0)
    store.claim_session("s1", "shard-b", LEASE_S, now=T0 + 2 * LEASE_S)  # took it over: epoch 2
    before = observable(store)
    with pytest.raises(SessionFenced) as fenced:
        store.commit_keyframe(
            KeyframeCommit(
                "s1",
                3,
                [make_object(3, version=7)],
                [1],
                {"frames": 99, "keyframes": 9, "sightings": 5},
                4,
                last_used_at=2e9,
                changes=[Change(1, "removed", 9.0, "label-1")],
                last_t=9.0,
                epoch=1,
                done=("stream", 1, b"ack"),
            )
        )
    assert (fenced.value.session_id, fenced.value.epoch, fenced.value.stored_epoch) == ("s1", 1, 2)
    assert observable(store) == before


def test_a_commit_at_the_current_epoch_lands_with_its_ack(store):
    seeded(store)
    epoch = store.claim_session("s1", "shard-a", LEASE_S, now=T0)
    store.commit_keyframe(
        KeyframeCommit(
            "s1",
            3,
            [make_object(3)],
            [],
            {"keyframes": 3},
            4,
            epoch=epoch,
            done=("stream", 1, b"a"),
        )
    )
    assert [o.id for o in store.load_objects("s1")] == [1, 2, 3]
    assert store.load_session("s1").keyframes == 3
    assert store.done_ack("s1", "stream", 1) == b"a"


@pytest.mark.parametrize(
    "write",
    [
        lambda s, epoch: s.update_session("s1", name="x", counters={"frames": 9}, epoch=epoch),
        lambda s, epoch: s.update_session("s1", epoch=epoch),
        lambda s, epoch: s.trim_tombstones("s1", 2, epoch=epoch),
        lambda s, epoch: s.trim_tombstones("s1", 0, epoch=epoch),  # a trim that trims nothing
    ],
    ids=["update", "update-nothing", "trim", "trim-nothing"],
)
def test_an_update_or_trim_at_a_stale_epoch_is_fenced_and_changes_nothing(store, write):
    seeded(store)  # a tombstone at seq 2
    store.claim_session("s1", "shard-a", LEASE_S, now=T0)
    current = store.claim_session("s1", "shard-a", LEASE_S, now=T0 + 1)
    before = observable(store)
    with pytest.raises(SessionFenced):
        write(store, current - 1)
    assert observable(store) == before
    write(store, current)  # the current epoch's write lands


def test_writes_without_an_epoch_are_not_fenced(store):
    """A server that is not a map shard names no epoch."""
    seeded(store)
    store.claim_session("s1", "shard-a", LEASE_S, now=T0)
    store.update_session("s1", counters={"frames": 5})
    store.commit_keyframe(KeyframeCommit("s1", 3, [make_object(3)], [], {}, 4))
    store.trim_tombstones("s1", 2)
    assert store.load_session("s1").frames == 5 and store.load_delta_log("s1").floor == 2


@pytest.mark.parametrize(
    "call",
    [
        lambda s: s.claim_session("nope", "shard-a", LEASE_S, now=T0),
        lambda s: s.commit_keyframe(
            KeyframeCommit("nope", 1, [], [], {}, 1, epoch=1, done=("st", 1, b""))
        ),
        lambda s: s.update_session("nope", epoch=1),
        lambda s: s.trim_tombstones("nope", 0, epoch=1),
        lambda s: s.done_ack("nope", "stream", 1),
    ],
    ids=["claim", "commit", "update", "trim", "done_ack"],
)
def test_an_unknown_session_is_a_key_error(store, call):
    with pytest.raises(KeyError, match="nope"):
        call(store)


# ---------------------------------------------------------------------- leases
def test_renewing_extends_the_leases_still_held_and_names_the_others(store):
    for sid in ("kept", "taken", "gone", "released"):
        store.create_session(record(sid))
    epochs = {
        sid: store.claim_session(sid, "shard-a", LEASE_S, now=T0)
        for sid in ("kept", "taken", "gone", "released")
    }
    store.claim_session("taken", "shard-b", LEASE_S, now=T0 + 2 * LEASE_S)  # after the lease
    store.delete_session("gone")
    store.release_session("released", "shard-a", epochs["released"])

    lost = store.renew_leases("shard-a", {**epochs, "never": 1}, LEASE_S, now=T0 + 3 * LEASE_S)

    assert lost == ["taken", "gone", "released", "never"]
    assert store.load_session("kept").lease_until == T0 + 4 * LEASE_S
    taken = store.load_session("taken")
    assert (taken.owner, taken.epoch, taken.lease_until) == ("shard-b", 2, T0 + 3 * LEASE_S)
    assert store.load_session("released").owner is None
    assert store.renew_leases("shard-a", {}, LEASE_S, now=T0) == []


def test_a_lease_is_renewed_only_at_the_epoch_held(store):
    store.create_session(record("s1"))
    store.claim_session("s1", "shard-a", LEASE_S, now=T0)
    store.claim_session("s1", "shard-a", LEASE_S, now=T0 + 1)  # restarted: epoch 2
    assert store.renew_leases("shard-a", {"s1": 1}, LEASE_S, now=T0 + 5) == ["s1"]
    assert store.load_session("s1").lease_until == T0 + 1 + LEASE_S


def test_a_released_session_is_claimed_by_another_owner_at_once(store):
    store.create_session(record("s1"))
    epoch = store.claim_session("s1", "shard-a", LEASE_S, now=T0)
    store.release_session("s1", "shard-a", epoch)
    rec = store.load_session("s1")
    assert (rec.owner, rec.epoch, rec.lease_until) == (None, 1, None)
    assert store.claim_session("s1", "shard-b", LEASE_S, now=T0 + 1) == 2  # within a's lease


def test_a_release_by_an_owner_that_no_longer_holds_the_session_does_nothing(store):
    store.create_session(record("s1"))
    store.claim_session("s1", "shard-a", LEASE_S, now=T0)
    store.claim_session("s1", "shard-b", LEASE_S, now=T0 + 2 * LEASE_S)
    before = store.load_session("s1")
    store.release_session("s1", "shard-a", 1)  # the old owner, late
    store.release_session("s1", "shard-b", 1)  # the right owner, a stale epoch
    store.release_session("nope", "shard-b", 2)  # an unknown session: no error
    assert store.load_session("s1") == before


# ---------------------------------------------------------------------- remembered acks
def test_a_commit_remembers_its_ack_under_its_stream_and_seq(store):
    store.create_session(record("s1"))
    store.commit_keyframe(
        KeyframeCommit("s1", 1, [make_object(1)], [], {}, 2, done=("phone", 7, b"\x00ack 7"))
    )
    store.commit_keyframe(KeyframeCommit("s1", 1, [], [], {}, 2, done=("glasses", 7, b"ack g7")))
    assert store.done_ack("s1", "phone", 7) == b"\x00ack 7"
    assert store.done_ack("s1", "glasses", 7) == b"ack g7"
    assert store.done_ack("s1", "phone", 8) is None
    assert store.done_ack("s1", "tablet", 7) is None
    store.commit_keyframe(
        KeyframeCommit("s1", 1, [], [], {}, 2, done=("phone", 7, b"again"))
    )  # replaced
    assert store.done_ack("s1", "phone", 7) == b"again"


def test_a_malformed_done_is_refused_and_nothing_is_committed(store):
    seeded(store)
    before = observable(store)
    for done in (("stream", 1), ("stream", 1, "text, not bytes"), (1, 1, b"ack")):
        with pytest.raises(ValueError, match="done must be"):
            store.commit_keyframe(KeyframeCommit("s1", 3, [make_object(3)], [], {}, 4, done=done))
    assert observable(store) == before


def test_each_session_keeps_the_newest_window_of_acks(store):
    store.create_session(record("quiet"))
    store.create_session(record("busy"))
    store.commit_keyframe(
        KeyframeCommit("quiet", 0, [], [], {}, 1, done=("s", 0, b"quiet 0"))
    )  # the oldest ack
    for seq in range(DONE_WINDOW + 2):
        store.commit_keyframe(
            KeyframeCommit("busy", 0, [], [], {}, 1, done=("s", seq, f"busy {seq}".encode()))
        )

    assert store.done_ack("busy", "s", 0) is None and store.done_ack("busy", "s", 1) is None
    assert store.done_ack("busy", "s", 2) == b"busy 2"
    assert store.done_ack("busy", "s", DONE_WINDOW + 1) == f"busy {DONE_WINDOW + 1}".encode()
    assert store.done_ack("quiet", "s", 0) == b"quiet 0"  # another session's window


def test_deleting_a_session_forgets_its_acks(store, store_url):
    for sid in ("gone", "kept"):
        store.create_session(record(sid))
        store.commit_keyframe(KeyframeCommit(sid, 0, [], [], {}, 1, done=("stream", 1, b"ack")))
    store.delete_session("gone")
    assert query(store_url, "SELECT session_id FROM done_acks") == [("kept",)]
    store.create_session(record("gone"))
    assert store.done_ack("gone", "stream", 1) is None


# ---------------------------------------------------------------------- the shard registry
def test_shards_heard_from_recently_are_live_by_name(store):
    store.heartbeat_shard("shard-b", "http://b:8000", now=T0)
    store.heartbeat_shard("shard-a", "http://a:8000", now=T0 - 5)
    store.heartbeat_shard("shard-c", "http://c:8000", now=T0 - 5.5)
    assert store.live_shards(5.0, now=T0) == [
        ShardRecord("shard-a", "http://a:8000", T0 - 5),  # exactly max_age_s old: live
        ShardRecord("shard-b", "http://b:8000", T0),
    ]
    store.heartbeat_shard("shard-c", "http://c2:8000", now=T0 + 1)  # moved, and alive
    assert [s.url for s in store.live_shards(6.0, now=T0 + 1)] == [
        "http://a:8000",
        "http://b:8000",
        "http://c2:8000",
    ]


def test_forgetting_a_shard_lets_go_of_its_sessions_at_once(store):
    for sid in ("a1", "a2", "b1"):
        store.create_session(record(sid))
    store.claim_session("a1", "shard-a", LEASE_S, now=T0)
    store.claim_session("a2", "shard-a", LEASE_S, now=T0)
    store.claim_session("a2", "shard-a", LEASE_S, now=T0)  # epoch 2
    store.claim_session("b1", "shard-b", LEASE_S, now=T0)
    store.heartbeat_shard("shard-a", "http://a", now=T0)
    store.heartbeat_shard("shard-b", "http://b", now=T0)

    store.forget_shard("shard-a")

    assert store.live_shards(LEASE_S, now=T0) == [ShardRecord("shard-b", "http://b", T0)]
    owned = {r.session_id: (r.owner, r.epoch, r.lease_until) for r in store.list_sessions()}
    assert owned == {
        "a1": (None, 1, None),
        "a2": (None, 2, None),
        "b1": ("shard-b", 1, T0 + LEASE_S),
    }
    assert store.claim_session("a2", "shard-b", LEASE_S, now=T0 + 1) == 3  # within a's lease
    store.forget_shard("never-heard-of")  # no error


# ---------------------------------------------------------------------- creating at the limit
def test_a_creation_at_max_sessions_is_refused_and_writes_nothing(store):
    store.create_session(record("s1"), max_sessions=2)
    store.create_session(record("s2"), max_sessions=2)
    with pytest.raises(StoredSessionsLimit) as limit:
        store.create_session(record("s3"), max_sessions=2)
    assert limit.value.limit == 2
    assert [r.session_id for r in store.list_sessions()] == ["s1", "s2"]
    store.create_session(record("s3"), max_sessions=3)
    store.create_session(record("s4"))  # no limit given
    assert store.count_sessions() == 4


def test_creations_at_once_never_both_take_the_last_place(store_url):
    """Two stores on one database, as two server processes would be; a race lost by chance
    is raced again (ROUNDS times)."""
    with open_store(store_url) as one, open_store(store_url) as other:
        for round_ in range(ROUNDS):
            results = run_together(
                [
                    lambda store=store, sid=f"r{round_}-{i}": store.create_session(
                        record(sid), max_sessions=3
                    )
                    for i, store in enumerate([one, other] * 4)
                ]
            )
            assert sum(r is None for r in results) == 3, results
            assert all(r is None or isinstance(r, StoredSessionsLimit) for r in results), results
            assert one.count_sessions() == 3
            for rec in one.list_sessions():
                one.delete_session(rec.session_id)


# ---------------------------------------------------------------------- sightings
def test_the_sightings_counter_round_trips(store, store_url):
    store.create_session(record("s1", sightings=3))
    assert store.load_session("s1").sightings == 3
    store.update_session("s1", counters={"sightings": 40, "frames": 50})
    assert (store.load_session("s1").sightings, store.load_session("s1").frames) == (40, 50)
    store.commit_keyframe(KeyframeCommit("s1", 0, [], [], {"sightings": 41}, 1))
    assert store.list_sessions() == [record("s1", sightings=41, frames=50)]
    with open_store(store_url) as again:
        assert again.load_session("s1").sightings == 41


# ---------------------------------------------------------------------- from schema 4
def make_version_4_store(store_url: str) -> None:
    """An empty store as a server at schema 4 made it, holding one session."""
    if store_url.startswith("sqlite:///"):
        path = Path(store_url.removeprefix("sqlite:///"))
        path.parent.mkdir(parents=True, exist_ok=True)
        with sqlite3.connect(path) as db:
            for statement in statements(SQLITE, to_version=4):
                db.execute(statement)
            db.execute("PRAGMA user_version = 4")
    else:
        import psycopg

        with psycopg.connect(store_url) as conn:
            for statement in (postgres._VERSION_TABLE, *statements(POSTGRES, to_version=4)):
                conn.execute(statement)
            conn.execute("INSERT INTO schema_version (version) VALUES (4)")
    query(
        store_url,
        "INSERT INTO sessions (session_id, name, mode, perception, knobs, token_hash, created_at,"
        " frames, keyframes, bytes_in, bytes_out, next_object_id, seq, delta_floor, last_used_at)"
        " VALUES ('old', 'old', 'semanticxr', 'detections', '{}', 'h', 1.0, 9, 3, 0, 0, 1, 2, 0,"
        " 5.0) RETURNING session_id",
    )


def schema_version(store_url: str) -> int:
    if store_url.startswith("sqlite:///"):
        return query(store_url, "PRAGMA user_version")[0][0]
    return query(store_url, "SELECT version FROM schema_version")[0][0]


def test_a_version_4_store_opens_with_its_sessions_unowned_and_takes_claims(store_url):
    assert sqlite.SCHEMA_VERSION == postgres.SCHEMA_VERSION == 7
    make_version_4_store(store_url)
    with open_store(store_url) as store:
        rec = store.load_session("old")
        assert (rec.frames, rec.sightings, rec.owner, rec.epoch, rec.lease_until) == (
            9,
            0,
            None,
            0,
            None,
        )
        assert store.load_delta_log("old").seq == 2
        epoch = store.claim_session("old", "shard-a", LEASE_S, now=T0)
        store.commit_keyframe(
            KeyframeCommit(
                "old", 3, [], [], {"sightings": 1}, 1, epoch=epoch, done=("s", 1, b"ack")
            )
        )
        store.heartbeat_shard("shard-a", "http://a", now=T0)
    assert schema_version(store_url) == 7
    with open_store(store_url) as store:
        assert store.done_ack("old", "s", 1) == b"ack"
        assert store.load_session("old").sightings == 1
        assert store.live_shards(1.0, now=T0) == [ShardRecord("shard-a", "http://a", T0)]


def test_an_upgraded_postgresql_store_has_the_schema_a_new_one_has(pg_cluster, fresh_pg_url):
    """One path to each version: a new PostgreSQL store is made at 4 and migrated."""
    upgraded = pg_cluster.url(pg_cluster.create_database("upgraded"))
    try:
        make_version_4_store(upgraded)
        open_store(upgraded).close()
        open_store(fresh_pg_url).close()

        def schema(url: str) -> list:
            columns = query(
                url,
                "SELECT table_name, column_name, data_type, is_nullable, column_default,"
                " collation_name FROM information_schema.columns"
                " WHERE table_schema = 'public' ORDER BY 1, 2",
            )
            indexes = query(
                url,
                "SELECT indexname, indexdef FROM pg_indexes WHERE schemaname = 'public' ORDER BY 1",
            )
            return [*columns, *indexes]

        assert schema(upgraded) == schema(fresh_pg_url)
    finally:
        pg_cluster.drop_database(upgraded.rsplit("/", 1)[1])
