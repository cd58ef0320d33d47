"""The delta log, specified against a model: the newest change of every id after S."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from app.mapping.deltas import DeltaLog

ops = st.lists(
    st.tuples(st.sets(st.integers(1, 12), max_size=4), st.sets(st.integers(1, 12), max_size=2)),
    max_size=30,
)


@settings(max_examples=150, deadline=None)
@given(history=ops, data=st.data())
def test_delta_since_s_is_exactly_what_changed_after_s(history, data):
    log = DeltaLog()
    last_op: dict[int, tuple[int, str]] = {}  # id -> (seq, "up" | "rm")
    for upserted, removed in history:
        seq = log.commit(upserted, removed)
        for oid in upserted - removed:
            last_op[oid] = (seq, "up")
        for oid in removed:
            last_op[oid] = (seq, "rm")
    since = data.draw(st.integers(0, log.seq))
    delta = log.since(since)
    assert not delta.full and delta.seq == log.seq
    assert delta.upserts == sorted(i for i, (s, op) in last_op.items() if s > since and op == "up")
    assert delta.removed == sorted(i for i, (s, op) in last_op.items() if s > since and op == "rm")


@settings(max_examples=100, deadline=None)
@given(history=ops)
def test_applying_deltas_in_any_chunks_reproduces_the_live_set(history):
    log, held, applied = DeltaLog(), set(), 0
    for i, (upserted, removed) in enumerate(history):
        log.commit(upserted, removed)
        if i % 3 == 0:  # a subscriber that syncs now and then
            delta = log.since(applied)
            held = (held | set(delta.upserts)) - set(delta.removed)
            applied = delta.seq
    delta = log.since(applied)
    held = (held | set(delta.upserts)) - set(delta.removed)
    assert held == set(log.live_ids())


def test_empty_commits_do_not_advance_the_seq():
    log = DeltaLog()
    assert log.commit([1]) == 1 and log.commit() == 1 and log.commit([], []) == 1


def test_a_subscriber_older_than_the_kept_history_gets_a_full_snapshot():
    log = DeltaLog(max_tombstones=4)
    log.commit([1, 2, 3])
    for oid in range(10, 20):
        log.commit([oid])
        log.commit([], [oid])
    assert log.floor > 1
    delta = log.since(1)
    assert delta.full and delta.upserts == [1, 2, 3] and delta.removed == []
    assert log.since(None).full and log.since(log.seq + 5).full


def test_state_round_trips():
    log = DeltaLog()
    log.commit([1, 2])
    log.commit([3], [1])
    again = DeltaLog.from_state(log.state())
    assert again.since(0) == log.since(0) and again.since(1) == log.since(1)
