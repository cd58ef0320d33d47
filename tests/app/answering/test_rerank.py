"""Re-ranking a static tower's candidates with its teacher (app/answering/rerank.py)."""

from __future__ import annotations

from app.answering.rerank import rerank


def test_the_teacher_ranks_the_candidates_again_and_rates_them(encoder):
    # the static tower put the lamp first; the teacher ranks the bed first
    got = rerank(encoder, "where can I sleep tonight", ["lamp", "sofa", "bed"], k=2)
    assert got.order[0] == 2 and len(got.order) == 2
    assert got.scores[0] >= got.scores[1]
    assert len(got.rating.relevance) == 2
    assert got.rating.match


def test_equal_scores_keep_the_static_order(encoder):
    got = rerank(encoder, "a chair", ["chair", "chair", "table"], k=3)
    assert got.order[:2] == [0, 1]


def test_no_candidates_no_answer(encoder):
    got = rerank(encoder, "a chair", [], k=3)
    assert got.order == [] and not got.rating.match
