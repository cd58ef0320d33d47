"""A validated v1 `delta` as the local map's columns: what each upsert becomes on the device
before anything is applied (embeddings to 8 bits, points capped and to uint8 offsets in their
box, centroids of the received and of the held points).

The point cap keeps a subset seeded by (id, version, cap), so every device that receives the
same update holds the same points (app.mapping.held quantises them, client_sim.local_scan the
embeddings).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import numpy as np

from app.mapping.held import dequantise_points, quantise_points
from app.protocol import DeltaMessage
from client_sim.local_scan import quantise_embeddings


@dataclass
class ParsedDelta:
    """A delta that passed validation, as columns of m upserts (nothing applied yet)."""

    seq: int
    full: bool
    ids: np.ndarray  # int64 [m]
    versions: np.ndarray  # int64 [m]
    labels: list[str]  # [m]
    embeddings: np.ndarray  # int8 [m, dim]
    scales: np.ndarray  # float32 [m]: embeddings * scales are unit rows (or zero)
    points: list[bytes]  # uint8 [<= max_points, 3] each, offsets in their point box
    points_lo: np.ndarray  # float32 [m, 3], the point box's low corner
    points_step: np.ndarray  # float32 [m, 3], metres per uint8 step
    bboxes: np.ndarray  # float32 [m, 6]
    centroids: np.ndarray  # float32 [m, 3], mean of the received points
    held_centroids: np.ndarray  # float32 [m, 3], mean of the held (stored) points
    n_obs: np.ndarray  # int64 [m]
    last_seen_t: np.ndarray  # float64 [m], device-clock seconds, NaN where not sent
    removed: list[int]
    label_texts: dict[str, tuple[str, ...]]  # the labels' texts the server sent, by label


def cap_points(points: np.ndarray, max_points: int, oid: int, version: int) -> np.ndarray:
    """At most `max_points` rows of float16 [N, 3], as a new array owning its memory.

    The subset is random but seeded by (id, version, cap), so every device that receives the
    same update holds the same points; row order is kept.
    """
    if len(points) <= max_points:
        return points.copy()  # decoded arrays are views; a copy drops the extra header
    rng = np.random.default_rng((oid, version, max_points))
    keep = np.sort(rng.choice(len(points), size=max_points, replace=False))
    return points[keep]


def held_centroid(
    data: bytes, lo: np.ndarray, step: np.ndarray, fallback: np.ndarray
) -> np.ndarray:
    """float64 [3]: the mean of an object's held points (what its relation body's centroid
    is), `fallback` when it has none."""
    if not data:
        return np.asarray(fallback, np.float64)
    return dequantise_points(data, lo, step).mean(axis=0, dtype=np.float64)


def read_upserts(delta: DeltaMessage, dim: int, max_points: int) -> ParsedDelta:
    """The upserts of a delta `parse_delta` validated, as columns (no side effects)."""
    m = len(delta.upserts)
    ids = np.empty(m, np.int64)
    versions = np.empty(m, np.int64)
    n_obs = np.empty(m, np.int64)
    last_seen_t = np.full(m, np.nan, np.float64)
    labels: list[str] = []
    label_texts: dict[str, tuple[str, ...]] = {}
    embeddings = np.empty((m, dim), np.float16)
    bboxes = np.empty((m, 6), np.float32)
    centroids = np.empty((m, 3), np.float32)
    held_centroids = np.empty((m, 3), np.float32)
    points_list: list[bytes] = []
    points_lo = np.empty((m, 3), np.float32)
    points_step = np.empty((m, 3), np.float32)
    for i, upsert in enumerate(delta.upserts):
        ids[i], versions[i], n_obs[i] = upsert.id, upsert.version, upsert.n_obs
        if upsert.last_seen_t is not None:  # an older server sends none: NaN stays
            last_seen_t[i] = upsert.last_seen_t
        labels.append(sys.intern(upsert.label))  # thousands of objects share a few labels
        if upsert.label_texts is not None:  # an older server sends none: the label alone
            label_texts[labels[-1]] = upsert.label_texts
        bboxes[i] = upsert.bbox
        embeddings[i] = upsert.embedding
        points = upsert.points
        if len(points):
            centroids[i] = points.astype(np.float32).mean(axis=0)
        else:
            centroids[i] = (bboxes[i, :3] + bboxes[i, 3:]) / 2
        capped = cap_points(points, max_points, upsert.id, upsert.version)
        data, points_lo[i], points_step[i] = quantise_points(capped)
        held_centroids[i] = held_centroid(data, points_lo[i], points_step[i], centroids[i])
        points_list.append(data)
    quantised, scales = quantise_embeddings(embeddings)
    return ParsedDelta(
        seq=delta.seq,
        full=delta.full,
        ids=ids,
        versions=versions,
        labels=labels,
        embeddings=quantised,
        scales=scales,
        points=points_list,
        points_lo=points_lo,
        points_step=points_step,
        bboxes=bboxes,
        centroids=centroids,
        held_centroids=held_centroids,
        n_obs=n_obs,
        last_seen_t=last_seen_t,
        removed=delta.removed,
        label_texts=label_texts,
    )
