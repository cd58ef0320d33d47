"""A superlative within the target's category: the closest, farthest, biggest, smallest,
highest or lowest copy, measuring only the members whose box bounds say they may rank."""

from __future__ import annotations

import heapq
from collections.abc import Callable

import numpy as np

from app.answering.question import HEAD_NOUN_RELEVANCE, NO_ANCHOR, Part, Question
from app.answering.relevance import CONFIDENT
from app.relations.bodies import Body, boxes_in_up_frame
from app.relations.grammar import Superlative
from app.relations.superlatives import (
    biggest_degrees,
    box_distance_bounds,
    closest_degrees,
    distance_to,
    farthest_degrees,
    heights_along,
    highest_degrees,
    lowest_degrees,
    smallest_degrees,
    volume_upper_bounds,
)

CATEGORY_MIN_RELEVANCE = 0.25
"""Least relevance of the best-rated object for a weakly named target to have a category
("bag" rates backpacks 0.35 with MiniLM; below this nothing is what the phrase names)."""
CATEGORY_MARGIN = 0.2
"""A superlative's category holds the objects rated within this of the best-rated one."""


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


class _Measure:
    """One superlative's degree over the category's members (indices into the category),
    from a number per member (a distance, a size) computed when asked, with an upper bound
    on every member's degree once `settle` has found the extreme exactly."""

    def __init__(self, members: np.ndarray, q: Question):
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

    def __init__(self, reference, ref_lo, ref_hi, members: np.ndarray, q: Question, far: bool):
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

    def __init__(self, members: np.ndarray, q: Question):
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


class SuperlativePart(Part):
    """The target's extreme copy within its category (`category_of`; every object when the
    target is unspecified); degree 0 outside it."""

    def __init__(self, superlative: Superlative, target: np.ndarray, q: Question):
        self.kind, self.q, self.phrases = superlative.kind, q, list(superlative.anchors)
        self.category = category_of(target)
        self.member = np.full(len(target), NO_ANCHOR, np.int64)  # position -> index in category
        self.member[self.category] = np.arange(len(self.category))
        m = len(self.category)
        self.degrees = np.full(m, np.nan)  # exact, where measured
        self.anchors = np.full(m, NO_ANCHOR, np.int64)
        # (anchor position or NO_ANCHOR, weight, measure): the degree is the best weighted one
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
            self.measures.append((NO_ANCHOR, 1.0, _Sizes(self.category, q)))
        elif superlative.anchors:  # closest / farthest from a thing
            grounding = q.ground(superlative.anchors[0])
            for a in grounding.candidates():
                if self.member[a] != NO_ANCHOR:
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
                (NO_ANCHOR, 1.0, _Distances(viewer, here, here, self.category, q, far))
            )
        for _, _, measure in self.measures:
            measure.settle()

    def _measure_members(self, js: np.ndarray) -> None:
        """The exact degrees of these members: the best weighted measure, the first anchor
        on a tie."""
        best = np.zeros(len(js))
        anchors = np.full(len(js), NO_ANCHOR, np.int64)
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
        anchors = np.full((len(positions), 2), NO_ANCHOR, np.int64)
        js = self.member[positions]
        inside = js != NO_ANCHOR
        missing = js[inside][np.isnan(self.degrees[js[inside]])]
        if len(missing):
            self._measure_members(missing)
        degrees[inside], anchors[inside, 0] = self.degrees[js[inside]], self.anchors[js[inside]]
        return degrees, anchors

    explain = measure
