"""What a question reads of a map's geometry (`RelationSource`), and the floor it finds there.

Two sources give the same degrees for the same points: `RelationIndex` (app.relations.index),
kept as objects change (the server), and `OnDemandRelations` (app.relations.on_demand),
measured when asked (the device's local map, which holds far more objects than it is asked
about).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from app.relations.bodies import Body


class RelationSource(Protocol):
    """What a question reads of a map's geometry (`app.answering.relational.answer`): kept up
    to date as objects change (`RelationIndex`, the server) or measured when asked
    (`OnDemandRelations`, the device's local map). Both give the same degrees for the same
    points."""

    up: np.ndarray
    """The up axis, float64 [3]."""

    def body(self, object_id: int) -> Body: ...

    def bodies(self, ids: np.ndarray) -> list[Body]:
        """The bodies of these ids (int [m]), at once."""
        ...

    def degrees(self, kind: str, anchor: int, subjects: np.ndarray) -> np.ndarray:
        """float64 [m]: a pairwise kind's degree of each subject (ids int [m]) to the anchor."""
        ...

    def centroids(self, ids: np.ndarray) -> np.ndarray:
        """float64 [m, 3]: `Body.centroid` of each, world frame."""
        ...

    def boxes(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) float64 [m, 3]: boxes holding each one's points, up frame (the
        prefilters and bounds; a wider box costs work, never a different answer)."""
        ...


def floor_height(source: RelationSource, ids: np.ndarray) -> float | None:
    """The floor's height along up: the lowest `Body.bottom` of these objects (None for
    none). Exact and cheap: boxes hold their points, so an object whose box starts above
    the lowest bottom found so far cannot be lower, and only the lowest few bodies are built
    (the same floor on the server and the device, whatever their boxes' slack)."""
    if len(ids) == 0:
        return None
    lo, _ = source.boxes(ids)
    order = np.argsort(lo[:, 2], kind="stable")
    best = np.inf
    for start in range(0, len(order), 8):
        chunk = order[start : start + 8]
        if lo[chunk[0], 2] >= best:
            break
        for body in source.bodies(ids[chunk]):
            best = min(best, body.bottom)
    return float(best)
