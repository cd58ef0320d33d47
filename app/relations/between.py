"""`between(a, b, c)`: a thing between two anchors, seen from above, from centroids.

Like the viewpoint relations and the superlatives it needs only centroids, so it has a form
over many things at once (`between_degrees`): a question over thousands is one numpy pass.
"""

from __future__ import annotations

import numpy as np

from app.relations.bodies import (
    Z_UP,
    Body,
    BodyLike,
    as_bodies,
    frame_order,
    horizontal,
    snap_to_axis,
)
from app.relations.ramps import fall_many, rise_many
from app.relations.thresholds import THRESHOLDS as T


def between_degrees(
    subjects: np.ndarray,
    b: np.ndarray,
    c: np.ndarray,
    up: np.ndarray = Z_UP,
    anchors: tuple[Body, Body] | None = None,
) -> np.ndarray:
    """float64 [m]: `between` for many things at once, from centroids (world frame, metres):
    subjects float [m, 3], the anchors' b and c float [3]; with the anchors' bodies, a
    subject whose centre stands over either one's footprint is not between them (the bin
    under the desk is not between the desk and the table)."""
    axis_up = snap_to_axis(up)
    subjects = np.asarray(subjects, np.float64).reshape(-1, 3)
    b = np.asarray(b, np.float64)
    segment = horizontal(np.asarray(c, np.float64) - b, axis_up)
    length = float(np.linalg.norm(segment))
    if length < 1e-6:
        return np.zeros(len(subjects))
    offset = horizontal(subjects - b, axis_up)
    t = (offset @ segment) / length**2
    lateral = np.linalg.norm(offset - t[:, None] * segment, axis=1)
    allowed = max(T.between_lateral_m, T.between_lateral_share * length)
    along = rise_many(t, 0.0, T.between_end_share) * rise_many(1.0 - t, 0.0, T.between_end_share)
    degrees = along * fall_many(lateral, allowed, 2.0 * allowed)
    for body in anchors or ():
        order = frame_order(body.axis)
        plane = subjects[:, order[:2]].T  # seen from above, as the body's footprint is
        outside = body.footprint.outside_m(plane)
        degrees *= rise_many(outside, 0.0, T.between_clear_m)
    return degrees


def between(a: BodyLike, b: BodyLike, c: BodyLike, up=Z_UP) -> float:
    """Degree to which a is between b and c, seen from above: a's centre near the segment
    joining theirs (between_lateral_m or between_lateral_share of its length) and inside it
    (between_end_share from either end). Symmetric in b and c."""
    a, b, c = as_bodies(a, b, c, up=up)
    return float(between_degrees(a.centroid[None], b.centroid, c.centroid, a.up, (b, c))[0])
