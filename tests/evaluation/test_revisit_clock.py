"""The revisit clock: time to update starts at the first frame that showed the evidence,
keyframe or not; the walk's bound stays on its regular keyframes."""

from __future__ import annotations

from evaluation.change_scores import ConcludedChange, score_changes
from evaluation.revisit import _true_change, _Walks
from world.changes import GroundTruthChange


def _walks(**shown) -> _Walks:
    walks = _Walks(scenario=None)  # type: ignore[arg-type]
    for name, value in shown.items():
        getattr(walks, name).update(value)
    return walks


def _change(kind: str) -> GroundTruthChange:
    return GroundTruthChange(7, kind, "laptop", (1.0, 0.0, 0.8), None, 600.0)


def test_a_removal_is_timed_from_the_first_frame_showing_its_empty_place():
    # frames at 0.2 s: the empty place first shows at 700.4 (between keyframes 700 and 701)
    walks = _walks(
        old_place_first_frame_t={7: 700.4},
        old_place_shown_t={7: [701.0, 702.0, 703.0, 704.0]},
    )
    true = _true_change(walks, _change("removed"), key=0, min_evidence=3)
    assert true.t_evidence == 700.4
    assert true.t_bound == 703.0  # the third regular keyframe that showed it
    scores = score_changes([ConcludedChange(7, "removed", 703.0)], [true])
    assert scores["time_to_update_s"]["p50"] == 703.0 - 700.4
    assert scores["matched"][0]["t_evidence"] == 700.4


def test_a_place_shown_only_between_keyframes_still_starts_the_clock():
    walks = _walks(old_place_first_frame_t={7: 650.6})
    true = _true_change(walks, _change("removed"), key=0, min_evidence=3)
    assert true.t_evidence == 650.6 and true.t_bound == 650.6


def test_a_move_is_timed_from_when_both_places_were_shown():
    walks = _walks(
        old_place_first_frame_t={7: 610.2},
        new_place_first_frame_t={7: 612.8},
        old_place_shown_t={7: [611.0]},
        new_place_seen_t={7: 613.0},
    )
    true = _true_change(walks, _change("moved"), key=0, min_evidence=3)
    assert (true.t_evidence, true.t_bound) == (612.8, 613.0)


def test_a_change_never_shown_has_no_time():
    true = _true_change(_walks(), _change("removed"), key=0, min_evidence=3)
    assert true.t_evidence is None and true.t_bound is None
