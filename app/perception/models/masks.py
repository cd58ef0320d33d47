"""Pure-numpy geometry of the CPU profile: boxes -> depth-mode masks -> an instance image,
and per-object crops with context for the embedder. No model, no I/O."""

from __future__ import annotations

import numpy as np

DEPTH_BIN_M = 0.05
"""Histogram bin of the depth-mode mask."""
DEPTH_BAND_FRACTION = 0.1
"""A box pixel belongs to the object when its depth is within this fraction of the mode..."""
DEPTH_BAND_MIN_M = 0.1
"""...or within this many metres of it, whichever is wider (thin objects, near range)."""
CROP_CONTEXT = 0.15
"""A crop keeps this fraction of the box's size around it on every side (CLIP sees context)."""


def upsample_depth(depth_m: np.ndarray, rgb_size: tuple[int, int]) -> np.ndarray:
    """float32 [h, w] depth at the uploaded ratio -> float32 [H, W] at RGB size (nearest)."""
    width, height = rgb_size
    h, w = depth_m.shape
    rows = np.minimum(np.arange(height) * h // height, h - 1)
    cols = np.minimum(np.arange(width) * w // width, w - 1)
    return depth_m[rows[:, None], cols[None, :]]


def nms(boxes_px: np.ndarray, scores: np.ndarray, iou_max: float) -> np.ndarray:
    """Greedy non-maximum suppression. boxes_px: float [n, 4] (x0, y0, x1, y1); returns the
    kept indices, best score first."""
    order = np.argsort(-scores, kind="stable")
    x0, y0, x1, y1 = boxes_px.T
    area = np.maximum(x1 - x0, 0) * np.maximum(y1 - y0, 0)
    keep: list[int] = []
    while order.size:
        i, rest = order[0], order[1:]
        keep.append(int(i))
        iw = np.clip(np.minimum(x1[i], x1[rest]) - np.maximum(x0[i], x0[rest]), 0, None)
        ih = np.clip(np.minimum(y1[i], y1[rest]) - np.maximum(y0[i], y0[rest]), 0, None)
        inter = iw * ih
        iou = inter / np.maximum(area[i] + area[rest] - inter, 1e-9)
        order = rest[iou <= iou_max]
    return np.asarray(keep, np.int64)


def box_to_pixels(box_px: np.ndarray, rgb_size: tuple[int, int]) -> tuple[int, int, int, int]:
    """A float box -> integer half-open pixel box clipped to the image (may be empty)."""
    width, height = rgb_size
    x0, y0, x1, y1 = box_px
    return (
        int(np.clip(np.floor(x0), 0, width)),
        int(np.clip(np.floor(y0), 0, height)),
        int(np.clip(np.ceil(x1), 0, width)),
        int(np.clip(np.ceil(y1), 0, height)),
    )


def depth_mode_mask(depth_box_m: np.ndarray) -> np.ndarray:
    """bool [h, w]: the pixels of a box whose depth lies in the box's dominant depth mode
    (the fullest histogram bin, widened to a band); all False without valid depth."""
    valid = np.isfinite(depth_box_m) & (depth_box_m > 0)
    if not valid.any():
        return valid
    values = depth_box_m[valid]
    bins = np.floor(values / DEPTH_BIN_M).astype(np.int64)
    low = bins.min()
    mode_bin = int(np.bincount(bins - low).argmax()) + low
    mode_m = (mode_bin + 0.5) * DEPTH_BIN_M
    band_m = max(DEPTH_BAND_MIN_M, DEPTH_BAND_FRACTION * mode_m)
    return valid & (np.abs(depth_box_m - mode_m) <= band_m)


def instance_image_from_boxes(
    depth_full_m: np.ndarray, boxes_px: list[tuple[int, int, int, int]]
) -> tuple[np.ndarray, list[tuple[int, int, int, int] | None]]:
    """Depth-mode masks of boxes given best first, as one instance image.

    depth_full_m: float32 [H, W] at RGB size. A pixel goes to the best box whose mask has it.
    Returns uint16 [H, W] (box i has id i + 1, 0 = none) and each box's mask bbox (x0, y0,
    x1, y1), half-open, or None when its mask came out empty.
    """
    instance = np.zeros(depth_full_m.shape, np.uint16)
    bboxes: list[tuple[int, int, int, int] | None] = []
    for i, (x0, y0, x1, y1) in enumerate(boxes_px):
        if x1 <= x0 or y1 <= y0:
            bboxes.append(None)
            continue
        mask = depth_mode_mask(depth_full_m[y0:y1, x0:x1])
        mask &= instance[y0:y1, x0:x1] == 0  # better boxes keep their pixels
        if not mask.any():
            bboxes.append(None)
            continue
        instance[y0:y1, x0:x1][mask] = i + 1
        rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
        bboxes.append(
            (x0 + int(cols[0]), y0 + int(rows[0]), x0 + int(cols[-1]) + 1, y0 + int(rows[-1]) + 1)
        )
    return instance, bboxes


def crop_with_context(rgb: np.ndarray, bbox_px: tuple[int, int, int, int]) -> np.ndarray:
    """uint8 [s, s, 3]: a square crop centred on the mask's bbox with CROP_CONTEXT around
    it, padded with grey where it leaves the image (the embedder sees the whole object)."""
    height, width = rgb.shape[:2]
    x0, y0, x1, y1 = bbox_px
    side = max(x1 - x0, y1 - y0)
    side = max(2, int(round(side * (1 + 2 * CROP_CONTEXT))))
    cx, cy = (x0 + x1) // 2, (y0 + y1) // 2
    left, top = cx - side // 2, cy - side // 2
    crop = np.full((side, side, 3), 128, np.uint8)
    sx0, sy0 = max(left, 0), max(top, 0)
    sx1, sy1 = min(left + side, width), min(top + side, height)
    crop[sy0 - top : sy1 - top, sx0 - left : sx1 - left] = rgb[sy0:sy1, sx0:sx1]
    return crop
