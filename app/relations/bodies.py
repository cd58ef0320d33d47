"""Bodies and footprints: one object's points prepared for relations along one up axis.

Heights are taken along `up` (a world axis: our synthetic world is Z-up, XR runtimes are
Y-up) and footprints are polygons around the points seen from above, turned with the object,
so every degree is the same after any rotation about up and any translation. Boxes are only
a prefilter; the closest-points distance between two bodies is here too (near, closest).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from app.relations.thresholds import THRESHOLDS as T

Z_UP = np.array([0.0, 0.0, 1.0])
"""Our synthetic world's up, and the default when no pose is known."""


def snap_to_axis(vector: np.ndarray) -> np.ndarray:
    """The unit axis (±x, ±y or ±z, float64 [3]) nearest to `vector` (float [3], nonzero)."""
    vector = np.asarray(vector, np.float64)
    axis = int(np.argmax(np.abs(vector)))
    out = np.zeros(3)
    out[axis] = 1.0 if vector[axis] >= 0 else -1.0
    return out


class Footprint:
    """A thing seen from above: the convex polygon of its points' extents in
    footprint_directions directions, turned with the thing (the first along its principal
    axis), so the same after any rotation about up. Exact for a box turned any way about up,
    2 % wider than a round thing; a tenth of the convex hull's cost.

    directions: float64 [K, 2] unit vectors; extents: float64 [K, 1] (inside where
    directions @ p <= extents); area: m².
    """

    __slots__ = ("_area", "_bounds", "directions", "extents")

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
        self._bounds: tuple[float, float, float, float] | None = None

    def _corners(self) -> tuple[np.ndarray, np.ndarray]:
        """The polygon's corners (x float64 [K], y float64 [K]): where consecutive extent
        lines meet."""
        (cos, sin), e = self.directions.T, self.extents[:, 0]
        cos_next, sin_next, e_next = cos[_NEXT], sin[_NEXT], e[_NEXT]
        x = (e * sin_next - e_next * sin) / _SIN_STEP
        y = (cos * e_next - cos_next * e) / _SIN_STEP
        return x, y

    @property
    def area(self) -> float:
        """m²."""
        if self._area is None:
            x, y = self._corners()
            self._area = float(0.5 * abs(np.dot(x, y[_NEXT]) - np.dot(x[_NEXT], y)))
        return self._area

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(x min, y min, x max, y max) of the polygon. Wider than its points' box where a
        corner of the polygon stands past it (its sides are turned with the thing, not with
        the axes): a test of points against the polygon must not be cut short by the box."""
        if self._bounds is None:
            x, y = self._corners()
            self._bounds = (float(x.min()), float(y.min()), float(x.max()), float(y.max()))
        return self._bounds

    def outside_m(self, plane: np.ndarray) -> np.ndarray:
        """float64 [N]: how far each point (plane float [2, N]) lies outside the polygon
        along its worst direction (<= 0 inside)."""
        if plane.shape[1] == 0:
            return np.zeros(0)
        return (self.directions @ plane - self.extents).max(axis=0)

    def contains(self, plane: np.ndarray, margin_m: float = 0.0) -> np.ndarray:
        """bool [N]: the points (plane float [2, N]) inside the polygon grown by margin_m."""
        return self.outside_m(plane) <= margin_m


_TURNS = np.arange(T.footprint_directions) * (2 * np.pi / T.footprint_directions)
_DIRECTIONS = np.stack([np.cos(_TURNS), np.sin(_TURNS)], axis=1)
_SIN_STEP = np.sin(2 * np.pi / T.footprint_directions)
_NEXT = (np.arange(T.footprint_directions) + 1) % T.footprint_directions


class Body:
    """One object's points prepared for relations along one up axis.

    local:    float [3, N >= 1]: the points in the up frame, one row per axis: the two world
              axes other than up (the view from above; a reflection for a negative up, which
              keeps distances and areas), then the height along up. The input's float type
              (float32 from deltas; float16 from the wire becomes float32).
    lo, hi:   float64 [3] the box corners in that frame (the prefilter)
    bottom, top: heights of the lowest / highest points (height_quantile from each end)
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
        self.axis, self.sign = axis_of(up)
        order = frame_order(self.axis)
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
        k = int(T.height_quantile * (local.shape[1] - 1))
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
        xyz = np.asarray(xyz, np.float64)[frame_order(self.axis)]
        xyz[2] *= self.sign
        return xyz


def frame_order(axis: int) -> list[int]:
    return [i for i in range(3) if i != axis] + [axis]


def axis_of(up) -> tuple[int, float]:
    """(index, sign) of the world axis nearest to `up` (as `snap_to_axis`)."""
    x, y, z = np.asarray(up, np.float64).tolist()
    axis = max(range(3), key=lambda i: abs((x, y, z)[i]))
    return axis, 1.0 if (x, y, z)[axis] >= 0 else -1.0


BodyLike = Body | np.ndarray


def as_body(x: BodyLike, up: np.ndarray) -> Body:
    return x if isinstance(x, Body) else Body(x, up)


def as_bodies(*xs: BodyLike, up: np.ndarray) -> list[Body]:
    bodies = [as_body(x, up) for x in xs]
    if len({(b.axis, b.sign) for b in bodies}) > 1:
        raise ValueError("bodies prepared for different up axes")
    return bodies


def box_gaps(a: Body, b: Body) -> tuple[float, float, float]:
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
    g0, g1, g2 = box_gaps(a, b)
    return (g0 * g0 + g1 * g1 + g2 * g2) ** 0.5


def _within_box(local: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    return ((local >= lo[:, None]) & (local <= hi[:, None])).all(axis=0)


def closest_distance(a: BodyLike, b: BodyLike, within_m: float = np.inf, up=Z_UP) -> float:
    """The distance between the closest points of two bodies (metres); inf when more than
    `within_m` (only points within reach of the other's box are compared, so a far pair costs
    almost nothing). Symmetric."""
    a, b = as_bodies(a, b, up=up)
    return closest_distance_m(a, b, within_m)


def closest_distance_m(a: Body, b: Body, within_m: float) -> float:
    if (b.local.shape[1], b.box) < (a.local.shape[1], a.box):
        a, b = b, a  # one order for both calls: bit-for-bit symmetric
    floor = box_distance(a, b)
    if floor > within_m:
        return np.inf
    reach = min(within_m, floor + T.near_full_m)  # most pairs settle at the first reach
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
    empty. Dense up to dense_distance_pairs pairs (in place: temporaries small enough not to
    be fresh pages), a KD-tree beyond."""
    n, m = p.shape[1], q.shape[1]
    if n == 0 or m == 0:
        return np.inf
    if n * m > T.dense_distance_pairs:
        small, large = (p, q) if n <= m else (q, p)
        return float(cKDTree(large.T).query(small.T, k=1)[0].min())
    origin = p[:, :1].astype(np.float64)  # near both: small squares, little cancellation
    p, q = p - origin, q - origin
    squared = p.T @ q
    squared *= -2.0
    squared += np.einsum("ij,ij->j", p, p)[:, None]
    squared += np.einsum("ij,ij->j", q, q)
    return float(np.sqrt(max(float(squared.min()), 0.0)))


def footprints_overlap(a: Body, b: Body, margin_m: float) -> bool:
    """The footprints' bounds overlap when grown by margin_m (a prefilter for any footprint
    test: each footprint's bounds hold its points and its polygon)."""
    a0, a1, a2, a3 = a.footprint.bounds
    b0, b1, b2, b3 = b.footprint.bounds
    return max(a0 - b2, b0 - a2) <= margin_m and max(a1 - b3, b1 - a3) <= margin_m


def share_over(a: Body, b: Body, margin_m: float = 0.0) -> float:
    """The share of a's points over b's footprint (grown by margin_m), seen from above."""
    if not footprints_overlap(a, b, margin_m):
        return 0.0
    return float(np.count_nonzero(b.footprint.contains(a.local[:2], margin_m))) / a.local.shape[1]


def horizontal(vectors: np.ndarray, up: np.ndarray) -> np.ndarray:
    """vectors (float [3] or [m, 3]) with their component along `up` removed."""
    return vectors - (vectors @ up)[..., None] * up


def boxes_in_up_frame(
    lo: np.ndarray, hi: np.ndarray, up: np.ndarray = Z_UP
) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) float64 [n, 3]: world-frame boxes (lo, hi float [n, 3]) in the up frame, as
    `Body.lo` / `Body.hi` have them (the two axes across up, then the height)."""
    axis, sign = axis_of(up)
    order = frame_order(axis)
    lo_up = np.asarray(lo, np.float64).reshape(-1, 3)[:, order]
    hi_up = np.asarray(hi, np.float64).reshape(-1, 3)[:, order]
    if sign < 0:  # heights flip: the box's top becomes its bottom
        lo_up[:, 2], hi_up[:, 2] = -hi_up[:, 2], -lo_up[:, 2]
    return lo_up, hi_up
