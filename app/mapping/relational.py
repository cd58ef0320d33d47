"""Answering a question about how things stand: "the mug on the desk" (issue 27).

A reading (app.mapping.grammar) names a target phrase, relation clauses with anchor phrases
and perhaps a superlative. Each phrase is grounded with today's ranking (its text embedding
against the objects' embeddings, rated by app.mapping.relevance), then every object of the
map is scored

    score = target relevance x prod over clauses(max over anchor candidates of
            relation degree x anchor relevance) x superlative degree

so the whole target category is weighed against the top anchors, not only today's top k,
and a slightly wrong anchor reading still ranks sensibly. Pure: numpy, the grammar, the
relation index and a text encoder; the server and the device's local map both call it.

Plain questions stay plain: `answer` returns None (the caller answers as today) when the
reading has no relation or superlative, when an anchor phrase grounds to no confident map
object (relevance >= app.mapping.relevance.CONFIDENT: "keys on a ring" with no ring), when a
viewpoint relation or a superlative from the asker has no asker's position, or when a
relation to the asker ("on my left") needs an anchor the map cannot supply.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from app.mapping.grammar import Reading, is_relational
from app.mapping.relations import (
    PAIRWISE_RELATIONS,
    SUPERLATIVES,
    VIEWPOINT_RELATIONS,
    RelationIndex,
    between,
)
from app.mapping.relevance import CONFIDENT, rater_for
from app.semantics import TextEncoder

ANCHOR_CANDIDATES = 3
"""How many of an anchor phrase's best-rated objects a relation is weighed against."""
ANCHOR_MIN_RELEVANCE = 0.1
"""Least relevance of an anchor candidate (below it an object is not what the phrase means)."""
HEAD_NOUN_RELEVANCE = 0.75
"""Least relevance of a label to a phrase with the same head noun: "table" names the dining
table and the side table, "counter" the kitchen counter, "lamp" the floor lamp. The text
encoder rates such a label low when the vocabulary holds the bare word ("table" beats "dining
table" for the phrase "table"), yet in a question about a map the phrase means them."""
MATCH_MIN_SCORE = 0.25
"""Least score (target relevance x degrees x anchor relevances) of a best hit that answers
the question: `match` true. A mug fully on the desk scores ~1, a mug under no sofa 0."""


@dataclass(frozen=True)
class MapThing:
    """One object as a question sees it; its geometry is in the RelationIndex under `id`."""

    id: int
    label: str
    embedding: np.ndarray
    """float32 [dim], unit."""


@dataclass(frozen=True)
class HitRelation:
    """Why a hit answers: the relation it stands in and to what."""

    kind: str
    """A relation kind (grammar.RELATION_KINDS) or a superlative (grammar.SUPERLATIVE_KINDS)."""
    anchors: list[tuple[int, str]]
    """(id, label) of each anchor; [] when measured from the asker or within the category."""
    degree: float
    """In [0, 1]: how much the hit stands in `kind` to the anchors."""


@dataclass(frozen=True)
class RelationalHit:
    id: int
    label: str
    score: float
    """In [0, 1]: target relevance x relation degrees x anchor relevances; what ranks hits."""
    relevance: float
    """In [0, 1]: the target phrase's rated relevance to this object's label (1 for an
    unspecified target: "what is on the table")."""
    cosine: float
    """Raw cosine of the target phrase (the whole question for an unspecified target)."""
    relation: HitRelation


def is_match(hits: Sequence[RelationalHit]) -> bool:
    """Whether the best hit answers the question (score >= MATCH_MIN_SCORE)."""
    return bool(hits) and hits[0].score >= MATCH_MIN_SCORE


class _Grounding:
    """A phrase's relevance to every object (rated per label, as a plain query's hits)."""

    def __init__(self, encoder: TextEncoder, phrase: str, things: Sequence[MapThing]):
        self.embedding = encoder.encode_query(phrase).astype(np.float32)
        labels = list(dict.fromkeys(t.label for t in things))
        rating = rater_for(encoder).rate(self.embedding, labels)
        by_label = {
            label: max(rated, HEAD_NOUN_RELEVANCE) if same_head(phrase, label) else rated
            for label, rated in zip(labels, rating.relevance, strict=True)
        }
        self.relevance = np.array([by_label[t.label] for t in things], np.float64)

    def candidates(self) -> list[int]:
        """Indices of the best-rated objects, best first (ANCHOR_CANDIDATES at most)."""
        order = np.argsort(-self.relevance, kind="stable")[:ANCHOR_CANDIDATES]
        return [int(i) for i in order if self.relevance[i] >= ANCHOR_MIN_RELEVANCE]

    @property
    def confident(self) -> bool:
        return bool(len(self.relevance)) and float(self.relevance.max()) >= CONFIDENT


def answer(
    reading: Reading,
    things: Sequence[MapThing],
    index: RelationIndex,
    encoder: TextEncoder,
    viewer: np.ndarray | None = None,
    k: int = 5,
) -> list[RelationalHit] | None:
    """The top-k objects answering a relational reading, best first; None when the caller
    should answer as a plain query (see the module docstring).

    things: the map's objects, each with its points in `index` (same ids, same up axis);
    viewer: the asker's position float [3], metres, world frame (None: unknown).
    """
    if not is_relational(reading) or not things or k <= 0:
        return None
    groundings: dict[str, _Grounding] = {}

    def ground(phrase: str) -> _Grounding:
        if phrase not in groundings:
            groundings[phrase] = _Grounding(encoder, phrase, things)
        return groundings[phrase]

    anchor_phrases = [a for c in reading.relations for a in c.anchors]
    if reading.superlative is not None:
        anchor_phrases += reading.superlative.anchors
    if not all(ground(a).confident for a in anchor_phrases):
        return None
    needs_viewer = any(c.kind in VIEWPOINT_RELATIONS or not c.anchors for c in reading.relations)
    sup = reading.superlative
    needs_viewer |= sup is not None and sup.kind in ("closest", "farthest") and not sup.anchors
    if needs_viewer and viewer is None:
        return None
    if any(c.kind in VIEWPOINT_RELATIONS and not c.anchors for c in reading.relations):
        return None  # "on my left": left of what? not read yet

    n = len(things)
    if reading.any_target:
        target = np.ones(n)
        target_embedding = encoder.encode_query(_question(reading)).astype(np.float32)
    else:
        grounding = ground(reading.target)
        target, target_embedding = grounding.relevance, grounding.embedding
    cosine = np.stack([t.embedding for t in things]).astype(np.float32) @ target_embedding

    score = target.copy()
    explained: list[list[HitRelation]] = [[] for _ in range(n)]
    for clause in reading.relations:
        degrees, anchors = _clause(clause.kind, clause.anchors, things, index, ground, viewer)
        score *= degrees
        for i in range(n):
            explained[i].append(HitRelation(clause.kind, anchors[i], float(degrees[i])))
    if sup is not None:
        degrees, anchors = _superlative(
            sup.kind, sup.anchors, target, things, index, ground, viewer
        )
        score *= degrees
        for i in range(n):
            explained[i].append(HitRelation(sup.kind, anchors[i], float(degrees[i])))

    order = sorted(range(n), key=lambda i: (-score[i], -target[i], -cosine[i], things[i].id))
    return [
        RelationalHit(
            id=things[i].id,
            label=things[i].label,
            score=float(score[i]),
            relevance=float(target[i]),
            cosine=float(cosine[i]),
            relation=explained[i][0],
        )
        for i in order[:k]
    ]


_IRREGULAR_PLURALS = {
    "shelves": "shelf", "knives": "knife", "people": "person", "boxes": "box", "glasses":
    "glasses", "dishes": "dish", "benches": "bench", "couches": "couch", "watches": "watch",
}  # fmt: skip


def head_noun(phrase: str) -> str:
    """The last word of a phrase, lower case, a plural's s dropped ("dining tables" ->
    "table"; "glass" and "bus" keep theirs)."""
    words = phrase.lower().split()
    if not words:
        return ""
    word = words[-1]
    if word in _IRREGULAR_PLURALS:
        return _IRREGULAR_PLURALS[word]
    if word.endswith("ies") and len(word) > 4:
        return word[:-3] + "y"
    if word.endswith("s") and not word.endswith(("ss", "us", "is")) and len(word) > 3:
        return word[:-1]
    return word


def same_head(phrase: str, label: str) -> bool:
    """Whether a phrase and a label end in the same noun ("the table" and "dining table")."""
    head = head_noun(phrase)
    return bool(head) and head == head_noun(label)


def _question(reading: Reading) -> str:
    """Words for an unspecified target's cosine: the anchors ("on the table" -> "table")."""
    clauses = [" ".join(c.anchors) for c in reading.relations]
    return " ".join(clauses) or "object"


def _clause(kind, anchor_phrases, things, index, ground, viewer):
    """Per object: the best over anchor candidates of degree x anchor relevances, and those
    anchors as (id, label)."""
    n = len(things)
    best = np.zeros(n)
    best_anchors: list[list[tuple[int, str]]] = [[] for _ in range(n)]
    if not anchor_phrases:  # the asker is the anchor: "near me"
        fn = PAIRWISE_RELATIONS[kind]
        here = np.asarray(viewer, np.float64)[None]
        for i, t in enumerate(things):
            best[i] = fn(index.body(t.id), here, up=index.up)
        return best, best_anchors
    groundings = [ground(p) for p in anchor_phrases]
    if kind == "between" and len(groundings) == 2:
        for b in groundings[0].candidates():
            for c in groundings[1].candidates():
                if b == c:
                    continue
                weight = groundings[0].relevance[b] * groundings[1].relevance[c]
                for i, t in enumerate(things):
                    if i in (b, c):
                        continue
                    value = weight * between(
                        index.body(t.id),
                        index.body(things[b].id),
                        index.body(things[c].id),
                        up=index.up,
                    )
                    if value > best[i]:
                        best[i] = value
                        best_anchors[i] = [_named(things[b]), _named(things[c])]
        return best, best_anchors
    grounding = groundings[0]
    position = {t.id: i for i, t in enumerate(things)}
    for a in grounding.candidates():
        weight = grounding.relevance[a]
        anchor = things[a]
        if kind in VIEWPOINT_RELATIONS:
            fn = VIEWPOINT_RELATIONS[kind]
            values = [
                (i, fn(index.body(t.id), index.body(anchor.id), viewer, up=index.up))
                for i, t in enumerate(things)
                if i != a
            ]
        else:  # only this anchor's pairs are computed
            subjects, _, degrees = index.pairs(kind, anchor=anchor.id)  # type: ignore[arg-type]
            values = [
                (position[s], d)
                for s, d in zip(subjects.tolist(), degrees.tolist(), strict=True)
                if s in position
            ]
        for i, degree in values:
            if weight * degree > best[i]:
                best[i] = weight * degree
                best_anchors[i] = [_named(anchor)]
    top = grounding.candidates()
    for i in range(n):  # unsatisfied: name the best anchor it was weighed against
        if not best_anchors[i] and top:
            best_anchors[i] = [_named(things[top[0]])]
    return best, best_anchors


def _superlative(kind, anchor_phrases, target, things, index, ground, viewer):
    """Per object: its superlative degree within the target category (objects rated as
    confident targets; every object when the target is unspecified), 0 outside it."""
    n = len(things)
    degrees = np.zeros(n)
    anchors: list[list[tuple[int, str]]] = [[] for _ in range(n)]
    category = [i for i in range(n) if target[i] >= CONFIDENT]
    if not category:
        return degrees, anchors
    bodies = [index.body(things[i].id) for i in category]
    fn = SUPERLATIVES[kind]
    if kind in ("closest", "farthest"):
        if anchor_phrases:
            grounding = ground(anchor_phrases[0])
            for a in grounding.candidates():
                if a in category:
                    continue
                values = grounding.relevance[a] * fn(index.body(things[a].id), bodies, up=index.up)
                for j, i in enumerate(category):
                    if values[j] > degrees[i]:
                        degrees[i], anchors[i] = values[j], [_named(things[a])]
            return degrees, anchors
        values = fn(np.asarray(viewer, np.float64), bodies, up=index.up)
    else:
        values = fn(bodies, up=index.up)
    degrees[category] = values
    return degrees, anchors


def _named(thing: MapThing) -> tuple[int, str]:
    return (thing.id, thing.label)
