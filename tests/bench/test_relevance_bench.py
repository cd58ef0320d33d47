"""bench.relevance, run small with the real encoder: the match curve's shape and that its
"today" point is the rate the service's own limits give."""

import json

from app.answering.relevance import MATCH_MAX_GAP_Z, MATCH_MIN_Z
from bench.relevance import main


def test_curve_holds_todays_point_and_moves_the_right_way(tmp_path):
    document = main(["--maps", "1", "--objects", "8", "--out", str(tmp_path)])
    curve = document["curve"]
    today = [p for p in curve if p["today"]]
    assert len(today) == 1
    assert (today[0]["min_z"], today[0]["max_gap_z"]) == (MATCH_MIN_Z, MATCH_MAX_GAP_Z)
    assert today[0]["right_answers_match"] == document["right_answers_match"]
    # the curve rates the top-1 answer; the service's `match` any of the top 5
    assert today[0]["false_match_rate"] <= document["false_match_rate"]
    by_limits = {(p["min_z"], p["max_gap_z"]): p for p in curve}
    for (min_z, gap), point in by_limits.items():  # looser limits never match less
        looser = by_limits.get((min_z, gap + 0.5))
        if looser is not None:
            assert looser["right_answers_match"] >= point["right_answers_match"]
            assert looser["false_match_rate"] >= point["false_match_rate"]
    assert json.loads((tmp_path / "relevance.json").read_text())["curve"] == curve
