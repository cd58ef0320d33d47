"""A map's objects as a question sees them, and the hits of its answer."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

MATCH_MIN_SCORE = 0.25
"""Least score (target relevance x degrees x anchor relevances) of a best hit that answers
the question: `match` true. A mug fully on the desk scores ~1, a mug under no sofa 0."""


@dataclass(frozen=True)
class MapThing:
    """One object as a question sees it; its geometry is in the relation source under `id`."""

    id: int
    label: str
    embedding: np.ndarray
    """float32 [dim], unit."""


@dataclass(frozen=True)
class MapThings:
    """A map's objects as columns, what `answer` reads of them: a device's local map gives
    them straight from its rows, without one `MapThing` per object."""

    ids: np.ndarray
    """int64 [n], unique: each object's geometry is in the relation source under its id."""
    labels: Sequence[str]
    """The distinct labels."""
    label_of: np.ndarray
    """int [n]: each object's label, an index into `labels`."""
    cosines: Callable[[np.ndarray, np.ndarray], np.ndarray]
    """(positions int [m], query float32 [dim], unit) -> float [m]: the raw cosine of those
    objects' embeddings with the query (asked only for the few a ranking needs), each row on
    its own (`row_dots`): copies with one embedding tie exactly, and the tie goes by id."""

    def __len__(self) -> int:
        return len(self.ids)

    @classmethod
    def of(cls, things: Sequence[MapThing]) -> MapThings:
        codes: dict[str, int] = {}
        label_of = np.array([codes.setdefault(t.label, len(codes)) for t in things], np.int64)

        def cosines(positions: np.ndarray, query: np.ndarray) -> np.ndarray:
            if len(positions) == 0:
                return np.zeros(0, np.float32)
            embeddings = np.stack([things[int(i)].embedding for i in positions])
            return row_dots(embeddings.astype(np.float32), query)

        ids = np.array([t.id for t in things], np.int64)
        return cls(ids, list(codes), label_of, cosines)


def row_dots(rows: np.ndarray, vector: np.ndarray) -> np.ndarray:
    """float32 [m]: each row (float32 [m, d]) dotted with the vector (float32 [d]), a row's
    value depending on that row alone. A matrix product's rounding depends on where a row
    sits in the matrix, so two copies with one embedding could differ in the last bit and
    the tie-break by cosine would follow the rows' order, not the ids."""
    return (rows * vector).sum(axis=1, dtype=np.float32)


@dataclass(frozen=True)
class HitRelation:
    """Why a hit answers: the relation it stands in and to what."""

    kind: str
    """A relation kind (app.relations.grammar.RELATION_KINDS) or a superlative
    (SUPERLATIVE_KINDS there)."""
    anchors: list[tuple[int, str]]
    """(id, label) of each anchor; [] when measured from the asker or within the category."""
    degree: float
    """In [0, 1]: how much the hit stands in `kind` to the anchors: the relation's own
    degree, before the anchors' relevance weighs it into the score (a lamp wholly on a
    nightstand named "bedside table" is 1.0 however weakly the phrase names it)."""


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
