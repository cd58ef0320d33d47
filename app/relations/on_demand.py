"""A map's relations measured when a question reads them (`OnDemandRelations`): the device's
local map, which holds far more objects than it is asked about."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from app.relations.bodies import Z_UP, Body, boxes_in_up_frame, snap_to_axis
from app.relations.pairwise import PAIRWISE_KINDS, PAIRWISE_RELATIONS, within_reach


class OnDemandRelations:
    """A map's relations measured when a question reads them, for a map held elsewhere (the
    device's local map, 10k objects or more): nothing is prepared ahead and nothing is kept,
    so a question builds bodies only for the objects it touches (`bodies_of`, which may cache
    them). The degrees are `RelationIndex`'s: the same relation functions on the same bodies;
    the boxes only decide which pairs are worth measuring (`within_reach`), and a box wider
    than its points changes no degree.
    """

    def __init__(
        self,
        ids: np.ndarray,
        lo: np.ndarray,
        hi: np.ndarray,
        bodies_of: Callable[[np.ndarray], list[Body]],
        centroids_of: Callable[[np.ndarray], np.ndarray] | None = None,
        up: np.ndarray = Z_UP,
    ):
        """ids: int [n], unique; lo, hi: float [n, 3] world-frame boxes holding each object's
        points (wider is fine); bodies_of: ids (int [m]) -> their `Body`s for `up`;
        centroids_of: rows (int [m], into `ids`) -> float [m, 3], the bodies' centroids
        without building them (default: from `bodies_of`)."""
        self.up = snap_to_axis(up)
        ids = np.asarray(ids, np.int64)
        self._order = np.argsort(ids, kind="stable")
        self._sorted_ids = ids[self._order]
        self._lo, self._hi = boxes_in_up_frame(lo, hi, self.up)
        self._bodies_of = bodies_of
        self._centroids_of = centroids_of

    def __len__(self) -> int:
        return len(self._sorted_ids)

    def _rows(self, ids: np.ndarray) -> np.ndarray:
        ids = np.asarray(ids, np.int64).reshape(-1)
        at = np.minimum(np.searchsorted(self._sorted_ids, ids), max(len(self) - 1, 0))
        if len(ids) and (len(self) == 0 or (self._sorted_ids[at] != ids).any()):
            raise KeyError(f"unknown object ids among {ids[:5].tolist()}")
        return self._order[at]

    def body(self, object_id: int) -> Body:
        return self._bodies_of(np.array([object_id], np.int64))[0]

    def bodies(self, ids: np.ndarray) -> list[Body]:
        return self._bodies_of(np.asarray(ids, np.int64).reshape(-1))

    def degrees(self, kind: str, anchor: int, subjects: np.ndarray) -> np.ndarray:
        """float64 [m]: as `RelationIndex.degrees`; bodies only for the subjects whose boxes
        are within reach of the anchor's."""
        relation = PAIRWISE_RELATIONS.get(kind)
        if relation is None:
            raise ValueError(f"unknown relation {kind!r}; one of {PAIRWISE_KINDS}")
        subjects = np.asarray(subjects, np.int64).reshape(-1)
        out = np.zeros(len(subjects))
        if len(subjects) == 0:
            return out
        anchor_row = self._rows([anchor])[0]
        rows = self._rows(subjects)
        reach = within_reach(
            self._lo[rows], self._hi[rows], self._lo[anchor_row], self._hi[anchor_row], kind
        )
        reach &= subjects != anchor
        within = np.flatnonzero(reach)
        if len(within):
            anchor_body = self.body(anchor)
            for i, body in zip(within.tolist(), self.bodies(subjects[within]), strict=True):
                out[i] = relation(body, anchor_body, up=self.up)
        return out

    def centroids(self, ids: np.ndarray) -> np.ndarray:
        if self._centroids_of is None:
            return np.array([b.centroid for b in self.bodies(ids)], np.float64).reshape(-1, 3)
        return np.asarray(self._centroids_of(self._rows(ids)), np.float64).reshape(-1, 3)

    def boxes(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rows = self._rows(ids)
        return self._lo[rows], self._hi[rows]
