"""Superlatives over a candidate set: closest_to / farthest_from (the asker or a thing),
biggest, smallest, highest, lowest.

Each needs one number per thing (a distance, a size, a height) and has a form over those
numbers (`*_degrees`), which the functions on bodies call; the bounds from boxes tell a
question which candidates cannot win and need no body (`box_distance_bounds`,
`volume_upper_bounds`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Literal

import numpy as np

from app.relations.bodies import (
    Z_UP,
    Body,
    BodyLike,
    as_bodies,
    as_body,
    axis_of,
    closest_distance_m,
)
from app.relations.thresholds import THRESHOLDS as T


def distance_to(reference: BodyLike, body: Body) -> float:
    """Metres from the reference (a world point float [3], or a thing: a body or its points
    [N, 3]) to the body's closest point."""
    if isinstance(reference, Body) or np.ndim(reference) == 2:
        return closest_distance_m(as_body(reference, body.up), body, np.inf)
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
    exp(-extra distance / distance_scale_m) for the others."""
    distances = np.asarray(distances, np.float64)
    if len(distances) == 0:
        return distances
    shortest = distances.min() if shortest_m is None else shortest_m
    return np.exp(-(distances - shortest) / T.distance_scale_m)


def farthest_degrees(distances: np.ndarray, longest_m: float | None = None) -> np.ndarray:
    """float64 [n]: `farthest_from` from the candidates' distances (mirror of
    `closest_degrees`)."""
    distances = np.asarray(distances, np.float64)
    if len(distances) == 0:
        return distances
    longest = distances.max() if longest_m is None else longest_m
    return np.exp(-(longest - distances) / T.distance_scale_m)


def closest_to(reference: BodyLike, candidates: Sequence[BodyLike], up=Z_UP) -> np.ndarray:
    """float64 [n]: degree to which each candidate is the closest to `reference` (the asker's
    position float [3], or a thing: a body or its points [N, 3], "the lamp closest to the
    window") by closest points: 1 for the winner, exp(-extra distance / distance_scale_m)
    for the others."""
    return closest_degrees(_distances_from(reference, as_bodies(*candidates, up=up)))


def farthest_from(reference: BodyLike, candidates: Sequence[BodyLike], up=Z_UP) -> np.ndarray:
    """float64 [n]: degree to which each candidate is the farthest from `reference` (mirror
    of `closest_to`)."""
    return farthest_degrees(_distances_from(reference, as_bodies(*candidates, up=up)))


SizeMeasure = Literal["volume", "footprint"]


def _sizes(candidates: Sequence[BodyLike], by: SizeMeasure, up) -> np.ndarray:
    bodies = as_bodies(*candidates, up=up)
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
    return np.exp(-(heights.max() - heights) / T.height_scale_m)


def lowest_degrees(heights: np.ndarray) -> np.ndarray:
    """float64 [n]: `lowest` from the candidates' centre heights (mirror of
    `highest_degrees`)."""
    heights = np.asarray(heights, np.float64)
    if len(heights) == 0:
        return heights
    return np.exp(-(heights - heights.min()) / T.height_scale_m)


def highest(candidates: Sequence[BodyLike], up=Z_UP) -> np.ndarray:
    """float64 [n]: by centre height along up, 1 for the highest, exp(-drop / height_scale_m)
    for others."""
    return highest_degrees([b.centre_height for b in as_bodies(*candidates, up=up)])


def lowest(candidates: Sequence[BodyLike], up=Z_UP) -> np.ndarray:
    """float64 [n]: mirror of `highest`."""
    return lowest_degrees([b.centre_height for b in as_bodies(*candidates, up=up)])


def heights_along(centroids: np.ndarray, up=Z_UP) -> np.ndarray:
    """float64 [m]: the height along up of each centroid (float [m, 3], world frame): what
    `Body.centre_height` gives for a body with that centroid."""
    axis, sign = axis_of(up)
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


_FOOTPRINT_IN_DISC = T.footprint_directions * math.tan(math.pi / T.footprint_directions)
"""A `Footprint` of points within a disc of radius R lies inside the regular polygon
circumscribed about that disc (each extent is at most the disc's): area <= this x R²."""


def volume_upper_bounds(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """float64 [m] m³: bounds on `Body.volume_m3` of the things within each box (lo, hi float
    [m, 3] in the up frame): the polygon about the disc holding the box seen from above, times
    the box's height."""
    size = np.asarray(hi, np.float64) - np.asarray(lo, np.float64)
    radius_squared = 0.25 * (size[:, 0] ** 2 + size[:, 1] ** 2)
    return _FOOTPRINT_IN_DISC * radius_squared * np.maximum(size[:, 2], 0.0) * (1 + 1e-9) + 1e-12


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
