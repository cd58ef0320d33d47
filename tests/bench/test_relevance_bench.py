"""bench.relevance, run small with the real encoder: both sets of wordings are reported, the
figures are the shipped rule's, and the fixed queries come out right."""

import json

from app.answering.relevance import rule_for
from bench.relevance import main, outside_wordings


def test_reports_training_and_outside_wordings_under_the_shipped_rule(tmp_path):
    document = main(["--maps", "1", "--objects", "12", "--out", str(tmp_path)])
    assert document["rule"]["bias"] == rule_for(document["encoder"]).bias
    for name in ("training", "outside"):
        figures = document[name]
        assert figures["right_answers"] > 0 and figures["queries_absent_or_negative"] > 0
        assert 0.0 <= figures["false_match_rate"] <= 1.0
    _, negatives = outside_wordings()
    assert document["outside"]["negatives"] == len(negatives)  # every negative asked once
    assert document["fixed_queries_right"], document["fixed_queries_match"]
    assert json.loads((tmp_path / "relevance.json").read_text())["outside"] == document["outside"]
    for name in ("training", "outside"):  # the failures listed are the ones the figures count
        figures, listed = document[name], document[f"{name}_failures"]
        unmatched = sum(f["maps"] for f in listed if f["kind"] == "right_unmatched")
        false = sum(f["maps"] for f in listed if f["kind"] == "false_match")
        assert unmatched == round(figures["right_answers"] * (1 - figures["right_answers_match"]))
        assert false == round(figures["queries_absent_or_negative"] * figures["false_match_rate"])
        for f in listed:  # the hit shown is the one that says match, or the unmatched top-1
            assert (f["relevance"] >= 0.5) == (f["kind"] == "false_match")
