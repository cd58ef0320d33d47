"""bench.relevance, run small with the real encoder: both sets of wordings are reported, the
figures are the shipped rule's, and the fixed queries come out right; its fit and its
leave-one-category-out validation on answers of known standing."""

import json

import numpy as np

from app.answering.relevance import Standing, background_texts, rule_for, texts_of
from bench.relevance import (
    FALSE_MATCH_TARGET,
    cross_validate,
    figures,
    fit_rule,
    main,
    outside_wordings,
)


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
            # the background label its gap is measured against, by one of that label's texts
            rival, text = f["rival"]
            assert text in texts_of(rival, background_texts())


def _asked(rng, category: str, n: int, right_mean, absent_mean) -> list:
    from bench.relevance import Asked

    out = []
    for i in range(n):
        right = Standing(*rng.normal(right_mean, 0.5))
        absent = Standing(*rng.normal(absent_mean, 0.5))
        out.append(Asked("right", ["hit"], [right], f"{category} {i}", category))
        out.append(Asked("absent", ["other"], [absent], f"no {category} {i}", category))
    return out


def test_the_fit_keeps_false_matches_in_bounds_and_cross_validation_holds_each_category_out():
    rng = np.random.default_rng(0)
    asked = [
        a for c in range(6) for a in _asked(rng, f"c{c}", 20, [3.0, 0.0, 3.0], [1.5, 1.5, 1.0])
    ]
    # a category whose right answers stand out less than any other's: only a fit that saw it
    # can match them
    asked += _asked(rng, "odd", 20, [2.0, 1.0, 1.8], [1.5, 1.5, 1.0])
    rule = fit_rule({0.7: asked})
    got = figures(asked, rule)
    assert got["false_match_rate"] <= FALSE_MATCH_TARGET
    cv = cross_validate({0.7: asked})
    assert cv["folds"] == 7
    assert cv["right_answers"] == 140 and cv["queries_absent_or_negative"] == 140
    matched = []  # by hand: each category's right answers under the rule fitted without it
    for category in sorted({a.category for a in asked}):
        fold = fit_rule({0.7: [a for a in asked if a.category != category]})
        mine = [a for a in asked if a.category == category and a.kind == "right"]
        matched += [s.relevance(fold) >= 0.5 for a in mine for s in a.standings[:1]]
        if category == "odd":  # not seen, it is matched less than by the fit that saw it
            mine_asked = [a for a in asked if a.category == category]
            assert (
                figures(mine_asked, fold)["right_answers_match"]
                < figures(mine_asked, rule)["right_answers_match"]
            )
    assert cv["right_answers_match"] == round(sum(matched) / len(matched), 4)
