"""An object's points as the device's local map holds them.

The server sends each confirmed object's client-capped points (`max_object_points_client`)
as float16 on the wire; the device's local map stores them as uint8 offsets in the object's
own point box (3 bytes a point). Both ends import this module: the device to store and read
its points, the server to measure relations on exactly the points a device holds
(`held_points`), so a relation's degree is the same on both ends (LQ = SQ:
docs/evaluation.md "Relations").
"""

from __future__ import annotations

import numpy as np

POINT_LEVELS = 255
"""Points are stored as uint8 offsets: 255 steps per axis across the object's point box."""


def quantise_points(points: np.ndarray) -> tuple[bytes, np.ndarray, np.ndarray]:
    """(uint8 [N, 3] as bytes, lo float32 [3], step float32 [3]) of float [N, 3] points.

    Offsets are rounded in POINT_LEVELS steps of the points' own box, so
    `lo + offset * step` is within step / 2 of each point per axis (step 0 on a flat axis).
    """
    as32 = np.asarray(points, np.float32).reshape(-1, 3)
    if len(as32) == 0:
        return b"", np.zeros(3, np.float32), np.zeros(3, np.float32)
    lo, hi = as32.min(axis=0), as32.max(axis=0)
    step = ((hi - lo) / POINT_LEVELS).astype(np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):
        offsets = np.where(step > 0, (as32 - lo) / step, 0.0)
    quantised = np.clip(np.rint(offsets), 0, POINT_LEVELS).astype(np.uint8)
    return quantised.tobytes(), lo, step


def dequantise_points(data: bytes, lo: np.ndarray, step: np.ndarray) -> np.ndarray:
    """float32 [N, 3] metres of `quantise_points` output."""
    offsets = np.frombuffer(data, np.uint8).reshape(-1, 3)
    return (offsets.astype(np.float32) * step + lo).astype(np.float32)


def held_points(points: np.ndarray) -> np.ndarray:
    """float32 [N, 3] metres: exactly the points a device's local map holds for these
    client points (float [N, 3], already capped: the device takes no further subset at the
    same cap): rounded to float16 as the wire does, then stored as uint8 in their box."""
    wire = np.asarray(points, np.float64).astype(np.float16)  # as app.codecs packs them
    return dequantise_points(*quantise_points(wire))
