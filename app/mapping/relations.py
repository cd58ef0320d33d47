"""How things stand to each other, from their points: "the mug on the desk" (issue 27).

Arrays in, arrays out: one module the server and the device's local map both import, so it
depends only on numpy, scipy and what deltas carry (per object: label and capped points
[N, 3]). Every relation is a degree in [0, 1], smooth where sensible and exactly 0 beyond
its documented thresholds (metres), so a box prefilter never changes an answer.

Geometry comes from the points; boxes are only a prefilter. Heights are taken along `up` (a
world axis: our synthetic world is Z-up, XR runtimes are Y-up) and footprints are polygons
around the points seen from above, turned with the object, so every degree is the same after
any rotation about up and any translation.

- pairwise, held by `RelationIndex`: `on`, `in_`, `under`, `above`, `below`, `near`,
  `next_to` (`degree(kind, a, b)`: how much `a` stands in `kind` to the anchor `b`);
- `between(a, b, c)`;
- from a viewpoint (the asker's position): `left_of`, `right_of`, `in_front_of`, `behind`;
- superlatives over a candidate set: `closest_to` / `farthest_from` (the asker or a thing),
  `biggest`, `smallest`, `highest`, `lowest`.

The functions take a `Body` (points prepared once for an up axis) or plain points; the
kinds' names (as the query grammar names them) map to them in PAIRWISE_RELATIONS,
VIEWPOINT_RELATIONS and SUPERLATIVES. Those that need only centroids or one number per thing
(between, viewpoint, superlatives) have a form over many things at once (`*_degrees`).

A question reads the map's geometry through a `RelationSource`: `RelationIndex`, kept as
objects change (the server), or `OnDemandRelations`, measured when asked (the device's local
map, which holds far more objects than it is asked about). Both give the same degrees.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Literal, Protocol

import numpy as np
from scipy.spatial import cKDTree

Z_UP = np.array([0.0, 0.0, 1.0])
"""Our synthetic world's up, and the default when no pose is known."""

# near / next to
NEAR_FULL_M = 0.2
"""Closest points at most this far apart: near with degree 1..."""
NEAR_MAX_M = 0.8
"""...falling smoothly to 0 here (0.5 at 0.5 m, the issue's "within ~0.5 m")."""
NEXT_TO_MIN_OVERLAP = 0.1
"""Next to: the height ranges overlap by at least this share of the shorter one's height..."""
NEXT_TO_FULL_OVERLAP = 0.5
"""...for degree 1 at this share (side by side at a similar height)."""
STACKED_MIN_SHARE = 0.3
"""Next to fades once this share of one object's points lies over the other's footprint..."""
STACKED_FULL_SHARE = 0.7
"""...and is 0 from this share (stacked or inside, not side by side)."""

# on / above / below / under
FOOTPRINT_MARGIN_M = 0.05
"""A footprint (`Footprint`: the polygon around a thing seen from above) is taken this much
wider when asking whether a thing stands over it (noisy edges), this much narrower when
asking whether it is covered."""
SUPPORT_MARGIN_M = 0.15
"""Where a thing stands, its support's points are looked for this far around its footprint:
the surface right under it is hidden by the thing itself, and a capped large object's
points are ~10 cm apart."""
HEIGHT_QUANTILE = 0.02
"""An object's bottom and top are its points' heights at this quantile from each end (a few
stray points do not lift or sink it)."""
ON_SLACK_M = 0.03
"""The support's surface may stand this much above a thing's bottom (noisy points, a bag
sunk into a cushion)."""
ON_FULL_GAP_M = 0.03
"""On: the bottom at most this far above the support's surface under it, degree 1..."""
ON_MAX_GAP_M = 0.10
"""...falling to 0 here ("within a few cm"); `above` takes over from the same gap."""
ON_MIN_SHARE = 0.3
"""On / above: at least this share of the thing's points over the support's footprint..."""
ON_FULL_SHARE = 0.7
"""...for degree 1 at this share ("most of its footprint over it")."""
ON_MIN_RISE_M = 0.02
"""On / above: a thing's bottom must stand more than this above the support's bottom (things
on one floor stand beside each other: a bag under a table by its feet, a ball in a box)..."""
ON_FULL_RISE_M = 0.04
"""...for degree 1 from this (a mug on a book lying flat)."""
COVER_CLEARANCE_M = 0.02
"""Under: what lies more than this above a thing's top covers it..."""
COVER_MIN_POINTS = 2
"""...when at least this many of its points are right over the thing."""
VERTICAL_FULL_GAP_M = 1.0
"""Above / below / under: a vertical gap up to this keeps degree 1..."""
VERTICAL_MAX_GAP_M = 2.0
"""...falling to 0 here (a lamp hanging over a table is above it; one on the ceiling of the
floor below is not)."""
UNDER_MIN_SHARE = 0.3
"""Under: at least this share of the smaller footprint covered by the thing above..."""
UNDER_FULL_SHARE = 0.7
"""...for degree 1 at this share."""

# in
IN_SLACK_M = 0.02
"""In: a point counts inside a container up to this far below its bottom or above its top."""
IN_MIN_SHARE = 0.3
"""In: at least this share of the thing's points inside the container's extent (its
footprint times its height range)..."""
IN_FULL_SHARE = 0.7
"""...for degree 1 at this share ("mostly inside")."""
IN_FLOOR_M = 0.03
"""The container's walls are its points from this above the thing's bottom (what it stands
on is a floor, not a wall)..."""
IN_RIM_M = 0.05
"""...to this below the container's top (a table's top and its edge are a lid, not a
wall)..."""
IN_EDGE_SHARE = 0.25
"""...each at most this share of the thing's (floor) or the container's (rim) height: an
apple in a bowl."""
IN_WALL_PATCH_M = 0.2
"""Each wall point stands for a patch this wide (a capped object's points are up to ~20 cm
apart), covering the arc it spans seen from the thing's centre..."""
IN_MIN_ENCLOSURE = 0.25
"""...and the walls must enclose at least this share of the full turn (a table's 4 legs seen
from under its middle: ~0.15; a bookcase's sides and back: ~0.75; a box: 1)..."""
IN_FULL_ENCLOSURE = 0.5
"""...for degree 1 at this share..."""
IN_FULL_OPENING_DEG = 90.0
"""...with no opening wider than this (a bookcase's front) for degree 1..."""
IN_MAX_OPENING_DEG = 180.0
"""...and 0 with one this wide (a sofa's back alone walls in half the turn)."""

# between
BETWEEN_LATERAL_M = 0.3
"""Between: the thing's centre within this of the line joining the two anchors' centres..."""
BETWEEN_LATERAL_SHARE = 0.25
"""...or within this share of the anchors' distance, whichever is wider, for degree 1; 0 at
twice that."""
BETWEEN_CLEAR_M = 0.05
"""Between: the thing's centre at least this far outside either anchor's footprint for degree
1, 0 over it."""
BETWEEN_END_SHARE = 0.15
"""Between: along the line, degree 1 from this share of the way from either anchor; 0 at
the anchors' centres."""

# viewpoint
LEFT_RIGHT_FULL_DEG = 10.0
"""Left / right of: degree 1 once the bearings, seen from the viewer, differ by this; 0 at
the same bearing."""
FRONT_FULL_M = 0.3
"""In front of / behind: degree 1 once the depths along the view direction differ by this..."""
FRONT_LATERAL_FULL_M = 0.5
"""...with the thing within this of the line of sight to the anchor (degree 1)..."""
FRONT_LATERAL_MAX_M = 1.5
"""...and 0 from here."""

# superlatives
DISTANCE_SCALE_M = 0.5
"""Closest / farthest: a candidate this much farther (nearer) than the winner has degree
1/e."""
HEIGHT_SCALE_M = 0.3
"""Highest / lowest: a candidate's centre this much lower (higher) than the winner's has
degree 1/e."""

FOOTPRINT_DIRECTIONS = 16
"""A footprint is the points' extents in this many directions seen from above (see
`Footprint`)."""
DENSE_DISTANCE_PAIRS = 12_000
"""Closest points by a dense distance matrix up to this many point pairs, a KD-tree beyond."""

PairwiseKind = Literal["on", "in", "under", "above", "below", "near", "next_to"]
PAIRWISE_KINDS: tuple[str, ...] = ("on", "in", "under", "above", "below", "near", "next_to")
VIEWPOINT_KINDS: tuple[str, ...] = ("left_of", "right_of", "in_front_of", "behind")


def snap_to_axis(vector: np.ndarray) -> np.ndarray:
    """The unit axis (±x, ±y or ±z, float64 [3]) nearest to `vector` (float [3], nonzero)."""
    vector = np.asarray(vector, np.float64)
    axis = int(np.argmax(np.abs(vector)))
    out = np.zeros(3)
    out[axis] = 1.0 if vector[axis] >= 0 else -1.0
    return out


def _rise(x: float, lo: float, hi: float) -> float:
    """Smoothstep: 0 at or below `lo`, 1 at or above `hi`, C1 in between."""
    t = min(max((float(x) - lo) / (hi - lo), 0.0), 1.0)
    return t * t * (3.0 - 2.0 * t)


def _fall(x: float, lo: float, hi: float) -> float:
    """1 at or below `lo`, 0 at or above `hi` (1 - `_rise`)."""
    return 1.0 - _rise(x, lo, hi)


class Footprint:
    """A thing seen from above: the convex polygon of its points' extents in
    FOOTPRINT_DIRECTIONS directions, turned with the thing (the first along its principal
    axis), so the same after any rotation about up. Exact for a box turned any way about up,
    2 % wider than a round thing; a tenth of the convex hull's cost.

    directions: float64 [K, 2] unit vectors; extents: float64 [K, 1] (inside where
    directions @ p <= extents); area: m².
    """

    __slots__ = ("_area", "directions", "extents")

    def __init__(self, plane: np.ndarray, centre: np.ndarray | None = None):
        """plane: float [2, N >= 1], the points seen from above (one row per axis); centre:
        their mean, float [2], if known."""
        if centre is None:
            centre = plane.mean(axis=1, dtype=np.float64)
        offsets = plane - centre[:, None]
        (xx, xy), (_, yy) = (offsets @ offsets.T).tolist()
        angle = 0.5 * math.atan2(2.0 * xy, xx - yy)  # along the principal axis
        self.directions = _DIRECTIONS @ np.array(
            [[math.cos(angle), math.sin(angle)], [-math.sin(angle), math.cos(angle)]]
        )
        self.extents = (self.directions @ plane).max(axis=1, keepdims=True)
        self._area: float | None = None

    @property
    def area(self) -> float:
        """m²: consecutive extent lines meet at the polygon's corners."""
        if self._area is None:
            (cos, sin), e = self.directions.T, self.extents[:, 0]
            cos_next, sin_next, e_next = cos[_NEXT], sin[_NEXT], e[_NEXT]
            x = (e * sin_next - e_next * sin) / _SIN_STEP
            y = (cos * e_next - cos_next * e) / _SIN_STEP
            self._area = float(0.5 * abs(np.dot(x, y[_NEXT]) - np.dot(x[_NEXT], y)))
        return self._area

    def outside_m(self, plane: np.ndarray) -> np.ndarray:
        """float64 [N]: how far each point (plane float [2, N]) lies outside the polygon
        along its worst direction (<= 0 inside)."""
        if plane.shape[1] == 0:
            return np.zeros(0)
        return (self.directions @ plane - self.extents).max(axis=0)

    def contains(self, plane: np.ndarray, margin_m: float = 0.0) -> np.ndarray:
        """bool [N]: the points (plane float [2, N]) inside the polygon grown by margin_m."""
        return self.outside_m(plane) <= margin_m


_TURNS = np.arange(FOOTPRINT_DIRECTIONS) * (2 * np.pi / FOOTPRINT_DIRECTIONS)
_DIRECTIONS = np.stack([np.cos(_TURNS), np.sin(_TURNS)], axis=1)
_SIN_STEP = np.sin(2 * np.pi / FOOTPRINT_DIRECTIONS)
_NEXT = (np.arange(FOOTPRINT_DIRECTIONS) + 1) % FOOTPRINT_DIRECTIONS


class Body:
    """One object's points prepared for relations along one up axis.

    local:    float [3, N >= 1]: the points in the up frame, one row per axis: the two world
              axes other than up (the view from above; a reflection for a negative up, which
              keeps distances and areas), then the height along up. The input's float type
              (float32 from deltas; float16 from the wire becomes float32).
    lo, hi:   float64 [3] the box corners in that frame (the prefilter)
    bottom, top: heights of the lowest / highest points (HEIGHT_QUANTILE from each end)
    centroid: float64 [3] world frame; centre: float64 [3] the same in the up frame
    footprint: the `Footprint` seen from above
    """

    __slots__ = (
        "axis",
        "bottom",
        "box",
        "centre",
        "centroid",
        "footprint",
        "hi",
        "lo",
        "local",
        "sign",
        "top",
    )

    def __init__(self, points: np.ndarray, up: np.ndarray = Z_UP):
        """points: float [N >= 1, 3] metres, world frame; up: a world axis (a vector off
        the axes counts as the nearest one)."""
        points = np.asarray(points)
        if not np.issubdtype(points.dtype, np.floating):
            points = points.astype(np.float64)
        elif points.dtype.itemsize < 4:  # float16 as on the wire: numpy computes it slowly
            points = points.astype(np.float32)
        if points.ndim != 2 or points.shape[1] != 3 or len(points) == 0:
            raise ValueError(f"a body needs points [N >= 1, 3], got shape {points.shape}")
        self.axis, self.sign = _axis_of(up)
        order = _frame_order(self.axis)
        local = self.local = np.empty((3, len(points)), points.dtype)
        local[0], local[1], local[2] = points[:, order[0]], points[:, order[1]], points[:, order[2]]
        if self.sign < 0:
            local[2] *= -1
        self.lo = local.min(axis=1).astype(np.float64)
        self.hi = local.max(axis=1).astype(np.float64)
        self.box = (*self.lo.tolist(), *self.hi.tolist())
        self.centre = local.mean(axis=1, dtype=np.float64)
        self.centroid = np.empty(3)
        self.centroid[order] = self.centre
        self.centroid[self.axis] *= self.sign
        k = int(HEIGHT_QUANTILE * (local.shape[1] - 1))
        if k == 0:
            self.bottom, self.top = self.box[2], self.box[5]
        else:
            ordered = np.partition(local[2], (k, local.shape[1] - 1 - k))
            self.bottom, self.top = float(ordered[k]), float(ordered[-1 - k])
        self.footprint = Footprint(local[:2], self.centre[:2])

    @property
    def up(self) -> np.ndarray:
        """The up axis, float64 [3]."""
        out = np.zeros(3)
        out[self.axis] = self.sign
        return out

    @property
    def height_m(self) -> float:
        return self.top - self.bottom

    @property
    def centre_height(self) -> float:
        """The centroid's height along up."""
        return float(self.centre[2])

    def volume_m3(self) -> float:
        """Footprint area times height: the size `biggest` / `smallest` compare."""
        return self.footprint.area * max(self.height_m, 0.0)

    def to_local(self, xyz: np.ndarray) -> np.ndarray:
        """float64 [3]: a world point in this body's up frame."""
        xyz = np.asarray(xyz, np.float64)[_frame_order(self.axis)]
        xyz[2] *= self.sign
        return xyz


def _frame_order(axis: int) -> list[int]:
    return [i for i in range(3) if i != axis] + [axis]


def _axis_of(up) -> tuple[int, float]:
    """(index, sign) of the world axis nearest to `up` (as `snap_to_axis`)."""
    x, y, z = np.asarray(up, np.float64).tolist()
    axis = max(range(3), key=lambda i: abs((x, y, z)[i]))
    return axis, 1.0 if (x, y, z)[axis] >= 0 else -1.0


BodyLike = Body | np.ndarray


def _body(x: BodyLike, up: np.ndarray) -> Body:
    return x if isinstance(x, Body) else Body(x, up)


def _bodies(*xs: BodyLike, up: np.ndarray) -> list[Body]:
    bodies = [_body(x, up) for x in xs]
    if len({(b.axis, b.sign) for b in bodies}) > 1:
        raise ValueError("bodies prepared for different up axes")
    return bodies


# -- shared pieces ------------------------------------------------------------------------


def _box_gaps(a: Body, b: Body) -> tuple[float, float, float]:
    """The gaps between the two boxes along each axis of the up frame (0 where they
    overlap): across, across, along up."""
    (a0, a1, a2, a3, a4, a5), (b0, b1, b2, b3, b4, b5) = a.box, b.box
    return (
        max(a0 - b3, b0 - a3, 0.0),
        max(a1 - b4, b1 - a4, 0.0),
        max(a2 - b5, b2 - a5, 0.0),
    )


def box_distance(a: Body, b: Body) -> float:
    """The distance between the two bodies' boxes (0 when they touch): a lower bound on the
    distance between their closest points."""
    g0, g1, g2 = _box_gaps(a, b)
    return (g0 * g0 + g1 * g1 + g2 * g2) ** 0.5


def _within_box(local: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    return ((local >= lo[:, None]) & (local <= hi[:, None])).all(axis=0)


def closest_distance(a: BodyLike, b: BodyLike, within_m: float = np.inf, up=Z_UP) -> float:
    """The distance between the closest points of two bodies (metres); inf when more than
    `within_m` (only points within reach of the other's box are compared, so a far pair costs
    almost nothing). Symmetric."""
    a, b = _bodies(a, b, up=up)
    return _closest_distance(a, b, within_m)


def _closest_distance(a: Body, b: Body, within_m: float) -> float:
    if (b.local.shape[1], b.box) < (a.local.shape[1], a.box):
        a, b = b, a  # one order for both calls: bit-for-bit symmetric
    floor = box_distance(a, b)
    if floor > within_m:
        return np.inf
    reach = min(within_m, floor + NEAR_FULL_M)  # most pairs settle at the first reach
    while True:
        near_a = a.local[:, _within_box(a.local, b.lo - reach, b.hi + reach)]
        near_b = b.local[:, _within_box(b.local, a.lo - reach, a.hi + reach)]
        found = _min_distance(near_a, near_b)
        # any pair within `reach` has both points in the subsets: the minimum is exact
        if found <= reach or reach >= within_m:
            return found if found <= within_m else np.inf
        reach = min(within_m, 2.0 * reach)


def _min_distance(p: np.ndarray, q: np.ndarray) -> float:
    """The smallest distance between point sets float [3, n] and [3, m]; inf if either is
    empty. Dense up to DENSE_DISTANCE_PAIRS pairs (in place: temporaries small enough not to
    be fresh pages), a KD-tree beyond."""
    n, m = p.shape[1], q.shape[1]
    if n == 0 or m == 0:
        return np.inf
    if n * m > DENSE_DISTANCE_PAIRS:
        small, large = (p, q) if n <= m else (q, p)
        return float(cKDTree(large.T).query(small.T, k=1)[0].min())
    origin = p[:, :1].astype(np.float64)  # near both: small squares, little cancellation
    p, q = p - origin, q - origin
    squared = p.T @ q
    squared *= -2.0
    squared += np.einsum("ij,ij->j", p, p)[:, None]
    squared += np.einsum("ij,ij->j", q, q)
    return float(np.sqrt(max(float(squared.min()), 0.0)))


def _footprints_overlap(a: Body, b: Body, margin_m: float) -> bool:
    """The boxes seen from above overlap when grown by margin_m (a prefilter for any
    footprint test)."""
    g0, g1, _ = _box_gaps(a, b)
    return g0 <= margin_m and g1 <= margin_m


def share_over(a: Body, b: Body, margin_m: float = 0.0) -> float:
    """The share of a's points over b's footprint (grown by margin_m), seen from above."""
    if not _footprints_overlap(a, b, margin_m):
        return 0.0
    return float(np.count_nonzero(b.footprint.contains(a.local[:2], margin_m))) / a.local.shape[1]


def _surface_under(a: Body, b: Body) -> float | None:
    """The height of b's surface under a: b's highest point around a's footprint
    (SUPPORT_MARGIN_M) not above a's bottom (ON_SLACK_M); None if b has none there."""
    heights = b.local[2]
    low = b.local[:, heights <= a.bottom + ON_SLACK_M]
    if low.shape[1] == 0:
        return None
    around = low[2, a.footprint.contains(low[:2], SUPPORT_MARGIN_M)]
    return float(around.max()) if len(around) else None


def covered_share(a: Body, b: Body) -> float:
    """How much b covers a from above, in [0, 1]: the part of b more than COVER_CLEARANCE_M
    above a's top must reach over a (COVER_MIN_POINTS of its points over a's footprint grown
    by FOOTPRINT_MARGIN_M: an open box's walls do not), then the share of the smaller
    footprint (a's, or that part's) well inside the other."""
    return _cover(a, b)[0]


def _cover(a: Body, b: Body, enough: float = 1.0) -> tuple[float, float]:
    """(`covered_share`, the height of b's lowest point over a above a's top); `enough`: a
    share past which the other footprint need not be measured (the caller's degree is full
    from there)."""
    if not _footprints_overlap(a, b, FOOTPRINT_MARGIN_M) or b.hi[2] <= a.top + COVER_CLEARANCE_M:
        return 0.0, np.inf
    upper = b.local[:, b.local[2] > a.top + COVER_CLEARANCE_M]
    outside = a.footprint.outside_m(upper[:2])
    over_a = outside <= FOOTPRINT_MARGIN_M
    count = int(np.count_nonzero(over_a))
    if count == 0:
        return 0.0, np.inf
    # well inside (FOOTPRINT_MARGIN_M in): a thing touching a sofa's back is not under it
    share = np.count_nonzero(outside <= -FOOTPRINT_MARGIN_M) / upper.shape[1]
    if share < enough:
        a_under = Footprint(upper[:2]).contains(a.local[:2], -FOOTPRINT_MARGIN_M)
        share = max(share, np.count_nonzero(a_under) / a.local.shape[1])
    clearance = float(upper[2, over_a].min()) - a.top
    return _rise(count, 0.0, COVER_MIN_POINTS) * share, clearance


# -- pairwise relations -------------------------------------------------------------------


def near(a: BodyLike, b: BodyLike, up=Z_UP) -> float:
    """Degree to which a and b are near: 1 with closest points within NEAR_FULL_M, falling
    to 0 at NEAR_MAX_M. Symmetric."""
    return _near(*_bodies(a, b, up=up))


def _near(a: Body, b: Body) -> float:
    distance = _closest_distance(a, b, NEAR_MAX_M)
    return _fall(distance, NEAR_FULL_M, NEAR_MAX_M) if distance <= NEAR_MAX_M else 0.0


def next_to(a: BodyLike, b: BodyLike, up=Z_UP) -> float:
    """Degree to which a is next to b: near, side by side at a similar height (their height
    ranges overlap), not stacked (neither mostly over the other's footprint). Symmetric."""
    a, b = _bodies(a, b, up=up)
    return _next_to(a, b, _near(a, b))


def _next_to(a: Body, b: Body, near_degree: float) -> float:
    if near_degree == 0.0:
        return 0.0
    overlap = min(a.top, b.top) - max(a.bottom, b.bottom)
    shorter = max(min(a.height_m, b.height_m), 1e-3)
    level = _rise(overlap / shorter, NEXT_TO_MIN_OVERLAP, NEXT_TO_FULL_OVERLAP)
    if level == 0.0:
        return 0.0
    stacked = max(share_over(a, b), share_over(b, a))
    return near_degree * level * _fall(stacked, STACKED_MIN_SHARE, STACKED_FULL_SHARE)


def on(a: BodyLike, b: BodyLike, up=Z_UP) -> float:
    """Degree to which a rests on b: a's bottom within ON_FULL_GAP_M (0 at ON_MAX_GAP_M)
    above b's surface under a (b's highest points around a's footprint up to a's bottom),
    most of a over b's footprint, a's bottom above b's (ON_MIN_RISE_M: not a bag under a
    table by its feet, not a ball in a box). a on b implies b not on a."""
    a, b = _bodies(a, b, up=up)
    return _support(a, b)[0]


def above(a: BodyLike, b: BodyLike, up=Z_UP) -> float:
    """Degree to which a is above b without resting on it: over b's footprint with a gap
    beyond `on`'s (up to VERTICAL_FULL_GAP_M, 0 at VERTICAL_MAX_GAP_M) above b's surface
    under it. on + above is 1 for a gap within VERTICAL_FULL_GAP_M."""
    a, b = _bodies(a, b, up=up)
    return _support(a, b)[1]


def below(a: BodyLike, b: BodyLike, up=Z_UP) -> float:
    """Degree to which a is below b: the converse of `above` (b above a)."""
    return above(b, a, up)


def _support(a: Body, b: Body) -> tuple[float, float]:
    """(on, above) of a over b: they share the footprint share and the gap."""
    raised = _rise(a.bottom - b.bottom, ON_MIN_RISE_M, ON_FULL_RISE_M)
    if raised == 0.0 or a.bottom - b.hi[2] > VERTICAL_MAX_GAP_M:
        return 0.0, 0.0
    spread = _rise(share_over(a, b, FOOTPRINT_MARGIN_M), ON_MIN_SHARE, ON_FULL_SHARE)
    if spread == 0.0:
        return 0.0, 0.0
    surface = _surface_under(a, b)
    if surface is None:
        return 0.0, 0.0
    gap = a.bottom - surface
    resting = _fall(gap, ON_FULL_GAP_M, ON_MAX_GAP_M)
    lifted = (1.0 - resting) * _fall(gap, VERTICAL_FULL_GAP_M, VERTICAL_MAX_GAP_M)
    return spread * raised * resting, spread * raised * lifted


def under(a: BodyLike, b: BodyLike, up=Z_UP) -> float:
    """Degree to which a is under b: b covers a from above (`covered_share`: the bag under
    the table, the book under the mug), its lowest part over a touching a or up to
    VERTICAL_FULL_GAP_M above a's top (0 at VERTICAL_MAX_GAP_M). a under b implies b not
    under a (a's top must be below b's)."""
    a, b = _bodies(a, b, up=up)
    return _under(a, b)


def _under(a: Body, b: Body) -> float:
    if not a.top < b.top:
        return 0.0
    share, clearance = _cover(a, b, UNDER_FULL_SHARE)
    covered = _rise(share, UNDER_MIN_SHARE, UNDER_FULL_SHARE)
    if covered == 0.0:
        return 0.0
    return covered * _fall(clearance, VERTICAL_FULL_GAP_M, VERTICAL_MAX_GAP_M)


def in_(a: BodyLike, b: BodyLike, up=Z_UP) -> float:
    """Degree to which a is in b: most of a's points inside b's extent (its footprint times
    its height range), and b's points at a's heights walling a in (a table's legs do not, nor
    a sofa's back alone). a in b implies b not in a (a's footprint must be the smaller)."""
    a, b = _bodies(a, b, up=up)
    return _in(a, b)


def _in(a: Body, b: Body) -> float:
    if not _footprints_overlap(a, b, 0.0) or not a.footprint.area < b.footprint.area:
        return 0.0
    heights = a.local[2]
    level = (heights >= b.bottom - IN_SLACK_M) & (heights <= b.top + IN_SLACK_M)
    count = len(heights)
    if np.count_nonzero(level) <= IN_MIN_SHARE * count:
        return 0.0
    inside = np.count_nonzero(b.footprint.contains(a.local[:2, level]))
    share = _rise(inside / count, IN_MIN_SHARE, IN_FULL_SHARE)
    return share * _enclosure(a, b) if share > 0.0 else 0.0


def _enclosure(a: Body, b: Body) -> float:
    """How well b's walls close a in, seen from above around a's centre, in [0, 1]: b's
    points from a's floor up to b's lid (all of a wall's height: a capped bookcase has a dozen
    points at a book's height) each cover the arc an IN_WALL_PATCH_M patch spans at its
    distance; enough of the turn covered and no wide opening."""
    heights = b.local[2]
    floor = a.bottom + min(IN_FLOOR_M, IN_EDGE_SHARE * a.height_m)
    ceiling = b.top - min(IN_RIM_M, IN_EDGE_SHARE * b.height_m)
    wall = (heights >= floor) & (heights <= ceiling)
    if not wall.any():
        return 0.0
    offsets = b.local[:2, wall] - a.centre[:2, None]
    distance = np.maximum(np.sqrt(np.einsum("ij,ij->j", offsets, offsets)), 1e-6)
    openings = _arc_openings(
        np.arctan2(offsets[1], offsets[0]), np.arctan(0.5 * IN_WALL_PATCH_M / distance)
    )
    covered = 1.0 - float(openings.sum()) / (2 * np.pi)
    widest_deg = float(np.degrees(openings.max()))
    return _rise(covered, IN_MIN_ENCLOSURE, IN_FULL_ENCLOSURE) * _fall(
        widest_deg, IN_FULL_OPENING_DEG, IN_MAX_OPENING_DEG
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


# -- between, viewpoint, superlatives -----------------------------------------------------
#
# These need only centroids (between, viewpoint, highest / lowest) or one number per thing
# (distances, sizes): each has a form over arrays of many things (`*_degrees`), which the
# functions on bodies call, so a question over thousands of things is one numpy pass.


def _horizontal(vectors: np.ndarray, up: np.ndarray) -> np.ndarray:
    """vectors (float [3] or [m, 3]) with their component along `up` removed."""
    return vectors - (vectors @ up)[..., None] * up


def _rise_many(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """`_rise` of each element of `x`."""
    t = np.clip((np.asarray(x, np.float64) - lo) / (hi - lo), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _fall_many(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
    return 1.0 - _rise_many(x, lo, hi)


FLOOR_WORDS = frozenset({"floor", "ground"})
"""Head nouns of the floor: an implicit surface when the map holds no object named so."""


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


def on_floor_degrees(bottoms: np.ndarray, floor: float) -> np.ndarray:
    """float64 [m]: how much things with these bottoms (heights along up) rest on the floor
    at `floor`: `on`'s gap ramp (1 within ON_FULL_GAP_M of it, 0 from ON_MAX_GAP_M)."""
    return _fall_many(np.asarray(bottoms, np.float64) - floor, ON_FULL_GAP_M, ON_MAX_GAP_M)


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
    segment = _horizontal(np.asarray(c, np.float64) - b, axis_up)
    length = float(np.linalg.norm(segment))
    if length < 1e-6:
        return np.zeros(len(subjects))
    offset = _horizontal(subjects - b, axis_up)
    t = (offset @ segment) / length**2
    lateral = np.linalg.norm(offset - t[:, None] * segment, axis=1)
    allowed = max(BETWEEN_LATERAL_M, BETWEEN_LATERAL_SHARE * length)
    along = _rise_many(t, 0.0, BETWEEN_END_SHARE) * _rise_many(1.0 - t, 0.0, BETWEEN_END_SHARE)
    degrees = along * _fall_many(lateral, allowed, 2.0 * allowed)
    for body in anchors or ():
        order = _frame_order(body.axis)
        plane = subjects[:, order[:2]].T  # seen from above, as the body's footprint is
        outside = body.footprint.outside_m(plane)
        degrees *= _rise_many(outside, 0.0, BETWEEN_CLEAR_M)
    return degrees


def between(a: BodyLike, b: BodyLike, c: BodyLike, up=Z_UP) -> float:
    """Degree to which a is between b and c, seen from above: a's centre near the segment
    joining theirs (BETWEEN_LATERAL_M or BETWEEN_LATERAL_SHARE of its length) and inside it
    (BETWEEN_END_SHARE from either end). Symmetric in b and c."""
    a, b, c = _bodies(a, b, c, up=up)
    return float(between_degrees(a.centroid[None], b.centroid, c.centroid, a.up, (b, c))[0])


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
    view = _horizontal(np.asarray(anchor, np.float64) - viewer, axis_up)
    reach = float(np.linalg.norm(view))
    if reach < 1e-6:
        return np.zeros(len(subjects))
    view /= reach
    to_subject = _horizontal(subjects - viewer, axis_up)
    depth = to_subject @ view
    if kind in ("left_of", "right_of"):
        # positive to the left: the subject's bearing from the line of sight to the anchor
        bearing = np.degrees(np.arctan2(np.cross(view, to_subject) @ axis_up, depth))
        return _rise_many(bearing if kind == "left_of" else -bearing, 0.0, LEFT_RIGHT_FULL_DEG)
    nearer = reach - depth  # how much nearer to the viewer than the anchor
    lateral = np.linalg.norm(to_subject - depth[:, None] * view, axis=1)
    ahead = _rise_many(nearer if kind == "in_front_of" else -nearer, 0.0, FRONT_FULL_M)
    return ahead * _fall_many(lateral, FRONT_LATERAL_FULL_M, FRONT_LATERAL_MAX_M)


def _viewpoint(kind: str, a: BodyLike, b: BodyLike, viewer: np.ndarray, up) -> float:
    a, b = _bodies(a, b, up=up)
    return float(viewpoint_degrees(kind, a.centroid[None], b.centroid, viewer, a.up)[0])


def left_of(a: BodyLike, b: BodyLike, viewer: np.ndarray, up=Z_UP) -> float:
    """Degree to which a is left of b seen from `viewer` (float [3], the asker's position):
    a's bearing left of b's by LEFT_RIGHT_FULL_DEG for degree 1."""
    return _viewpoint("left_of", a, b, viewer, up)


def right_of(a: BodyLike, b: BodyLike, viewer: np.ndarray, up=Z_UP) -> float:
    """Degree to which a is right of b seen from `viewer` (mirror of `left_of`)."""
    return _viewpoint("right_of", a, b, viewer, up)


def in_front_of(a: BodyLike, b: BodyLike, viewer: np.ndarray, up=Z_UP) -> float:
    """Degree to which a is in front of b seen from `viewer`: nearer along the view direction
    from the viewer to b (FRONT_FULL_M for degree 1), near the line of sight to b."""
    return _viewpoint("in_front_of", a, b, viewer, up)


def behind(a: BodyLike, b: BodyLike, viewer: np.ndarray, up=Z_UP) -> float:
    """Degree to which a is behind b seen from `viewer` (mirror of `in_front_of`)."""
    return _viewpoint("behind", a, b, viewer, up)


def distance_to(reference: BodyLike, body: Body) -> float:
    """Metres from the reference (a world point float [3], or a thing: a body or its points
    [N, 3]) to the body's closest point."""
    if isinstance(reference, Body) or np.ndim(reference) == 2:
        return _closest_distance(_body(reference, body.up), body, np.inf)
    offsets = body.local - body.to_local(reference)[:, None]
    return float(np.sqrt(np.einsum("ij,ij->j", offsets, offsets).min()))


def _distances_from(reference: BodyLike, bodies: list[Body]) -> np.ndarray:
    """float64 [n]: from the reference (as `distance_to`) to each body's closest point."""
    if bodies and not isinstance(reference, Body) and np.ndim(reference) == 2:
        reference = Body(reference, bodies[0].up)  # prepared once
    return np.array([distance_to(reference, body) for body in bodies], np.float64)


def closest_degrees(distances: np.ndarray, shortest_m: float | None = None) -> np.ndarray:
    """float64 [n]: `closest_to` from the candidates' distances (metres): 1 for the shortest
    (`shortest_m`, the least of `distances` unless given: the least over a larger set),
    exp(-extra distance / DISTANCE_SCALE_M) for the others."""
    distances = np.asarray(distances, np.float64)
    if len(distances) == 0:
        return distances
    shortest = distances.min() if shortest_m is None else shortest_m
    return np.exp(-(distances - shortest) / DISTANCE_SCALE_M)


def farthest_degrees(distances: np.ndarray, longest_m: float | None = None) -> np.ndarray:
    """float64 [n]: `farthest_from` from the candidates' distances (mirror of
    `closest_degrees`)."""
    distances = np.asarray(distances, np.float64)
    if len(distances) == 0:
        return distances
    longest = distances.max() if longest_m is None else longest_m
    return np.exp(-(longest - distances) / DISTANCE_SCALE_M)


def closest_to(reference: BodyLike, candidates: Sequence[BodyLike], up=Z_UP) -> np.ndarray:
    """float64 [n]: degree to which each candidate is the closest to `reference` (the asker's
    position float [3], or a thing: a body or its points [N, 3], "the lamp closest to the
    window") by closest points: 1 for the winner, exp(-extra distance / DISTANCE_SCALE_M)
    for the others."""
    return closest_degrees(_distances_from(reference, _bodies(*candidates, up=up)))


def farthest_from(reference: BodyLike, candidates: Sequence[BodyLike], up=Z_UP) -> np.ndarray:
    """float64 [n]: degree to which each candidate is the farthest from `reference` (mirror
    of `closest_to`)."""
    return farthest_degrees(_distances_from(reference, _bodies(*candidates, up=up)))


SizeMeasure = Literal["volume", "footprint"]


def _sizes(candidates: Sequence[BodyLike], by: SizeMeasure, up) -> np.ndarray:
    bodies = _bodies(*candidates, up=up)
    if by == "volume":
        return np.array([b.volume_m3() for b in bodies])
    return np.array([b.footprint.area for b in bodies])


def biggest_degrees(sizes: np.ndarray, largest: float | None = None) -> np.ndarray:
    """float64 [n]: `biggest` from the candidates' sizes: each over the largest (`largest`
    when given: the largest over a larger set), all 1 when that is 0."""
    sizes = np.asarray(sizes, np.float64)
    if len(sizes) == 0:
        return sizes
    top = sizes.max() if largest is None else largest
    return sizes / top if top > 0 else np.ones(len(sizes))


def smallest_degrees(sizes: np.ndarray) -> np.ndarray:
    """float64 [n]: `smallest` from the candidates' sizes: the smallest over each one's."""
    sizes = np.asarray(sizes, np.float64)
    if len(sizes) == 0:
        return sizes
    smallest_size = sizes.min()
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(sizes > 0, smallest_size / sizes, 1.0)


def biggest(candidates: Sequence[BodyLike], by: SizeMeasure = "volume", up=Z_UP) -> np.ndarray:
    """float64 [n]: each candidate's size over the largest (1 for the winner), by volume
    (footprint area times height) or footprint area (m²)."""
    return biggest_degrees(_sizes(candidates, by, up))


def smallest(candidates: Sequence[BodyLike], by: SizeMeasure = "volume", up=Z_UP) -> np.ndarray:
    """float64 [n]: the smallest candidate's size over each one's (1 for the winner)."""
    return smallest_degrees(_sizes(candidates, by, up))


def highest_degrees(heights: np.ndarray) -> np.ndarray:
    """float64 [n]: `highest` from the candidates' centre heights along up (metres)."""
    heights = np.asarray(heights, np.float64)
    if len(heights) == 0:
        return heights
    return np.exp(-(heights.max() - heights) / HEIGHT_SCALE_M)


def lowest_degrees(heights: np.ndarray) -> np.ndarray:
    """float64 [n]: `lowest` from the candidates' centre heights (mirror of
    `highest_degrees`)."""
    heights = np.asarray(heights, np.float64)
    if len(heights) == 0:
        return heights
    return np.exp(-(heights - heights.min()) / HEIGHT_SCALE_M)


def highest(candidates: Sequence[BodyLike], up=Z_UP) -> np.ndarray:
    """float64 [n]: by centre height along up, 1 for the highest, exp(-drop / HEIGHT_SCALE_M)
    for others."""
    return highest_degrees([b.centre_height for b in _bodies(*candidates, up=up)])


def lowest(candidates: Sequence[BodyLike], up=Z_UP) -> np.ndarray:
    """float64 [n]: mirror of `highest`."""
    return lowest_degrees([b.centre_height for b in _bodies(*candidates, up=up)])


def heights_along(centroids: np.ndarray, up=Z_UP) -> np.ndarray:
    """float64 [m]: the height along up of each centroid (float [m, 3], world frame): what
    `Body.centre_height` gives for a body with that centroid."""
    axis, sign = _axis_of(up)
    return sign * np.asarray(centroids, np.float64).reshape(-1, 3)[:, axis]


# -- bounds from boxes (which things a question may skip) ----------------------------------


def box_distance_bounds(
    lo: np.ndarray, hi: np.ndarray, ref_lo: np.ndarray, ref_hi: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(lower float64 [m], upper float64 [m]) metres: bounds on the distance between any
    point of each box (lo, hi float [m, 3]) and any point of the reference box (ref_lo,
    ref_hi float [3]; a point is a box with lo = hi), so on the closest-points distance of
    the things inside them. Any frame, as long as both are in it."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    gap = np.maximum(np.maximum(lo - ref_hi, ref_lo - hi), 0.0)
    span = np.maximum(np.abs(hi - ref_lo), np.abs(ref_hi - lo))
    return np.sqrt(np.einsum("ij,ij->i", gap, gap)), np.sqrt(np.einsum("ij,ij->i", span, span))


_FOOTPRINT_IN_DISC = FOOTPRINT_DIRECTIONS * math.tan(math.pi / FOOTPRINT_DIRECTIONS)
"""A `Footprint` of points within a disc of radius R lies inside the regular polygon
circumscribed about that disc (each extent is at most the disc's): area <= this x R²."""


def volume_upper_bounds(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """float64 [m] m³: bounds on `Body.volume_m3` of the things within each box (lo, hi float
    [m, 3] in the up frame): the polygon about the disc holding the box seen from above, times
    the box's height."""
    size = np.asarray(hi, np.float64) - np.asarray(lo, np.float64)
    radius_squared = 0.25 * (size[:, 0] ** 2 + size[:, 1] ** 2)
    return _FOOTPRINT_IN_DISC * radius_squared * np.maximum(size[:, 2], 0.0) * (1 + 1e-9) + 1e-12


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
VIEWPOINT_RELATIONS: dict[str, Callable[..., float]] = {
    "left_of": left_of,
    "right_of": right_of,
    "in_front_of": in_front_of,
    "behind": behind,
}
"""Each viewpoint kind's function (subject, anchor, viewer, up=...) -> degree."""
SUPERLATIVES: dict[str, Callable[..., np.ndarray]] = {
    "closest": closest_to,
    "farthest": farthest_from,
    "biggest": biggest,
    "smallest": smallest,
    "highest": highest,
    "lowest": lowest,
}
"""Each superlative's function: (reference, candidates, up=...) for closest / farthest,
(candidates, up=...) for the others -> degrees [n]."""


# -- the index ----------------------------------------------------------------------------

# Per unordered pair (a < b), one float64 row: near, next_to, then each directed relation
# a→b and b→a; `below` is `above` read the other way.
_NEAR, _NEXT_TO, _ON, _IN, _UNDER, _ABOVE = 0, 1, 2, 4, 6, 8
_PAIR_WIDTH = 10
_SLOT = {"near": _NEAR, "next_to": _NEXT_TO, "on": _ON, "in": _IN, "under": _UNDER, "above": _ABOVE}


def pair_degrees(a: Body, b: Body) -> np.ndarray:
    """float64 [10]: every pairwise degree of two bodies: near, next_to, on (a→b, b→a), in,
    under, above (each both ways). `RelationIndex` holds these rows."""
    out = np.zeros(_PAIR_WIDTH)
    gaps = _box_gaps(a, b)
    if gaps[0] ** 2 + gaps[1] ** 2 + gaps[2] ** 2 <= NEAR_MAX_M**2:
        out[_NEAR] = near_degree = _near(a, b)
        out[_NEXT_TO] = _next_to(a, b, near_degree)
        out[_IN], out[_IN + 1] = _in(a, b), _in(b, a)
    if _in_column(gaps):
        out[_ON], out[_ABOVE] = _support(a, b)
        out[_ON + 1], out[_ABOVE + 1] = _support(b, a)
        out[_UNDER], out[_UNDER + 1] = _under(a, b), _under(b, a)
    return out


def _in_column(gaps: tuple[float, float, float]) -> bool:
    """Box gaps (`_box_gaps`) within FOOTPRINT_MARGIN_M seen from above and within
    VERTICAL_MAX_GAP_M along up: the prefilter of on / above / below / under."""
    return (
        gaps[0] <= FOOTPRINT_MARGIN_M
        and gaps[1] <= FOOTPRINT_MARGIN_M
        and gaps[2] <= VERTICAL_MAX_GAP_M
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
    within NEAR_MAX_M, or over one another (`_in_column`). Every pairwise degree of things
    whose boxes fail it is 0. With a pairwise `kind`, only that relation's: near and next_to
    within NEAR_MAX_M, the others (on, in, under, above, below) over one another."""
    gap = np.maximum(np.maximum(lo - box_hi, box_lo - hi), 0.0)
    close = np.einsum("ij,ij->i", gap, gap) <= NEAR_MAX_M**2
    if kind in ("near", "next_to"):
        return close
    column = (
        (gap[:, 0] <= FOOTPRINT_MARGIN_M)
        & (gap[:, 1] <= FOOTPRINT_MARGIN_M)
        & (gap[:, 2] <= VERTICAL_MAX_GAP_M)
    )
    return column if kind in PAIRWISE_KINDS else close | column


def boxes_in_up_frame(
    lo: np.ndarray, hi: np.ndarray, up: np.ndarray = Z_UP
) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) float64 [n, 3]: world-frame boxes (lo, hi float [n, 3]) in the up frame, as
    `Body.lo` / `Body.hi` have them (the two axes across up, then the height)."""
    axis, sign = _axis_of(up)
    order = _frame_order(axis)
    lo_up = np.asarray(lo, np.float64).reshape(-1, 3)[:, order]
    hi_up = np.asarray(hi, np.float64).reshape(-1, 3)[:, order]
    if sign < 0:  # heights flip: the box's top becomes its bottom
        lo_up[:, 2], hi_up[:, 2] = -hi_up[:, 2], -lo_up[:, 2]
    return lo_up, hi_up


@dataclass(frozen=True)
class ObjectGeometry:
    """What a delta carries about one object's shape."""

    label: str
    points: np.ndarray
    """float [N >= 1, 3] metres, world frame (the client-capped points)."""


@dataclass(frozen=True)
class Relation:
    """`subject` stands in `kind` to `anchor` with `degree` in (0, 1]."""

    kind: str
    subject: int
    anchor: int
    degree: float


class RelationIndex:
    """The pairwise relations of a map's objects, kept as objects change.

    Holds each object's `Body` and label, the pairs within reach of each other (boxes within
    NEAR_MAX_M, or over one another within VERTICAL_MAX_GAP_M: the only pairs with a degree
    above 0), and their degrees of on, in, under, above, below, near and next_to.

    `update` prepares the changed objects' bodies and marks the pairs within reach of them
    stale; a stale pair's degrees are computed when first read (`degree`, `pairs`,
    `relations_of`) or by `settle`. Only pairs touching a changed object are ever recomputed,
    and keyframes come far more often than questions: a pair re-observed for a minute is
    computed once, when asked about. No I/O, no clock: the server and the device's local map
    each keep one.
    """

    def __init__(self, up: np.ndarray = Z_UP):
        self.up = snap_to_axis(up)
        self._bodies: dict[int, Body] = {}
        self._labels: dict[int, str] = {}
        self._reach: dict[int, set[int]] = {}
        """id -> the ids within reach of it (settled or stale)."""
        self._degrees: dict[tuple[int, int], np.ndarray] = {}
        """(smaller id, larger id) -> `pair_degrees` of the settled pairs with any above 0."""
        self._stale: set[tuple[int, int]] = set()
        # the boxes (up frame) as rows for the prefilter; a free row has id -1
        self._row_of: dict[int, int] = {}
        self._row_ids = np.full(16, -1, np.int64)
        self._lo = np.full((16, 3), np.inf)
        self._hi = np.full((16, 3), -np.inf)
        self._free: list[int] = list(range(15, -1, -1))

    def __len__(self) -> int:
        return len(self._bodies)

    def __contains__(self, object_id: int) -> bool:
        return object_id in self._bodies

    def body(self, object_id: int) -> Body:
        return self._bodies[object_id]

    def label(self, object_id: int) -> str:
        return self._labels[object_id]

    def ids(self) -> list[int]:
        return list(self._bodies)

    @property
    def stale_pairs(self) -> int:
        """Pairs whose degrees will be computed when next read."""
        return len(self._stale)

    def update(
        self, upserts: Mapping[int, ObjectGeometry], removed: Iterable[int] = ()
    ) -> list[int]:
        """Apply one delta: objects created or changed, objects gone. Returns the ids whose
        geometry changed (their pairs are now stale); a new label alone is just replaced."""
        for object_id in removed:
            if object_id in self._bodies:
                self._forget(object_id)
        changed: list[int] = []
        for object_id, geometry in upserts.items():
            self._labels[object_id] = geometry.label
            body = Body(geometry.points, self.up)
            held = self._bodies.get(object_id)
            if held is not None:
                if np.array_equal(held.local, body.local):
                    continue
                self._forget(object_id, keep_label=True)
            self._remember(object_id, body)
            changed.append(object_id)
        for object_id in changed:
            reach = self._reach[object_id]
            for other in self._candidates(self._bodies[object_id]).tolist():
                if other != object_id:
                    reach.add(other)
                    self._reach[other].add(object_id)
                    self._stale.add((object_id, other) if object_id < other else (other, object_id))
        return changed

    def settle(self) -> int:
        """Compute every stale pair now; returns how many were."""
        stale = len(self._stale)
        while self._stale:
            self._settle(self._stale.pop())
        return stale

    def _settle(self, key: tuple[int, int]) -> None:
        degrees = pair_degrees(self._bodies[key[0]], self._bodies[key[1]])
        if degrees.any():
            self._degrees[key] = degrees
        else:
            self._degrees.pop(key, None)

    def _row(self, subject: int, anchor: int) -> np.ndarray | None:
        key = (subject, anchor) if subject < anchor else (anchor, subject)
        if key in self._stale:
            self._stale.discard(key)
            self._settle(key)
        return self._degrees.get(key)

    def _candidates(self, body: Body) -> np.ndarray:
        """Ids of the objects whose boxes pass `pair_degrees`'s prefilters with `body`."""
        return self._row_ids[
            within_reach(self._lo, self._hi, body.lo, body.hi) & (self._row_ids >= 0)
        ]

    def _remember(self, object_id: int, body: Body) -> None:
        self._bodies[object_id] = body
        self._reach[object_id] = set()
        if not self._free:
            grown = len(self._row_ids)
            self._row_ids = np.concatenate([self._row_ids, np.full(grown, -1, np.int64)])
            self._lo = np.concatenate([self._lo, np.full((grown, 3), np.inf)])
            self._hi = np.concatenate([self._hi, np.full((grown, 3), -np.inf)])
            self._free = list(range(2 * grown - 1, grown - 1, -1))
        row = self._free.pop()
        self._row_of[object_id] = row
        self._row_ids[row] = object_id
        self._lo[row], self._hi[row] = body.lo, body.hi

    def _forget(self, object_id: int, keep_label: bool = False) -> None:
        del self._bodies[object_id]
        if not keep_label:
            del self._labels[object_id]
        for other in self._reach.pop(object_id):
            self._reach[other].discard(object_id)
            key = (object_id, other) if object_id < other else (other, object_id)
            self._degrees.pop(key, None)
            self._stale.discard(key)
        row = self._row_of.pop(object_id)
        self._row_ids[row] = -1
        self._lo[row], self._hi[row] = np.inf, -np.inf
        self._free.append(row)

    def degree(self, kind: PairwiseKind, subject: int, anchor: int) -> float:
        """How much `subject` stands in `kind` to `anchor` (0 for a pair out of reach or an
        unknown id)."""
        if kind == "below":
            kind, subject, anchor = "above", anchor, subject  # type: ignore[assignment]
        slot = _SLOT.get(kind)
        if slot is None:
            raise ValueError(f"unknown relation {kind!r}; one of {PAIRWISE_KINDS}")
        if anchor not in self._reach.get(subject, ()):
            return 0.0
        row = self._row(subject, anchor)
        if row is None:
            return 0.0
        directed = kind not in ("near", "next_to")
        return float(row[slot + 1 if directed and subject > anchor else slot])

    def degrees(self, kind: str, anchor: int, subjects: np.ndarray) -> np.ndarray:
        """float64 [m]: how much each of `subjects` (ids int [m]) stands in `kind` to `anchor`
        (0 out of reach, for the anchor itself and for unknown ids); only the pairs within
        reach of the anchor are computed."""
        if kind != "below" and kind not in _SLOT:
            raise ValueError(f"unknown relation {kind!r}; one of {PAIRWISE_KINDS}")
        subjects = np.asarray(subjects, np.int64)
        out = np.zeros(len(subjects))
        reach = self._reach.get(anchor)
        if reach:
            within = np.isin(subjects, np.fromiter(reach, np.int64, len(reach)))
            for i in np.flatnonzero(within).tolist():
                out[i] = self.degree(kind, int(subjects[i]), anchor)  # type: ignore[arg-type]
        return out

    def bodies(self, ids: np.ndarray) -> list[Body]:
        return [self._bodies[int(i)] for i in ids]

    def centroids(self, ids: np.ndarray) -> np.ndarray:
        """float64 [m, 3]: the bodies' centroids, world frame."""
        return np.array([self._bodies[int(i)].centroid for i in ids], np.float64).reshape(-1, 3)

    def boxes(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) float64 [m, 3]: the bodies' boxes in the up frame."""
        rows = [self._row_of[int(i)] for i in ids]
        return self._lo[rows].reshape(-1, 3), self._hi[rows].reshape(-1, 3)

    def relations_of(self, object_id: int) -> list[Relation]:
        """Every relation with a degree above 0 that `object_id` takes part in, as subject or
        as anchor (near and next_to listed once, with `object_id` as subject)."""
        out: list[Relation] = []
        for other in sorted(self._reach.get(object_id, ())):
            if self._row(object_id, other) is None:
                continue
            for kind in PAIRWISE_KINDS:
                pairs = [(object_id, other)]
                if kind not in ("near", "next_to"):
                    pairs.append((other, object_id))
                for subject, anchor in pairs:
                    value = self.degree(kind, subject, anchor)  # type: ignore[arg-type]
                    if value > 0.0:
                        out.append(Relation(kind, subject, anchor, value))
        return out

    def pairs(
        self,
        kind: PairwiseKind,
        subject: int | None = None,
        anchor: int | None = None,
        min_degree: float = 0.0,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(subjects int64 [m], anchors int64 [m], degrees float64 [m]): every pair standing
        in `kind` with degree above min_degree, only those with this subject and / or this
        anchor when given. Symmetric kinds (near, next_to) list each pair both ways. With a
        subject or an anchor only that object's stale pairs are computed; without, all of the
        map's (the first such read after building a large map computes every pair)."""
        if kind not in PAIRWISE_KINDS:
            raise ValueError(f"unknown relation {kind!r}; one of {PAIRWISE_KINDS}")
        if subject is not None:
            others = self._reach.get(subject, set())
            candidates = [(subject, o) for o in others if anchor is None or o == anchor]
        elif anchor is not None:
            candidates = [(o, anchor) for o in self._reach.get(anchor, ())]
        else:
            self.settle()
            candidates = [(x, y) for x, y in self._degrees] + [(y, x) for x, y in self._degrees]
        found = [(s, t, self.degree(kind, s, t)) for s, t in candidates]
        found = [(s, t, d) for s, t, d in found if d > min_degree]
        found.sort()
        return (
            np.array([s for s, _, _ in found], np.int64),
            np.array([t for _, t, _ in found], np.int64),
            np.array([d for _, _, d in found], np.float64),
        )


class RelationSource(Protocol):
    """What a question reads of a map's geometry (`app.mapping.relational.answer`): kept up
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
