"""One question being answered: its phrases grounded on the map's objects (`Grounding`), and
each relation clause measured against the anchor candidates (`Clause`)."""

from __future__ import annotations

from functools import cached_property

import numpy as np

from app.answering.phrases import head_noun, same_head
from app.answering.relevance import CONFIDENT, LabelTexts, QueryRater
from app.answering.things import MapThings
from app.relations.between import between_degrees
from app.relations.bodies import Body
from app.relations.grammar import RelationClause
from app.relations.pairwise import FLOOR_WORDS, PAIRWISE_RELATIONS, on_floor_degrees, within_reach
from app.relations.source import RelationSource, floor_height
from app.relations.thresholds import THRESHOLDS
from app.relations.viewpoint import VIEWPOINT_RELATIONS, viewpoint_degrees

ANCHOR_CANDIDATES = 3
"""How many of an anchor phrase's best-rated objects a relation is weighed against (ties by
id, so the answer does not depend on the order the objects come in)."""
ANCHOR_MIN_RELEVANCE = 0.1
"""Least relevance of an anchor candidate (below it an object is not what the phrase means)."""
HEAD_NOUN_RELEVANCE = 0.75
"""Least relevance of a label to a phrase with the same head noun: "table" names the dining
table and the side table, "counter" the kitchen counter, "lamp" the floor lamp. The text
encoder rates such a label low when the vocabulary holds the bare word ("table" beats "dining
table" for the phrase "table"), yet in a question about a map the phrase means them."""


class Grounding:
    """A phrase's relevance to every object (rated per label, as a plain query's hits)."""

    def __init__(
        self,
        rater: QueryRater,
        phrase: str,
        embedding: np.ndarray,
        things: MapThings,
        label_texts: LabelTexts | None = None,
    ):
        self.embedding = embedding
        labels = list(things.labels)
        rating = rater.rate(embedding, labels, label_texts)
        by_label = np.array(
            [
                max(rated, HEAD_NOUN_RELEVANCE) if same_head(phrase, label) else rated
                for label, rated in zip(labels, rating.relevance, strict=True)
            ],
            np.float64,
        )
        self.relevance = by_label[things.label_of]
        self._ids = things.ids
        self._candidates: list[int] | None = None

    def candidates(self) -> list[int]:
        """Positions of the best-rated objects, best first, ties by id (ANCHOR_CANDIDATES at
        most, each rated at least ANCHOR_MIN_RELEVANCE)."""
        if self._candidates is None:
            relevance, n = self.relevance, len(self.relevance)
            top = min(ANCHOR_CANDIDATES, n)
            floor = float(np.partition(relevance, n - top)[n - top])
            near_top = np.flatnonzero(relevance >= max(floor, ANCHOR_MIN_RELEVANCE))
            order = np.lexsort((self._ids[near_top], -relevance[near_top]))
            self._candidates = near_top[order][:ANCHOR_CANDIDATES].tolist()
        return self._candidates

    @property
    def confident(self) -> bool:
        return bool(len(self.relevance)) and float(self.relevance.max()) >= CONFIDENT


class Question:
    """One question being answered: the map's objects, their geometry, the phrases."""

    def __init__(
        self,
        things: MapThings,
        index: RelationSource,
        rater: QueryRater,
        embeddings: dict[str, np.ndarray],
        viewer: np.ndarray | None,
        label_texts: LabelTexts | None = None,
    ):
        """label_texts: the labels' texts the rater reads (None: each label alone)."""
        self.things, self.index, self.viewer = things, index, viewer
        self.label_texts = label_texts
        self.up = index.up
        self._rater, self._embeddings = rater, embeddings
        self._groundings: dict[str, Grounding] = {}

    def embedding(self, phrase: str) -> np.ndarray:
        return self._embeddings[phrase]

    def ground(self, phrase: str) -> Grounding:
        if phrase not in self._groundings:
            self._groundings[phrase] = Grounding(
                self._rater, phrase, self.embedding(phrase), self.things, self.label_texts
            )
        return self._groundings[phrase]

    def ids(self, positions) -> np.ndarray:
        return self.things.ids[positions]

    def named(self, position: int) -> tuple[int, str]:
        if position == FLOOR_POSITION:
            return FLOOR_ANCHOR
        things = self.things
        return int(things.ids[position]), things.labels[int(things.label_of[position])]

    def is_floor(self, phrase: str) -> bool:
        """Whether the phrase means the implicit floor: its head noun is "floor" or "ground"
        and no object of the map is named so (a map holding a floor object answers by it)."""
        return head_noun(phrase) in FLOOR_WORDS and not any(
            same_head(phrase, label) for label in self.things.labels
        )

    @cached_property
    def floor(self) -> float | None:
        """The floor's height along up (`app.relations.source.floor_height` over the whole map)."""
        return floor_height(self.index, self.things.ids)


NO_ANCHOR = -1
"""No anchor (in the int64 [m, 2] anchor positions a part measures)."""
FLOOR_POSITION = -2
"""The implicit floor as an anchor position."""
FLOOR_ANCHOR = (0, "floor")
"""How a hit names the implicit floor: id 0 (no map object has it), label "floor"."""


class Part:
    """A clause or the superlative: per object, a degree in [0, 1] and the anchors it was
    measured against (positions, NO_ANCHOR where none)."""

    kind: str
    q: Question
    phrases: list[str]
    """The anchor phrases (none: the asker, or within the category)."""

    def measure(self, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(degrees float64 [m], anchor positions int64 [m, 2]) of the objects at `positions`:
        each degree weighed by its anchors' relevance (what the score multiplies)."""
        raise NotImplementedError

    def anchor_weight(self, anchors: np.ndarray) -> float:
        """The anchors' relevance a measured degree was weighed by (anchors: one row of
        anchor positions); 1 for none, the asker or the floor."""
        weight = 1.0
        for phrase, a in zip(self.phrases, anchors.tolist(), strict=False):
            if a >= 0:
                weight *= float(self.q.ground(phrase).relevance[a])
        return weight


class Clause(Part):
    """One relation clause; remembers what it measured, for the hits' explanations."""

    def __init__(self, clause: RelationClause, question: Question):
        self.kind, self.phrases, self.q = clause.kind, clause.anchors, question
        n = len(question.things)
        self._degrees = np.zeros(n)
        self._anchors = np.full((n, 2), NO_ANCHOR, np.int64)
        self._measured = np.zeros(n, bool)

    def measure(self, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if not self.phrases:
            degrees, anchors = self._from_asker(positions)
        elif self.kind == "between":
            degrees, anchors = self._between(positions)
        else:
            degrees, anchors = self._to_anchor(positions)
        self._degrees[positions], self._anchors[positions] = degrees, anchors
        self._measured[positions] = True
        return degrees, anchors

    def explain(self, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """`measure`, from memory where it was measured already."""
        missing = positions[~self._measured[positions]]
        if len(missing):
            self.measure(missing)
        return self._degrees[positions], self._anchors[positions]

    def _from_asker(self, positions):
        """The asker is the anchor ("near me"): only objects within reach of them."""
        q = self.q
        relation = PAIRWISE_RELATIONS[self.kind]
        here = Body(np.asarray(q.viewer, np.float64)[None], q.up)
        degrees = np.zeros(len(positions))
        ids = q.ids(positions)
        lo, hi = q.index.boxes(ids)
        for i in np.flatnonzero(within_reach(lo, hi, here.lo, here.hi, self.kind)).tolist():
            degrees[i] = relation(q.index.body(int(ids[i])), here, up=q.up)
        return degrees, np.full((len(positions), 2), NO_ANCHOR, np.int64)

    def _to_anchor(self, positions):
        """Best over the anchor candidates of degree x anchor relevance; an object no
        candidate satisfies names the best candidate it was weighed against."""
        q = self.q
        if q.is_floor(self.phrases[0]):
            return self._on_floor(positions)
        grounding = q.ground(self.phrases[0])
        ids = q.ids(positions)
        best = np.zeros(len(positions))
        anchors = np.full((len(positions), 2), NO_ANCHOR, np.int64)
        viewpoint = self.kind in VIEWPOINT_RELATIONS
        centroids = q.index.centroids(ids) if viewpoint else None
        for a in grounding.candidates():
            anchor_id = int(q.things.ids[a])
            if viewpoint:
                anchor_centroid = q.index.centroids([anchor_id])[0]
                degrees = viewpoint_degrees(self.kind, centroids, anchor_centroid, q.viewer, q.up)
                degrees[positions == a] = 0.0  # not to itself
            else:  # only the pairs within reach of this anchor are measured
                degrees = q.index.degrees(self.kind, anchor_id, ids)
            values = grounding.relevance[a] * degrees
            better = values > best
            best[better], anchors[better, 0] = values[better], a
        top = grounding.candidates()
        if top:  # unsatisfied: name the best anchor it was weighed against
            anchors[anchors[:, 0] == NO_ANCHOR, 0] = top[0]
        return best, anchors

    def _on_floor(self, positions):
        """On the implicit floor (`answer` lets only `on` reach it): the gap of each thing's
        bottom above the floor; boxes rule out (exactly) what starts too high to rest on it."""
        q = self.q
        degrees = np.zeros(len(positions))
        anchors = np.full((len(positions), 2), NO_ANCHOR, np.int64)
        anchors[:, 0] = FLOOR_POSITION
        floor = q.floor
        if floor is None:
            return degrees, anchors
        ids = q.ids(positions)
        lo, _ = q.index.boxes(ids)
        low = np.flatnonzero(lo[:, 2] - floor < THRESHOLDS.on_max_gap_m)
        bottoms = [body.bottom for body in q.index.bodies(ids[low])]
        degrees[low] = on_floor_degrees(np.array(bottoms, np.float64), floor)
        return degrees, anchors

    def _between(self, positions):
        q = self.q
        best = np.zeros(len(positions))
        anchors = np.full((len(positions), 2), NO_ANCHOR, np.int64)
        if len(self.phrases) != 2:
            return best, anchors
        first, second = q.ground(self.phrases[0]), q.ground(self.phrases[1])
        centroids = q.index.centroids(q.ids(positions))
        for b in first.candidates():
            for c in second.candidates():
                if b == c:
                    continue
                ends = q.index.centroids(q.ids([b, c]))
                bodies = q.index.bodies(q.ids([b, c]))
                weight = first.relevance[b] * second.relevance[c]
                values = weight * between_degrees(
                    centroids, ends[0], ends[1], q.up, (bodies[0], bodies[1])
                )
                values[(positions == b) | (positions == c)] = 0.0
                better = values > best
                best[better] = values[better]
                anchors[better] = (b, c)
        return best, anchors
