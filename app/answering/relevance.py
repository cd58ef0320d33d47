"""How well a query's hits answer it: a calibrated relevance in [0, 1] and a match verdict.

Raw cosine scores do not say whether anything matches: "xyzzy plugh" scores 0.33 against a
coffee maker, "the milk cold" 0.35 against the refrigerator it means. What does tell them
apart is how the query scores against a hit's *label* compared with every other label it
could have meant: the label vocabulary (the `models` backend's indoor vocabulary, a few
everyday things people lose, and the hits' own labels), all embedded by the session's
encoder. Two numbers, both in standard deviations of the query's scores over that
vocabulary, so they do not depend on the encoder's cosine scale:

- `z`: how far the hit's label stands out from the vocabulary. A real query singles out a
  few labels (z >= 3.2); a nonsense query scores them all alike (z ~ 2).
- `gap`: how far the hit's label is behind the best label of the vocabulary. "keys" on a
  map without keys finds a keyboard, but the label "keys" scores far above it (gap 5).

A hit is a confident match when z >= MATCH_MIN_Z and gap <= MATCH_MAX_GAP_Z; its relevance
is the smaller of two ramps that cross 0.5 exactly at those limits, so `relevance >= 0.5`
and "confident match" are one test. Measured with all-MiniLM-L6-v2 on the synthetic
categories' names and paraphrases: 89 % of the queries whose object is in a 20-category map
match it, 10 % of those whose object is absent match an unrelated one (`python -m
bench.relevance`). Server (SQ) and device (LQ) both rate their hits here, so both answer
alike.
"""

from __future__ import annotations

import threading
import weakref
from collections.abc import Sequence
from dataclasses import dataclass
from importlib import resources

import numpy as np

from app.semantics import TextEncoder

MATCH_MIN_Z = 3.2
"""Least standing-out (vocabulary standard deviations) of a confidently matched label."""
MATCH_MAX_GAP_Z = 2.0
"""Most a matched label may trail the query's best vocabulary label (standard deviations)."""
RAMP_Z = 1.0
"""Half-width of the z ramp: relevance goes 0 -> 1 over MATCH_MIN_Z -/+ RAMP_Z."""
RAMP_GAP_Z = 2.0
"""Half-width of the gap ramp: relevance goes 1 -> 0 over MATCH_MAX_GAP_Z -/+ RAMP_GAP_Z."""
CONFIDENT = 0.5
"""Relevance from which a hit is a confident match."""

EVERYDAY_LABELS = (
    "keys", "wallet", "phone", "glasses", "sunglasses", "watch", "charger", "earphones",
    "passport", "ring", "remote", "medicine", "shoes", "cat", "dog", "person",
)  # fmt: skip
"""Things people ask for that the indoor vocabulary lacks (or has only in the singular)."""


def background_vocabulary() -> list[str]:
    """The labels a query is weighed against: the `models` backend's vocabulary + EVERYDAY."""
    text = resources.files("app.perception.models").joinpath("vocabulary.txt").read_text("utf-8")
    tags = [line.split("#", 1)[0].strip() for line in text.splitlines()]
    return list(dict.fromkeys([t for t in tags if t] + list(EVERYDAY_LABELS)))


@dataclass(frozen=True)
class Rating:
    """The hits of one query, rated."""

    relevance: list[float]
    """Per hit, in [0, 1]; >= CONFIDENT is a confident match."""
    match: bool
    """Whether any hit is a confident match."""


def is_match(relevances: Sequence[float]) -> bool:
    """Whether hits of these relevances answer the query (one of them is confident)."""
    return any(r >= CONFIDENT for r in relevances)


class QueryRater:
    """Rates hits by their labels against the vocabulary, embedded once by `encoder`."""

    def __init__(self, encoder: TextEncoder, vocabulary: Sequence[str] | None = None):
        self.encoder = encoder
        self.vocabulary = list(vocabulary) if vocabulary is not None else background_vocabulary()
        self._vocabulary_embeddings = encoder.encode(self.vocabulary)  # [V, dim] unit rows

    def rate(self, query_embedding: np.ndarray, labels: Sequence[str]) -> Rating:
        """query_embedding: float [dim] of the query text; labels: the hits' labels, best
        first. Relevance per hit and whether any matches."""
        standing = self.standing(query_embedding, labels)
        if standing is None:  # no labels, or every label alike: nothing stands out
            return Rating([0.0] * len(labels), False)
        relevance = [relevance_of(z, gap) for z, gap in standing]
        return Rating(relevance, is_match(relevance))

    def standing(
        self, query_embedding: np.ndarray, labels: Sequence[str]
    ) -> list[tuple[float, float]] | None:
        """Per label, (z, gap) of the query's score against it, in standard deviations of
        the query's scores over the vocabulary (module docstring); None for no labels or a
        query that scores every label alike."""
        if not labels:
            return None
        query = np.asarray(query_embedding, np.float32)
        extra = [label for label in dict.fromkeys(labels) if label not in self.vocabulary]
        vocabulary_scores = self._vocabulary_embeddings @ query
        extra_scores = self.encoder.encode(extra) @ query if extra else np.zeros(0, np.float32)
        scores = np.concatenate([vocabulary_scores, extra_scores]).astype(np.float64)
        by_label = dict(zip(self.vocabulary + extra, scores.tolist(), strict=True))
        spread = float(scores.std())
        if spread < 1e-6:
            return None
        mean, best = float(scores.mean()), float(scores.max())
        return [((by_label[x] - mean) / spread, (best - by_label[x]) / spread) for x in labels]


def relevance_of(
    z: float, gap: float, min_z: float = MATCH_MIN_Z, max_gap_z: float = MATCH_MAX_GAP_Z
) -> float:
    """A label's relevance in [0, 1] from its standing (`QueryRater.standing`): the smaller
    of two ramps crossing CONFIDENT at min_z and max_gap_z."""
    stands_out = CONFIDENT + (z - min_z) / (2 * RAMP_Z)
    is_best = CONFIDENT + (max_gap_z - gap) / (2 * RAMP_GAP_Z)
    return round(float(np.clip(min(stands_out, is_best), 0.0, 1.0)), 5)


_raters: weakref.WeakKeyDictionary[TextEncoder, QueryRater] = weakref.WeakKeyDictionary()
_raters_lock = threading.Lock()


def rate_hits(encoder: TextEncoder, query_embedding: np.ndarray, labels: Sequence[str]) -> Rating:
    """`QueryRater.rate` with one rater per encoder (the vocabulary is embedded on first use,
    ~1 s with MiniLM on 2 cores; `rater_for(encoder)` ahead of time avoids the wait)."""
    return rater_for(encoder).rate(query_embedding, labels)


def rater_for(encoder: TextEncoder) -> QueryRater:
    """The encoder's rater, made (and its vocabulary embedded) on first use."""
    with _raters_lock:
        rater = _raters.get(encoder)
    if rater is None:
        rater = QueryRater(encoder)  # outside the lock: embedding the vocabulary is slow
        with _raters_lock:
            rater = _raters.setdefault(encoder, rater)
    return rater
