"""Smooth ramps every degree is made of: 0 below a limit, 1 above another, C1 between."""

from __future__ import annotations

import numpy as np


def rise(x: float, lo: float, hi: float) -> float:
    """Smoothstep: 0 at or below `lo`, 1 at or above `hi`, C1 in between."""
    t = min(max((float(x) - lo) / (hi - lo), 0.0), 1.0)
    return t * t * (3.0 - 2.0 * t)


def fall(x: float, lo: float, hi: float) -> float:
    """1 at or below `lo`, 0 at or above `hi` (1 - `rise`)."""
    return 1.0 - rise(x, lo, hi)


def rise_many(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """`rise` of each element of `x`."""
    t = np.clip((np.asarray(x, np.float64) - lo) / (hi - lo), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def fall_many(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
    return 1.0 - rise_many(x, lo, hi)
