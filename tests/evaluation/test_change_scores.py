"""The revisit metrics: a change counts when object and kind are right, each truth once."""

from __future__ import annotations

import pytest

from evaluation.change_scores import ConcludedChange, TrueChange, score_changes, wilson_lower


def test_right_object_and_kind_count_once_added_apart():
    truth = [
        TrueChange(1, "moved", 10.0),
        TrueChange(2, "removed", 20.0),
        TrueChange(3, "added", 30.0),
    ]
    concluded = [
        ConcludedChange(1, "moved", 12.0),
        ConcludedChange(1, "moved", 13.0),  # the same change twice: the second is wrong
        ConcludedChange(2, "moved", 21.0),  # right object, wrong kind
        ConcludedChange(None, "removed", 5.0),  # matched nothing
        ConcludedChange(3, "added", 31.5),
    ]
    scores = score_changes(concluded, truth)
    assert scores["precision"] == pytest.approx(1 / 4)
    assert scores["recall"] == pytest.approx(1 / 2)
    assert scores["time_to_update_s"]["p50"] == pytest.approx(2.0)
    assert scores["added"]["precision"] == 1.0 and scores["added"]["recall"] == 1.0
    assert scores["added"]["time_to_update_s"]["p50"] == pytest.approx(1.5)
    assert [m["instance"] for m in scores["matched"]] == [1]
    assert scores["matched"][0]["delay_s"] == pytest.approx(2.0)
    assert scores["missed"] == [{"instance": 2, "kind": "removed", "t_evidence": 20.0}]


def test_nothing_concluded_is_perfect_precision_and_no_recall():
    scores = score_changes([], [TrueChange(1, "removed", 0.0)])
    assert scores["precision"] == 1.0 and scores["recall"] == 0.0 and scores["f1"] == 0.0


def test_wilson_lower_bound_is_below_the_rate_and_tightens_with_trials():
    assert wilson_lower(0, 0) == 0.0
    assert wilson_lower(10, 10) < 1.0
    assert wilson_lower(95, 100) < 0.95 < wilson_lower(950, 1000) + 0.03
    assert wilson_lower(60, 60) > wilson_lower(12, 12)


def test_the_walks_bound_splits_the_time_to_update():
    # the empty place first shown at 10 s, shown the third time at 16 s (the walk looked
    # away), concluded at 17 s: 7 s to update, 6 s of it the walk's, 1 s the map's
    truth = [TrueChange(1, "removed", 10.0, 16.0), TrueChange(2, "moved", 20.0)]
    concluded = [ConcludedChange(1, "removed", 17.0), ConcludedChange(2, "moved", 21.0)]
    scores = score_changes(concluded, truth)
    assert sorted(m["delay_s"] for m in scores["matched"]) == [1.0, 7.0]
    assert scores["walk_bound_s"]["p50"] == pytest.approx(3.0)  # of 6 and 0
    assert scores["beyond_walk_bound_s"]["p50"] == pytest.approx(1.0)  # of 1 and 1
    assert scores["beyond_walk_bound_s"]["p95"] == pytest.approx(1.0)
