"""The two system organisations of the mapping engine (docs/architecture.md).

Both call the same geometry, similarity, denoising and merge functions, so they differ in
how the work is organised and scheduled and how much geometry is kept, never in how a
detection and an object are compared or fused.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.perception.base import Detection
from app.protocol import DepthPatch

BASELINE_RESOLUTION_M = 0.01
"""The baseline keeps geometry at sensor resolution: de-duplicated only at 1 cm, finer than
a depth pixel at mapping range, so repeated views do not stack identical points."""


def _patch_covering(
    patches: list[DepthPatch], box_px: tuple[int, int, int, int]
) -> DepthPatch | None:
    """The first depth patch whose box holds all of `box_px` (x0, y0, x1, y1), or None."""
    x0, y0, x1, y1 = box_px
    for patch in patches:
        px0, py0, px1, py1 = patch.box_px
        if px0 <= x0 and py0 <= y0 and x1 <= px1 and y1 <= py1:
            return patch
    return None


@dataclass
class _Observation:
    """A lifted detection, ready to associate. points: float32 [N, 3] (de-duplicated)."""

    detection: Detection
    points: np.ndarray
    embedding: np.ndarray
    bbox: np.ndarray
