"""Answering a question about how things stand: "the mug on the desk". The parts:

A reading (app.relations.grammar) names a target phrase, relation clauses with anchor phrases
and perhaps a superlative. Each phrase is grounded with today's ranking (its text embedding
against the objects' embeddings, rated by app.answering.relevance), then every object of the
map is scored

    score = target relevance x prod over clauses(max over anchor candidates of
            relation degree x anchor relevance) x superlative degree

so the whole target category is weighed against the top anchors, not only today's top k,
and a slightly wrong anchor reading still ranks sensibly. Pure: numpy, the grammar, the
relation source and a text encoder; the server (`RelationIndex`) and the device's local map
(`OnDemandRelations`) both call it, so both answer alike.

Plain questions stay plain: `answer` returns None (the caller answers as today) when the
reading has no relation or superlative, when an anchor phrase grounds to no confident map
object (relevance >= app.answering.relevance.CONFIDENT: "keys on a ring" with no ring), when a
viewpoint relation or a superlative from the asker has no asker's position, or when a
relation to the asker ("on my left") needs an anchor the map cannot supply.

The floor is an implicit surface: "the bag on the floor" (or "on the ground") is measured
against the lowest bottom of the map's objects (`app.relations.source.floor_height`) when no object is
named floor; a hit names it FLOOR_ANCHOR, id 0. Only `on` reads it; any other relation to
the floor answers plain.

What a question costs (a device asks it of 10k objects): the phrases are embedded in one
encoder call (labels come from its cache); relevance is rated per label; a clause is
measured only for the objects its target may be (relevance above 0), pairwise relations only
within reach of the anchors' boxes, and viewpoint and `between` relations from centroids in
one numpy pass; a superlative over a category measures the members whose box bounds say they
may rank in the top k (closest, farthest, biggest); the raw cosine (a tie-break) only for the
objects tied near the top. The answer is the one measuring everything would give.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from app.answering.phrases import anchor_phrases_of, phrases_of, target_phrase_of
from app.answering.question import NO_ANCHOR, Clause, Question
from app.answering.relevance import LabelTexts, rater_for
from app.answering.superlative import SuperlativePart
from app.answering.things import HitRelation, MapThing, MapThings, RelationalHit
from app.relations.grammar import Reading, is_relational
from app.relations.source import RelationSource
from app.relations.viewpoint import VIEWPOINT_RELATIONS
from app.semantics import TextEncoder


def answer(
    reading: Reading,
    things: Sequence[MapThing] | MapThings,
    index: RelationSource,
    encoder: TextEncoder,
    viewer: np.ndarray | None = None,
    k: int = 5,
    label_texts: LabelTexts | None = None,
) -> list[RelationalHit] | None:
    """The top-k objects answering a relational reading, best first; None when the caller
    should answer as a plain query (see the module docstring). label_texts: the labels'
    texts the phrases are rated against (app.answering.relevance; None: each label alone).

    things: the map's objects (in any order), each with its geometry in `index` under its id
    (same up axis); viewer: the asker's position float [3], metres, world frame (None:
    unknown).
    """
    if not is_relational(reading) or not len(things) or k <= 0:
        return None
    if not isinstance(things, MapThings):
        things = MapThings.of(things)
    sup = reading.superlative
    anchor_phrases = anchor_phrases_of(reading)
    target_phrase = target_phrase_of(reading)
    phrases = phrases_of(reading)
    embedded = encoder.encode(phrases).astype(np.float32)  # one call; labels are cached
    q = Question(
        things,
        index,
        rater_for(encoder),
        dict(zip(phrases, embedded, strict=True)),
        viewer,
        label_texts,
    )
    if not all(q.is_floor(a) or q.ground(a).confident for a in anchor_phrases):
        return None
    if _floor_elsewhere(reading, q):
        return None  # only "on the floor" is read: "under the floor", "closest to the ground"
    needs_viewer = any(c.kind in VIEWPOINT_RELATIONS or not c.anchors for c in reading.relations)
    needs_viewer |= sup is not None and sup.kind in ("closest", "farthest") and not sup.anchors
    if needs_viewer and viewer is None:
        return None
    if any(c.kind in VIEWPOINT_RELATIONS and not c.anchors for c in reading.relations):
        return None  # "on my left": left of what? not read yet

    n = len(things)
    if reading.any_target:  # "what is on the table": anything but the anchors' like
        target = np.ones(n)
        target[np.isin(things.label_of, _anchor_labels(q, anchor_phrases))] = 0.0
    else:
        target = q.ground(reading.target).relevance
    score = target.copy()
    live = np.flatnonzero(target > 0)  # an object the target cannot be scores 0 whatever
    clauses = [Clause(c, q) for c in reading.relations]
    for clause in clauses:
        degrees, _ = clause.measure(live)
        score[live] *= degrees
        live = live[score[live] > 0]
    superlative = None
    if sup is not None:
        superlative = SuperlativePart(sup, target, q)
        score = superlative.apply(score, min(k, n))

    query = q.embedding(target_phrase)
    label_cosine = np.asarray(encoder.encode(list(things.labels)), np.float32) @ query
    top, cosine = _top(score, target, things, query, label_cosine, k)
    explaining: Clause | SuperlativePart = clauses[0] if clauses else superlative  # type: ignore[assignment]
    degrees, anchors = explaining.explain(top)
    hits = []
    for i, position in enumerate(top.tolist()):
        named = [q.named(int(a)) for a in anchors[i] if a != NO_ANCHOR]
        weight = explaining.anchor_weight(anchors[i])
        degree = min(1.0, float(degrees[i]) / weight) if weight > 0 else float(degrees[i])
        hits.append(
            RelationalHit(
                id=int(things.ids[position]),
                label=things.labels[int(things.label_of[position])],
                score=float(score[position]),
                relevance=float(target[position]),
                cosine=float(cosine[i]),
                relation=HitRelation(explaining.kind, named, degree),
            )
        )
    return hits


def _anchor_labels(q: Question, anchor_phrases: list[str]) -> np.ndarray:
    """Label codes of the anchor phrases' candidates: a thing of the anchor's own label is a
    piece of it (a bookcase mapped as two objects), not what stands on or in it."""
    codes = {
        int(q.things.label_of[a])
        for phrase in anchor_phrases
        if not q.is_floor(phrase)
        for a in q.ground(phrase).candidates()
    }
    return np.array(sorted(codes), np.int64)


def _floor_elsewhere(reading: Reading, q: Question) -> bool:
    """Whether the implicit floor is named anywhere but as the one anchor of `on`."""
    for clause in reading.relations:
        floors = [q.is_floor(a) for a in clause.anchors]
        if any(floors) and (clause.kind != "on" or len(floors) != 1):
            return True
    sup = reading.superlative
    return sup is not None and any(q.is_floor(a) for a in sup.anchors)


TIE_COSINE_DECIMALS = 2
"""Copies tied in score and relevance go by their own embedding's cosine to these decimals,
then by id: finer differences are float noise on the server and 8-bit rounding on the
device (up to ~0.002), and must not order the same answer differently on the two ends."""


def _top(
    score: np.ndarray,
    target: np.ndarray,
    things: MapThings,
    query: np.ndarray,
    label_cosine: np.ndarray,
    k: int,
) -> tuple[np.ndarray, np.ndarray]:
    """(positions int64 [<= k], their cosines): the k best by score, then target relevance,
    then the cosine of their label's text (the same on every end), then their own cosine
    (TIE_COSINE_DECIMALS), then id; own cosines only for the objects tied near the top."""
    n = len(score)
    k = min(k, n)
    kth_score = np.partition(score, n - k)[n - k]
    ahead = np.flatnonzero(score > kth_score)
    tied = np.flatnonzero(score == kth_score)
    needed = k - len(ahead)
    if needed < len(tied):
        kth_target = np.partition(target[tied], len(tied) - needed)[len(tied) - needed]
        tied = tied[target[tied] >= kth_target]
    candidates = np.concatenate([ahead, tied])
    cosine = np.asarray(things.cosines(candidates, query), np.float32)
    own = np.round(cosine.astype(np.float64), TIE_COSINE_DECIMALS)
    by_label = label_cosine[things.label_of[candidates]]
    keys = (things.ids[candidates], -own, -by_label, -target[candidates], -score[candidates])
    order = np.lexsort(keys)[:k]  # the last key first
    return candidates[order], cosine[order]
