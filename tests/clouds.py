"""Point clouds for mapping tests: simple shapes drawn from a test's own generator."""

from __future__ import annotations

import numpy as np


def disc(rng: np.random.Generator, centre, radius_m: float, n: int) -> np.ndarray:
    """n points spread evenly over a horizontal disc of radius_m around centre (x, y, z)."""
    r = radius_m * np.sqrt(rng.random(n))
    a = rng.random(n) * 2 * np.pi
    return np.stack(
        [centre[0] + r * np.cos(a), centre[1] + r * np.sin(a), np.full(n, centre[2])], 1
    )
