"""Pairwise relations of two bodies: on, in, under, above, below, near, next_to.

`degree = relation(a, b)`: how much `a` stands in the relation to the anchor `b`, in [0, 1],
exactly 0 beyond the thresholds (app.relations.thresholds). `pair_degrees` measures every
pairwise relation of two bodies at once (what `RelationIndex` holds per pair), and
`within_reach` is the box prefilter outside which every pairwise degree is 0. The implicit
floor ("on the floor") is `on`'s gap ramp against the lowest bottom of a map.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal

import numpy as np

from app.relations.bodies import (
    Z_UP,
    Body,
    BodyLike,
    Footprint,
    as_bodies,
    box_gaps,
    closest_distance_m,
    footprints_overlap,
    share_over,
)
from app.relations.ramps import fall, fall_many, rise
from app.relations.thresholds import THRESHOLDS as T

PairwiseKind = Literal["on", "in", "under", "above", "below", "near", "next_to"]
PAIRWISE_KINDS: tuple[str, ...] = ("on", "in", "under", "above", "below", "near", "next_to")


def _surface_under(a: Body, b: Body) -> float | None:
    """The height of b's surface under a: b's highest point around a's footprint
    (support_margin_m) not above a's bottom (on_slack_m); None if b has none there."""
    heights = b.local[2]
    low = b.local[:, heights <= a.bottom + T.on_slack_m]
    if low.shape[1] == 0:
        return None
    around = low[2, a.footprint.contains(low[:2], T.support_margin_m)]
    return float(around.max()) if len(around) else None


def covered_share(a: Body, b: Body) -> float:
    """How much b covers a from above, in [0, 1]: the part of b more than cover_clearance_m
    above a's top must reach over a (cover_min_points of its points over a's footprint grown
    by footprint_margin_m: an open box's walls do not), then the share of the smaller
    footprint (a's, or that part's) well inside the other."""
    return _cover(a, b)[0]


def _cover(a: Body, b: Body, enough: float = 1.0) -> tuple[float, float]:
    """(`covered_share`, the height of b's lowest point over a above a's top); `enough`: a
    share past which the other footprint need not be measured (the caller's degree is full
    from there)."""
    if not footprints_overlap(a, b, T.footprint_margin_m) or b.hi[2] <= a.top + T.cover_clearance_m:
        return 0.0, np.inf
    upper = b.local[:, b.local[2] > a.top + T.cover_clearance_m]
    outside = a.footprint.outside_m(upper[:2])
    over_a = outside <= T.footprint_margin_m
    count = int(np.count_nonzero(over_a))
    if count == 0:
        return 0.0, np.inf
    # well inside (footprint_margin_m in): a thing touching a sofa's back is not under it
    share = np.count_nonzero(outside <= -T.footprint_margin_m) / upper.shape[1]
    if share < enough:
        a_under = Footprint(upper[:2]).contains(a.local[:2], -T.footprint_margin_m)
        share = max(share, np.count_nonzero(a_under) / a.local.shape[1])
    clearance = float(upper[2, over_a].min()) - a.top
    return rise(count, 0.0, T.cover_min_points) * share, clearance


# -- pairwise relations -------------------------------------------------------------------


def near(a: BodyLike, b: BodyLike, up=Z_UP) -> float:
    """Degree to which a and b are near: 1 with closest points within near_full_m, falling
    to 0 at near_max_m. Symmetric."""
    return _near(*as_bodies(a, b, up=up))


def _near(a: Body, b: Body) -> float:
    distance = closest_distance_m(a, b, T.near_max_m)
    return fall(distance, T.near_full_m, T.near_max_m) if distance <= T.near_max_m else 0.0


def next_to(a: BodyLike, b: BodyLike, up=Z_UP) -> float:
    """Degree to which a is next to b: near, side by side at a similar height (their height
    ranges overlap), not stacked (neither mostly over the other's footprint). Symmetric."""
    a, b = as_bodies(a, b, up=up)
    return _next_to(a, b, _near(a, b))


def _next_to(a: Body, b: Body, near_degree: float) -> float:
    if near_degree == 0.0:
        return 0.0
    overlap = min(a.top, b.top) - max(a.bottom, b.bottom)
    shorter = max(min(a.height_m, b.height_m), 1e-3)
    level = rise(overlap / shorter, T.next_to_min_overlap, T.next_to_full_overlap)
    if level == 0.0:
        return 0.0
    stacked = max(share_over(a, b), share_over(b, a))
    return near_degree * level * fall(stacked, T.stacked_min_share, T.stacked_full_share)


def on(a: BodyLike, b: BodyLike, up=Z_UP) -> float:
    """Degree to which a rests on b: a's bottom within on_full_gap_m (0 at on_max_gap_m)
    above b's surface under a (b's highest points around a's footprint up to a's bottom),
    most of a over b's footprint, a's bottom above b's (on_min_rise_m: not a bag under a
    table by its feet, not a ball in a box). a on b implies b not on a."""
    a, b = as_bodies(a, b, up=up)
    return _support(a, b)[0]


def above(a: BodyLike, b: BodyLike, up=Z_UP) -> float:
    """Degree to which a is above b without resting on it: over b's footprint with a gap
    beyond `on`'s (up to vertical_full_gap_m, 0 at vertical_max_gap_m) above b's surface
    under it. on + above is 1 for a gap within vertical_full_gap_m."""
    a, b = as_bodies(a, b, up=up)
    return _support(a, b)[1]


def below(a: BodyLike, b: BodyLike, up=Z_UP) -> float:
    """Degree to which a is below b: the converse of `above` (b above a)."""
    return above(b, a, up)


def _support(a: Body, b: Body) -> tuple[float, float]:
    """(on, above) of a over b: they share the footprint share and the gap."""
    raised = rise(a.bottom - b.bottom, T.on_min_rise_m, T.on_full_rise_m)
    if raised == 0.0 or a.bottom - b.hi[2] > T.vertical_max_gap_m:
        return 0.0, 0.0
    spread = rise(share_over(a, b, T.footprint_margin_m), T.on_min_share, T.on_full_share)
    if spread == 0.0:
        return 0.0, 0.0
    surface = _surface_under(a, b)
    if surface is None:
        return 0.0, 0.0
    gap = a.bottom - surface
    resting = fall(gap, T.on_full_gap_m, T.on_max_gap_m)
    lifted = (1.0 - resting) * fall(gap, T.vertical_full_gap_m, T.vertical_max_gap_m)
    return spread * raised * resting, spread * raised * lifted


def under(a: BodyLike, b: BodyLike, up=Z_UP) -> float:
    """Degree to which a is under b: b covers a from above (`covered_share`: the bag under
    the table, the book under the mug), its lowest part over a touching a or up to
    vertical_full_gap_m above a's top (0 at vertical_max_gap_m). a under b implies b not
    under a (a's top must be below b's)."""
    a, b = as_bodies(a, b, up=up)
    return _under(a, b)


def _under(a: Body, b: Body) -> float:
    if not a.top < b.top:
        return 0.0
    share, clearance = _cover(a, b, T.under_full_share)
    covered = rise(share, T.under_min_share, T.under_full_share)
    if covered == 0.0:
        return 0.0
    return covered * fall(clearance, T.vertical_full_gap_m, T.vertical_max_gap_m)


def in_(a: BodyLike, b: BodyLike, up=Z_UP) -> float:
    """Degree to which a is in b: most of a's points inside b's extent (its footprint times
    its height range), and b's points at a's heights walling a in (a table's legs do not, nor
    a sofa's back alone). a in b implies b not in a (a's footprint must be the smaller)."""
    a, b = as_bodies(a, b, up=up)
    return _in(a, b)


def _in(a: Body, b: Body) -> float:
    if not footprints_overlap(a, b, 0.0) or not a.footprint.area < b.footprint.area:
        return 0.0
    heights = a.local[2]
    level = (heights >= b.bottom - T.in_slack_m) & (heights <= b.top + T.in_slack_m)
    count = len(heights)
    if np.count_nonzero(level) <= T.in_min_share * count:
        return 0.0
    inside = np.count_nonzero(b.footprint.contains(a.local[:2, level]))
    share = rise(inside / count, T.in_min_share, T.in_full_share)
    return share * _enclosure(a, b) if share > 0.0 else 0.0


def _enclosure(a: Body, b: Body) -> float:
    """How well b's walls close a in, seen from above around a's centre, in [0, 1]: b's
    points from a's floor up to b's lid (all of a wall's height: a capped bookcase has a dozen
    points at a book's height) each cover the arc an in_wall_patch_m patch spans at its
    distance; enough of the turn covered and no wide opening."""
    heights = b.local[2]
    floor = a.bottom + min(T.in_floor_m, T.in_edge_share * a.height_m)
    ceiling = b.top - min(T.in_rim_m, T.in_edge_share * b.height_m)
    wall = (heights >= floor) & (heights <= ceiling)
    if not wall.any():
        return 0.0
    offsets = b.local[:2, wall] - a.centre[:2, None]
    distance = np.maximum(np.sqrt(np.einsum("ij,ij->j", offsets, offsets)), 1e-6)
    openings = _arc_openings(
        np.arctan2(offsets[1], offsets[0]), np.arctan(0.5 * T.in_wall_patch_m / distance)
    )
    covered = 1.0 - float(openings.sum()) / (2 * np.pi)
    widest_deg = float(np.degrees(openings.max()))
    return rise(covered, T.in_min_enclosure, T.in_full_enclosure) * fall(
        widest_deg, T.in_full_opening_deg, T.in_max_opening_deg
    )


def _arc_openings(centres: np.ndarray, half_widths: np.ndarray) -> np.ndarray:
    """float64 [n]: the uncovered stretches (radians, zeros where arcs touch) of the circle
    covered by arcs [centre - half width, centre + half width] (half widths <= pi / 2);
    exact, so the same after any rotation or reflection."""
    starts = np.mod(centres - half_widths, 2 * np.pi)
    order = np.argsort(starts)
    starts, ends = starts[order], starts[order] + 2 * half_widths[order]
    # what runs past 2 pi covers the circle's beginning again
    reach = np.maximum.accumulate(np.maximum(ends, ends.max() - 2 * np.pi))
    next_starts = np.append(starts[1:], starts[0] + 2 * np.pi)
    return np.maximum(next_starts - reach, 0.0)


FLOOR_WORDS = frozenset({"floor", "ground"})
"""Head nouns of the floor: an implicit surface when the map holds no object named so."""


def on_floor_degrees(bottoms: np.ndarray, floor: float) -> np.ndarray:
    """float64 [m]: how much things with these bottoms (heights along up) rest on the floor
    at `floor`: `on`'s gap ramp (1 within on_full_gap_m of it, 0 from on_max_gap_m)."""
    return fall_many(np.asarray(bottoms, np.float64) - floor, T.on_full_gap_m, T.on_max_gap_m)


PAIRWISE_RELATIONS: dict[str, Callable[..., float]] = {
    "on": on,
    "in": in_,
    "under": under,
    "above": above,
    "below": below,
    "near": near,
    "next_to": next_to,
}
"""Each pairwise kind's function (subject, anchor, up=...) -> degree."""


# Per unordered pair (a < b), one float64 row: near, next_to, then each directed relation
# a→b and b→a; `below` is `above` read the other way.
_NEAR, _NEXT_TO, _ON, _IN, _UNDER, _ABOVE = 0, 1, 2, 4, 6, 8
_PAIR_WIDTH = 10
PAIR_SLOTS = {
    "near": _NEAR,
    "next_to": _NEXT_TO,
    "on": _ON,
    "in": _IN,
    "under": _UNDER,
    "above": _ABOVE,
}
"""Each kind's column in a `pair_degrees` row (a→b; b→a in the next for the directed ones)."""


def pair_degrees(a: Body, b: Body) -> np.ndarray:
    """float64 [10]: every pairwise degree of two bodies: near, next_to, on (a→b, b→a), in,
    under, above (each both ways). `RelationIndex` holds these rows."""
    out = np.zeros(_PAIR_WIDTH)
    gaps = box_gaps(a, b)
    if gaps[0] ** 2 + gaps[1] ** 2 + gaps[2] ** 2 <= T.near_max_m**2:
        out[_NEAR] = near_degree = _near(a, b)
        out[_NEXT_TO] = _next_to(a, b, near_degree)
        out[_IN], out[_IN + 1] = _in(a, b), _in(b, a)
    if _in_column(gaps):
        out[_ON], out[_ABOVE] = _support(a, b)
        out[_ON + 1], out[_ABOVE + 1] = _support(b, a)
        out[_UNDER], out[_UNDER + 1] = _under(a, b), _under(b, a)
    return out


def _in_column(gaps: tuple[float, float, float]) -> bool:
    """Box gaps (`box_gaps`) within footprint_margin_m seen from above and within
    vertical_max_gap_m along up: the prefilter of on / above / below / under."""
    return (
        gaps[0] <= T.footprint_margin_m
        and gaps[1] <= T.footprint_margin_m
        and gaps[2] <= T.vertical_max_gap_m
    )


def within_reach(
    lo: np.ndarray,
    hi: np.ndarray,
    box_lo: np.ndarray,
    box_hi: np.ndarray,
    kind: str | None = None,
) -> np.ndarray:
    """bool [m]: which boxes (lo, hi float [m, 3], up frame) pass `pair_degrees`'s
    prefilters with the box (box_lo, box_hi float [3]; a point is a box with lo = hi): boxes
    within near_max_m, or over one another (`_in_column`). Every pairwise degree of things
    whose boxes fail it is 0. With a pairwise `kind`, only that relation's: near and next_to
    within near_max_m, the others (on, in, under, above, below) over one another."""
    gap = np.maximum(np.maximum(lo - box_hi, box_lo - hi), 0.0)
    close = np.einsum("ij,ij->i", gap, gap) <= T.near_max_m**2
    if kind in ("near", "next_to"):
        return close
    column = (
        (gap[:, 0] <= T.footprint_margin_m)
        & (gap[:, 1] <= T.footprint_margin_m)
        & (gap[:, 2] <= T.vertical_max_gap_m)
    )
    return column if kind in PAIRWISE_KINDS else close | column
