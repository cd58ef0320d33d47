"""Relations seen from a viewpoint (the asker's position): left_of, right_of, in_front_of,
behind, from centroids; `viewpoint_degrees` measures many things against one anchor at once.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from app.relations.bodies import Z_UP, BodyLike, as_bodies, horizontal, snap_to_axis
from app.relations.ramps import fall_many, rise_many
from app.relations.thresholds import THRESHOLDS as T

VIEWPOINT_KINDS: tuple[str, ...] = ("left_of", "right_of", "in_front_of", "behind")


def viewpoint_degrees(
    kind: str, subjects: np.ndarray, anchor: np.ndarray, viewer: np.ndarray, up=Z_UP
) -> np.ndarray:
    """float64 [m]: a viewpoint relation (`left_of`, `right_of`, `in_front_of`, `behind`) of
    many things to one anchor at once, from centroids (world frame, metres): subjects float
    [m, 3], the anchor's float [3], the viewer's position float [3]. Seen from the viewer
    looking horizontally at the anchor's centre; all 0 with the anchor at the viewer."""
    if kind not in VIEWPOINT_KINDS:
        raise ValueError(f"unknown viewpoint relation {kind!r}; one of {VIEWPOINT_KINDS}")
    axis_up = snap_to_axis(up)
    subjects = np.asarray(subjects, np.float64).reshape(-1, 3)
    viewer = np.asarray(viewer, np.float64)
    view = horizontal(np.asarray(anchor, np.float64) - viewer, axis_up)
    reach = float(np.linalg.norm(view))
    if reach < 1e-6:
        return np.zeros(len(subjects))
    view /= reach
    to_subject = horizontal(subjects - viewer, axis_up)
    depth = to_subject @ view
    if kind in ("left_of", "right_of"):
        # positive to the left: the subject's bearing from the line of sight to the anchor
        bearing = np.degrees(np.arctan2(np.cross(view, to_subject) @ axis_up, depth))
        return rise_many(bearing if kind == "left_of" else -bearing, 0.0, T.left_right_full_deg)
    nearer = reach - depth  # how much nearer to the viewer than the anchor
    lateral = np.linalg.norm(to_subject - depth[:, None] * view, axis=1)
    ahead = rise_many(nearer if kind == "in_front_of" else -nearer, 0.0, T.front_full_m)
    return ahead * fall_many(lateral, T.front_lateral_full_m, T.front_lateral_max_m)


def _viewpoint(kind: str, a: BodyLike, b: BodyLike, viewer: np.ndarray, up) -> float:
    a, b = as_bodies(a, b, up=up)
    return float(viewpoint_degrees(kind, a.centroid[None], b.centroid, viewer, a.up)[0])


def left_of(a: BodyLike, b: BodyLike, viewer: np.ndarray, up=Z_UP) -> float:
    """Degree to which a is left of b seen from `viewer` (float [3], the asker's position):
    a's bearing left of b's by left_right_full_deg for degree 1."""
    return _viewpoint("left_of", a, b, viewer, up)


def right_of(a: BodyLike, b: BodyLike, viewer: np.ndarray, up=Z_UP) -> float:
    """Degree to which a is right of b seen from `viewer` (mirror of `left_of`)."""
    return _viewpoint("right_of", a, b, viewer, up)


def in_front_of(a: BodyLike, b: BodyLike, viewer: np.ndarray, up=Z_UP) -> float:
    """Degree to which a is in front of b seen from `viewer`: nearer along the view direction
    from the viewer to b (front_full_m for degree 1), near the line of sight to b."""
    return _viewpoint("in_front_of", a, b, viewer, up)


def behind(a: BodyLike, b: BodyLike, viewer: np.ndarray, up=Z_UP) -> float:
    """Degree to which a is behind b seen from `viewer` (mirror of `in_front_of`)."""
    return _viewpoint("behind", a, b, viewer, up)


VIEWPOINT_RELATIONS: dict[str, Callable[..., float]] = {
    "left_of": left_of,
    "right_of": right_of,
    "in_front_of": in_front_of,
    "behind": behind,
}
"""Each viewpoint kind's function (subject, anchor, viewer, up=...) -> degree."""
