"""Answering a question about how things stand: "the mug on the desk" (issue 27).

A reading (app.mapping.grammar) names a target phrase, relation clauses with anchor phrases
and perhaps a superlative. Each phrase is grounded with today's ranking (its text embedding
against the objects' embeddings, rated by app.mapping.relevance), then every object of the
map is scored

    score = target relevance x prod over clauses(max over anchor candidates of
            relation degree x anchor relevance) x superlative degree

so the whole target category is weighed against the top anchors, not only today's top k,
and a slightly wrong anchor reading still ranks sensibly. Pure: numpy, the grammar, the
relation source and a text encoder; the server (`RelationIndex`) and the device's local map
(`OnDemandRelations`) both call it, so both answer alike.

Plain questions stay plain: `answer` returns None (the caller answers as today) when the
reading has no relation or superlative, when an anchor phrase grounds to no confident map
object (relevance >= app.mapping.relevance.CONFIDENT: "keys on a ring" with no ring), when a
viewpoint relation or a superlative from the asker has no asker's position, or when a
relation to the asker ("on my left") needs an anchor the map cannot supply.

The floor is an implicit surface: "the bag on the floor" (or "on the ground") is measured
against the lowest bottom of the map's objects (`relations.floor_height`) when no object is
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

import heapq
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from app.mapping.grammar import Reading, RelationClause, Superlative, is_relational
from app.mapping.relations import (
    FLOOR_WORDS,
    ON_MAX_GAP_M,
    PAIRWISE_RELATIONS,
    VIEWPOINT_RELATIONS,
    Body,
    RelationSource,
    between_degrees,
    biggest_degrees,
    box_distance_bounds,
    boxes_in_up_frame,
    closest_degrees,
    distance_to,
    farthest_degrees,
    floor_height,
    heights_along,
    highest_degrees,
    lowest_degrees,
    on_floor_degrees,
    smallest_degrees,
    viewpoint_degrees,
    volume_upper_bounds,
    within_reach,
)
from app.mapping.relevance import CONFIDENT, QueryRater, rater_for
from app.semantics import TextEncoder

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
CATEGORY_MIN_RELEVANCE = 0.25
"""Least relevance of the best-rated object for a weakly named target to have a category
("bag" rates backpacks 0.35 with MiniLM; below this nothing is what the phrase names)."""
CATEGORY_MARGIN = 0.2
"""A superlative's category holds the objects rated within this of the best-rated one."""
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
    """A relation kind (grammar.RELATION_KINDS) or a superlative (grammar.SUPERLATIVE_KINDS)."""
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


class _Grounding:
    """A phrase's relevance to every object (rated per label, as a plain query's hits)."""

    def __init__(self, rater: QueryRater, phrase: str, embedding: np.ndarray, things: MapThings):
        self.embedding = embedding
        labels = list(things.labels)
        rating = rater.rate(embedding, labels)
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


class _Question:
    """One question being answered: the map's objects, their geometry, the phrases."""

    def __init__(
        self,
        things: MapThings,
        index: RelationSource,
        rater: QueryRater,
        embeddings: dict[str, np.ndarray],
        viewer: np.ndarray | None,
    ):
        self.things, self.index, self.viewer = things, index, viewer
        self.up = index.up
        self._rater, self._embeddings = rater, embeddings
        self._groundings: dict[str, _Grounding] = {}

    def embedding(self, phrase: str) -> np.ndarray:
        return self._embeddings[phrase]

    def ground(self, phrase: str) -> _Grounding:
        if phrase not in self._groundings:
            self._groundings[phrase] = _Grounding(
                self._rater, phrase, self.embedding(phrase), self.things
            )
        return self._groundings[phrase]

    def ids(self, positions) -> np.ndarray:
        return self.things.ids[positions]

    def named(self, position: int) -> tuple[int, str]:
        if position == _FLOOR:
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
        """The floor's height along up (`relations.floor_height` over the whole map)."""
        return floor_height(self.index, self.things.ids)


_NONE = -1
"""No anchor (in the int64 [m, 2] anchor positions a part measures)."""
_FLOOR = -2
"""The implicit floor as an anchor position."""
FLOOR_ANCHOR = (0, "floor")
"""How a hit names the implicit floor: id 0 (no map object has it), label "floor"."""


class _Part:
    """A clause or the superlative: per object, a degree in [0, 1] and the anchors it was
    measured against (positions, _NONE where none)."""

    kind: str
    q: _Question
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


class _Clause(_Part):
    """One relation clause; remembers what it measured, for the hits' explanations."""

    def __init__(self, clause: RelationClause, question: _Question):
        self.kind, self.phrases, self.q = clause.kind, clause.anchors, question
        n = len(question.things)
        self._degrees = np.zeros(n)
        self._anchors = np.full((n, 2), _NONE, np.int64)
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
        return degrees, np.full((len(positions), 2), _NONE, np.int64)

    def _to_anchor(self, positions):
        """Best over the anchor candidates of degree x anchor relevance; an object no
        candidate satisfies names the best candidate it was weighed against."""
        q = self.q
        if q.is_floor(self.phrases[0]):
            return self._on_floor(positions)
        grounding = q.ground(self.phrases[0])
        ids = q.ids(positions)
        best = np.zeros(len(positions))
        anchors = np.full((len(positions), 2), _NONE, np.int64)
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
            anchors[anchors[:, 0] == _NONE, 0] = top[0]
        return best, anchors

    def _on_floor(self, positions):
        """On the implicit floor (`answer` lets only `on` reach it): the gap of each thing's
        bottom above the floor; boxes rule out (exactly) what starts too high to rest on it."""
        q = self.q
        degrees = np.zeros(len(positions))
        anchors = np.full((len(positions), 2), _NONE, np.int64)
        anchors[:, 0] = _FLOOR
        floor = q.floor
        if floor is None:
            return degrees, anchors
        ids = q.ids(positions)
        lo, _ = q.index.boxes(ids)
        low = np.flatnonzero(lo[:, 2] - floor < ON_MAX_GAP_M)
        bottoms = [body.bottom for body in q.index.bodies(ids[low])]
        degrees[low] = on_floor_degrees(np.array(bottoms, np.float64), floor)
        return degrees, anchors

    def _between(self, positions):
        q = self.q
        best = np.zeros(len(positions))
        anchors = np.full((len(positions), 2), _NONE, np.int64)
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


class _Measure:
    """One superlative's degree over the category's members (indices into the category),
    from a number per member (a distance, a size) computed when asked, with an upper bound
    on every member's degree once `settle` has found the extreme exactly."""

    def __init__(self, members: np.ndarray, q: _Question):
        self.members, self.q = members, q
        self.exact = np.full(len(members), np.nan)
        """float64 [m]: the number of each member, NaN where not computed yet."""

    def _compute(self, bodies: list[Body]) -> list[float]:
        raise NotImplementedError

    def compute(self, js: np.ndarray) -> None:
        """The numbers of these members (their bodies fetched at once)."""
        js = js[np.isnan(self.exact[js])]
        if len(js):
            self.exact[js] = self._compute(self.q.index.bodies(self.q.ids(self.members[js])))

    _largest = False
    """Whether the extreme `_settle` looks for is the largest number (else the smallest)."""

    def _settle(
        self, order: np.ndarray, bound: np.ndarray, beyond: Callable[[float, float], bool]
    ) -> float:
        """Compute members in `order` (a chunk at a time) until the next one's bound cannot
        pass the extreme found so far (`beyond(bound, extreme)` false); the extreme, exact."""
        extreme = np.nan
        for start in range(0, len(order), _CHUNK):
            if not np.isnan(extreme) and not beyond(float(bound[order[start]]), extreme):
                break
            chunk = order[start : start + _CHUNK]
            self.compute(chunk)
            found = self.exact[chunk]
            best = float(found.max() if self._largest else found.min())
            if np.isnan(extreme) or beyond(best, extreme):
                extreme = best
        return extreme

    def settle(self) -> None:
        raise NotImplementedError

    def degrees(self, js: np.ndarray) -> np.ndarray:
        """float64 [len(js)]: the exact degrees of these members (after `settle`)."""
        raise NotImplementedError

    def upper(self) -> np.ndarray:
        """float64 [m]: bounds on every member's degree (after `settle`)."""
        raise NotImplementedError


_CHUNK = 32
"""Category members measured at a time while a superlative looks for its extreme."""


class _Distances(_Measure):
    """Closest (farthest) from a reference: the asker's position or an anchor's body."""

    def __init__(self, reference, ref_lo, ref_hi, members: np.ndarray, q: _Question, far: bool):
        super().__init__(members, q)
        self.reference, self.far, self._largest = reference, far, far
        lo, hi = q.index.boxes(q.ids(members))
        self.lower, self.longer = box_distance_bounds(lo, hi, ref_lo, ref_hi)
        self.extreme = np.nan

    def _compute(self, bodies: list[Body]) -> list[float]:
        return [distance_to(self.reference, body) for body in bodies]

    def settle(self) -> None:
        if self.far:  # from the farthest box on, until no box may be farther
            order = np.argsort(-self.longer, kind="stable")
            self.extreme = self._settle(order, self.longer, lambda bound, x: bound > x)
        else:  # from the nearest box on, until no box may be nearer
            order = np.argsort(self.lower, kind="stable")
            self.extreme = self._settle(order, self.lower, lambda bound, x: bound < x)

    def degrees(self, js: np.ndarray) -> np.ndarray:
        self.compute(js)
        if self.far:
            return farthest_degrees(self.exact[js], self.extreme)
        return closest_degrees(self.exact[js], self.extreme)

    def upper(self) -> np.ndarray:
        known = ~np.isnan(self.exact)
        if self.far:
            bound = farthest_degrees(np.where(known, self.exact, self.longer), self.extreme)
        else:
            bound = closest_degrees(np.where(known, self.exact, self.lower), self.extreme)
        return np.minimum(bound, 1.0)


class _Sizes(_Measure):
    """Biggest by volume: members from the largest box bound on, until none may be bigger."""

    _largest = True

    def __init__(self, members: np.ndarray, q: _Question):
        super().__init__(members, q)
        self.bound = volume_upper_bounds(*q.index.boxes(q.ids(members)))
        self.largest = np.nan

    def _compute(self, bodies: list[Body]) -> list[float]:
        return [body.volume_m3() for body in bodies]

    def settle(self) -> None:
        order = np.argsort(-self.bound, kind="stable")
        self.largest = self._settle(order, self.bound, lambda bound, x: bound > x)

    def degrees(self, js: np.ndarray) -> np.ndarray:
        self.compute(js)
        return biggest_degrees(self.exact[js], self.largest)

    def upper(self) -> np.ndarray:
        sizes = np.where(np.isnan(self.exact), self.bound, self.exact)
        return np.minimum(biggest_degrees(sizes, self.largest), 1.0)


class _Superlative(_Part):
    """The target's extreme copy within its category (`category_of`; every object when the
    target is unspecified); degree 0 outside it."""

    def __init__(self, superlative: Superlative, target: np.ndarray, q: _Question):
        self.kind, self.q, self.phrases = superlative.kind, q, list(superlative.anchors)
        self.category = category_of(target)
        self.member = np.full(len(target), _NONE, np.int64)  # position -> index in category
        self.member[self.category] = np.arange(len(self.category))
        m = len(self.category)
        self.degrees = np.full(m, np.nan)  # exact, where measured
        self.anchors = np.full(m, _NONE, np.int64)
        # (anchor position or _NONE, weight, measure): the degree is the best weighted one
        self.measures: list[tuple[int, float, _Measure]] = []
        if m == 0:
            return
        ids = q.ids(self.category)
        if self.kind in ("highest", "lowest", "smallest"):  # every member, at once
            if self.kind == "smallest":
                self.degrees = smallest_degrees([b.volume_m3() for b in q.index.bodies(ids)])
            else:
                heights = heights_along(q.index.centroids(ids), q.up)
                of = highest_degrees if self.kind == "highest" else lowest_degrees
                self.degrees = of(heights)
        elif self.kind == "biggest":
            self.measures.append((_NONE, 1.0, _Sizes(self.category, q)))
        elif superlative.anchors:  # closest / farthest from a thing
            grounding = q.ground(superlative.anchors[0])
            for a in grounding.candidates():
                if self.member[a] != _NONE:
                    continue
                anchor_id = int(q.things.ids[a])
                lo, hi = q.index.boxes([anchor_id])
                measure = _Distances(
                    q.index.body(anchor_id), lo[0], hi[0], self.category, q, self.kind == "farthest"
                )
                self.measures.append((a, float(grounding.relevance[a]), measure))
            if not self.measures:
                self.degrees = np.zeros(m)
        else:  # closest / farthest from the asker
            viewer = np.asarray(q.viewer, np.float64)
            here = boxes_in_up_frame(viewer[None], viewer[None], q.up)[0][0]
            far = self.kind == "farthest"
            self.measures.append(
                (_NONE, 1.0, _Distances(viewer, here, here, self.category, q, far))
            )
        for _, _, measure in self.measures:
            measure.settle()

    def _measure_members(self, js: np.ndarray) -> None:
        """The exact degrees of these members: the best weighted measure, the first anchor
        on a tie."""
        best = np.zeros(len(js))
        anchors = np.full(len(js), _NONE, np.int64)
        for a, weight, measure in self.measures:
            values = weight * measure.degrees(js)
            better = values > best
            best[better], anchors[better] = values[better], a
        self.degrees[js], self.anchors[js] = best, anchors

    def apply(self, score: np.ndarray, k: int) -> np.ndarray:
        """The scores times the degrees; a member whose bound keeps it out of the top k is
        not measured and scores -1 (below every measured object)."""
        out = np.zeros(len(score))
        category = self.category
        if len(category) == 0:
            return out
        base = score[category]
        if not self.measures:
            out[category] = base * self.degrees
            return out
        # members every measure has computed already (finding the extremes) score at once
        known = np.all([~np.isnan(measure.exact) for _, _, measure in self.measures], axis=0)
        self._measure_members(np.flatnonzero(known))
        bound = base * np.max([w * measure.upper() for _, w, measure in self.measures], axis=0)
        pending = np.flatnonzero((bound > 0) & ~known)
        pending = pending[np.argsort(-bound[pending], kind="stable")]
        best_k = heapq.nlargest(k, (base[known] * self.degrees[known]).tolist())
        heapq.heapify(best_k)  # a min-heap of the k best measured scores
        measured = np.flatnonzero(known).tolist()
        for start in range(0, len(pending), _CHUNK):
            if len(best_k) >= k and best_k[0] > bound[pending[start]]:
                break  # these and every one after them score below k measured ones
            chunk = pending[start : start + _CHUNK]
            self._measure_members(chunk)
            for value in (base[chunk] * self.degrees[chunk]).tolist():
                if len(best_k) < k:
                    heapq.heappush(best_k, value)
                else:
                    heapq.heappushpop(best_k, value)
            measured += chunk.tolist()
        skipped = np.setdiff1d(pending, measured)
        out[category] = 0.0  # members with a 0 bound score 0 whatever their degree
        out[category[measured]] = base[measured] * self.degrees[measured]
        out[category[skipped]] = -1.0
        return out

    def measure(self, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        degrees = np.zeros(len(positions))
        anchors = np.full((len(positions), 2), _NONE, np.int64)
        js = self.member[positions]
        inside = js != _NONE
        missing = js[inside][np.isnan(self.degrees[js[inside]])]
        if len(missing):
            self._measure_members(missing)
        degrees[inside], anchors[inside, 0] = self.degrees[js[inside]], self.anchors[js[inside]]
        return degrees, anchors

    explain = measure


def answer(
    reading: Reading,
    things: Sequence[MapThing] | MapThings,
    index: RelationSource,
    encoder: TextEncoder,
    viewer: np.ndarray | None = None,
    k: int = 5,
) -> list[RelationalHit] | None:
    """The top-k objects answering a relational reading, best first; None when the caller
    should answer as a plain query (see the module docstring).

    things: the map's objects (in any order), each with its geometry in `index` under its id
    (same up axis); viewer: the asker's position float [3], metres, world frame (None:
    unknown).
    """
    if not is_relational(reading) or not len(things) or k <= 0:
        return None
    if not isinstance(things, MapThings):
        things = MapThings.of(things)
    sup = reading.superlative
    anchor_phrases = _anchor_phrases(reading)
    target_phrase = _target_phrase(reading)
    phrases = phrases_of(reading)
    embedded = encoder.encode(phrases).astype(np.float32)  # one call; labels are cached
    q = _Question(
        things, index, rater_for(encoder), dict(zip(phrases, embedded, strict=True)), viewer
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
    clauses = [_Clause(c, q) for c in reading.relations]
    for clause in clauses:
        degrees, _ = clause.measure(live)
        score[live] *= degrees
        live = live[score[live] > 0]
    superlative = None
    if sup is not None:
        superlative = _Superlative(sup, target, q)
        score = superlative.apply(score, min(k, n))

    query = q.embedding(target_phrase)
    label_cosine = np.asarray(encoder.encode(list(things.labels)), np.float32) @ query
    top, cosine = _top(score, target, things, query, label_cosine, k)
    explaining: _Clause | _Superlative = clauses[0] if clauses else superlative  # type: ignore[assignment]
    degrees, anchors = explaining.explain(top)
    hits = []
    for i, position in enumerate(top.tolist()):
        named = [q.named(int(a)) for a in anchors[i] if a != _NONE]
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


def category_of(target: np.ndarray) -> np.ndarray:
    """Positions of the target's category, within which a superlative ranks: the objects
    rated as confident targets and within CATEGORY_MARGIN of the best ("the table lamp
    closest to the bookcase" ranks table lamps, not the floor lamp a "lamp" rates 0.6), or
    named by the phrase's head noun (HEAD_NOUN_RELEVANCE: "the lamp closest to the desk"
    ranks table lamps beside a thing labelled just "lamp");
    when none is confident, those rated as the best one is, if at least
    CATEGORY_MIN_RELEVANCE ("the lowest bag" on a map of backpacks, rated 0.35)."""
    if len(target) == 0:
        return np.zeros(0, np.int64)
    best = float(target.max())
    if best < CATEGORY_MIN_RELEVANCE:
        return np.zeros(0, np.int64)
    near_best = min(best - CATEGORY_MARGIN, HEAD_NOUN_RELEVANCE)  # a named kind is always in
    return np.flatnonzero(target >= max(min(CONFIDENT, best), near_best))


def _anchor_labels(q: _Question, anchor_phrases: list[str]) -> np.ndarray:
    """Label codes of the anchor phrases' candidates: a thing of the anchor's own label is a
    piece of it (a bookcase mapped as two objects), not what stands on or in it."""
    codes = {
        int(q.things.label_of[a])
        for phrase in anchor_phrases
        if not q.is_floor(phrase)
        for a in q.ground(phrase).candidates()
    }
    return np.array(sorted(codes), np.int64)


def _floor_elsewhere(reading: Reading, q: _Question) -> bool:
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


_IRREGULAR_PLURALS = {
    "shelves": "shelf", "knives": "knife", "people": "person", "boxes": "box", "glasses":
    "glasses", "dishes": "dish", "benches": "bench", "couches": "couch", "watches": "watch",
}  # fmt: skip


def head_noun(phrase: str) -> str:
    """The last word of a phrase, lower case, a plural's s dropped ("dining tables" ->
    "table"; "glass" and "bus" keep theirs)."""
    words = phrase.lower().split()
    return _singular(words[-1]) if words else ""


def _singular(word: str) -> str:
    if word in _IRREGULAR_PLURALS:
        return _IRREGULAR_PLURALS[word]
    if word.endswith("ies") and len(word) > 4:
        return word[:-3] + "y"
    if word.endswith("s") and not word.endswith(("ss", "us", "is")) and len(word) > 3:
        return word[:-1]
    return word


_ARTICLES = frozenset({"the", "a", "an", "my", "our", "your", "this", "that"})
COMPOUND_HEAD_MIN_LETTERS = 5
"""A head noun of at least this many letters also names a one-word compound ending in it:
"shelf" a bookshelf, "case" no bookcase."""


def same_head(phrase: str, label: str) -> bool:
    """Whether a phrase names a label by its head noun: the label ends in the same noun ("the
    table" and "dining table"), or in a compound of it ("the shelf" and "bookshelf"), and
    every other word of the phrase is in the label ("side table" does not name the dining
    table; "dining table" does)."""
    words = [_singular(w) for w in phrase.lower().split() if w not in _ARTICLES]
    label_words = [_singular(w) for w in label.lower().split()]
    if not words or not label_words:
        return False
    head, label_head = words[-1], label_words[-1]
    if head != label_head and not (
        len(head) >= COMPOUND_HEAD_MIN_LETTERS and label_head.endswith(head)
    ):
        return False
    return all(w in label_words for w in words[:-1])


def phrases_of(reading: Reading) -> list[str]:
    """The phrases `answer` embeds for a reading, in one `encoder.encode` call: the anchors,
    then the target (a device encodes them ahead, off its loop, into the encoder's cache)."""
    return list(dict.fromkeys([*_anchor_phrases(reading), _target_phrase(reading)]))


def _anchor_phrases(reading: Reading) -> list[str]:
    phrases = [a for c in reading.relations for a in c.anchors]
    if reading.superlative is not None:
        phrases += reading.superlative.anchors
    return phrases


def _target_phrase(reading: Reading) -> str:
    """The target phrase, or for an unspecified target the question's words (its cosine)."""
    return _question(reading) if reading.any_target else reading.target


def _question(reading: Reading) -> str:
    """Words for an unspecified target's cosine: the anchors ("on the table" -> "table")."""
    clauses = [" ".join(c.anchors) for c in reading.relations]
    return " ".join(clauses) or "object"
