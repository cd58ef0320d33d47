"""Re-ranking a static tower's answer with the tower it was distilled from.

A static text tower (app.semantics.static) answers in microseconds on every end, a few
points below its teacher on paraphrases (docs/evaluation.md "Text towers"). A device that
reaches the server may ask it to re-rank: the static tower's best RERANK_POOL objects are
ranked again by the teacher (MiniLM) over their labels, and rated by the teacher's match
rule. The answer says which tower ranked it (`ranked_by`), so nobody compares a re-ranked
answer with a local one as if they were alike.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from app.answering.relevance import LabelTexts, Rating, rate_hits
from app.semantics import TextEncoder

RERANK_POOL = 20
"""How many of the static tower's best objects the teacher ranks again."""


@dataclass(frozen=True)
class Reranked:
    order: list[int]
    """Positions in the candidates, best first (at most k)."""
    scores: list[float]
    """The teacher's cosine of each, in that order."""
    rating: Rating
    """The teacher's rating of those hits."""


def rerank(
    teacher: TextEncoder,
    text: str,
    labels: Sequence[str],
    k: int,
    label_texts: LabelTexts | None = None,
) -> Reranked:
    """The candidates (their labels, the static tower's best first) ranked by the teacher's
    cosine of the question with each label, ties by the static order."""
    if not labels:
        return Reranked([], [], Rating([], False))
    query = teacher.encode_query(text)
    scores = teacher.encode(list(labels)) @ query  # labels are cached by the encoder
    order = sorted(range(len(labels)), key=lambda i: (-float(scores[i]), i))[:k]
    ranked = [labels[i] for i in order]
    return Reranked(
        order,
        [float(np.float32(scores[i])) for i in order],
        rate_hits(teacher, query, ranked, label_texts),
    )
