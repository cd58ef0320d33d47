"""Sightings: a non-keyframe's detections counted towards confirming candidate objects.

A device with the sightings extension sends detections with frames it does not pick as
keyframes (docs/protocol.md); nothing is lifted from them and no geometry changes, but a
candidate seen on enough of the frames it was in view is confirmed by the next keyframe.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from app.mapping import geometry as geo
from app.mapping.object import MapObject
from app.protocol import FrameInput

SIGHTING_MIN_POINTS = 5
"""A candidate object is sighted on a non-keyframe only if at least this many of its points
are visible there (in the image, in front of the camera, not hidden behind nearer depth)..."""
SIGHTING_COVER = 0.5
"""...and at least this fraction of those fall in one detection carrying one of its labels."""
SIGHTING_AGREEMENT = 0.5
"""A candidate is confirmed by sightings only if it was seen on at least this fraction of
the frames it was in view: a detection with a confused label (the detector calls a window a
door one frame in twenty) builds a candidate that its frames rarely agree with."""
SIGHTING_SAMPLE_POINTS = 200
"""Points of each object projected into a non-keyframe (a regular subsample)."""
SIGHTING_DEPTH_TOLERANCE_M = 0.1
"""A projected point is visible when its depth is within this (plus 5 %) of the sensed depth."""


@dataclass
class _Glimpses:
    """What the frames said about one candidate object (frame seqs)."""

    seen: set[int] = field(default_factory=set)
    """Keyframes where it was observed and non-keyframes where it was sighted."""
    missed: set[int] = field(default_factory=set)
    """Non-keyframes where it was in view but no detection of its own sighted it."""

    def update(self, other: _Glimpses) -> None:
        self.seen |= other.seen
        self.missed |= other.missed - self.seen


class _SightSamples(NamedTuple):
    """What sightings project between two keyframes."""

    keyframe: int
    """The engine's keyframe count they were drawn at."""
    objects: list[MapObject]
    """The objects with points."""
    points: np.ndarray
    """float32 [N, 3]: about SIGHTING_SAMPLE_POINTS of each object's points, concatenated."""
    owner: np.ndarray
    """int [N]: the index in `objects` of each point."""
    sizes: np.ndarray
    """int64 [len(objects)]: each sample's size."""


def _project(
    points: np.ndarray, frame: FrameInput
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """World points float32 [N, 3] into the frame's RGB image: (u, v) int pixel, z metres
    (in front of the camera, inside the image) and the bool [N] mask of those points."""
    u, v, z = geo.project_to_pixels(points, frame.pose, frame.intrinsics)
    width, height = frame.rgb_size
    kept = (z > 1e-3) & (u >= 0) & (u < width) & (v >= 0) & (v < height)
    return u[kept].astype(np.int64), v[kept].astype(np.int64), z[kept], kept
