"""Pure geometry of the map: lifting, de-duplication, caps, boxes, overlap.

Conventions: camera frame is OpenCV (x right, y down, z forward), pixel centres at integer
coordinates; poses are camera-to-world; points are float32 [N, 3] in metres.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

EMPTY_POINTS = np.zeros((0, 3), np.float32)
PATCH_EROSION_PX = 2
"""Mask boundary (px) not lifted from a full-resolution depth patch..."""
PATCH_MIN_INNER_PX = 30
"""...unless fewer pixels than this would remain (then the whole mask is lifted)."""
DEPTH_EDGE_MIN_M = 0.02
"""A mask-edge depth sample is lifted only if its depth continues its mask's surface within
this much..."""
DEPTH_EDGE_PER_M = 0.02
"""...plus this much per metre of its depth (sensor noise grows with range)."""
_NEIGHBOURS = ((-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (-1, 1), (1, -1), (1, 1))
"""(dv, du) of a depth pixel's 8 neighbours, the 4 sharing a side first."""


def depth_to_rgb_pixel_grid(
    depth_size: tuple[int, int], rgb_size: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """RGB pixel coordinates of the depth pixels' centres.

    A depth image downsampled by r per dimension holds, at (u_d, v_d), the RGB pixel
    (floor((u_d + 0.5) * W / w), floor((v_d + 0.5) * H / h)) — for integer r that is
    (u_d * r + r // 2, v_d * r + r // 2), the centre of its r x r block.
    Returns (u_rgb int [w], v_rgb int [h]).
    """
    (w, h), (width, height) = depth_size, rgb_size
    u_rgb = np.floor((np.arange(w) + 0.5) * (width / w)).astype(np.intp)
    v_rgb = np.floor((np.arange(h) + 0.5) * (height / h)).astype(np.intp)
    return np.minimum(u_rgb, width - 1), np.minimum(v_rgb, height - 1)


def backproject(
    u_rgb: np.ndarray,
    v_rgb: np.ndarray,
    z_m: np.ndarray,
    intrinsics: tuple[float, float, float, float],
    pose: np.ndarray,
) -> np.ndarray:
    """World points [N, 3] float32 of pixels (u, v) [N] at z-depth z_m [N] (RGB intrinsics)."""
    fx, fy, cx, cy = intrinsics
    cam = np.empty((len(z_m), 3), np.float64)
    cam[:, 0] = (u_rgb - cx) / fx * z_m
    cam[:, 1] = (v_rgb - cy) / fy * z_m
    cam[:, 2] = z_m
    return (cam @ pose[:3, :3].T + pose[:3, 3]).astype(np.float32)


def valid_depth_mask(depth_m: np.ndarray, max_depth_m: float) -> np.ndarray:
    """bool [h, w]: finite, positive and within range."""
    with np.errstate(invalid="ignore"):
        return np.isfinite(depth_m) & (depth_m > 0) & (depth_m <= max_depth_m)


def _shifted(image: np.ndarray, dv: int, du: int, fill) -> np.ndarray:
    """image[v + dv, u + du] at every (v, u), `fill` where that falls outside."""
    h, w = image.shape
    out = np.full_like(image, fill)
    out[max(0, -dv) : h - max(0, dv), max(0, -du) : w - max(0, du)] = image[
        max(0, dv) : h - max(0, -dv) or None, max(0, du) : w - max(0, -du) or None
    ]
    return out


def depth_edge_keep(ids_d: np.ndarray, depth_m: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """bool [h, w]: the mask samples worth lifting, at depth resolution.

    ids_d: int [h, w] the mask (instance id, 0 = none) sampled at the depth pixels;
    depth_m: float [h, w]; valid: bool [h, w] usable depth. A detector's mask bleeds a pixel
    or two onto what lies behind, below or in front of the thing, and a depth sensor mixes
    the two sides of an edge: so a sample on its mask's edge (a side neighbour outside the
    mask) is dropped when its depth does not continue the mask's surface: no interior
    neighbour (all of whose side neighbours are in the mask) agrees with it, as it is or
    extrapolated one pixel further (a slanted surface), within DEPTH_EDGE_MIN_M +
    DEPTH_EDGE_PER_M * depth. A mask with no interior next to a sample (a pole or a leg one
    or two depth pixels wide) keeps it unless it lies that much behind a neighbouring sample
    of its mask (the rim on the wall behind the pole): erosion would delete such parts
    whole."""
    ids_d = np.where(valid, ids_d, 0).astype(np.int64)
    z = np.where(valid, depth_m, 0.0).astype(np.float64)
    inside = ids_d > 0
    same = [(_shifted(ids_d, dv, du, -1) == ids_d) & inside for dv, du in _NEIGHBOURS]
    beyond = [_shifted(ids_d, dv, du, -1) == -1 for dv, du in _NEIGHBOURS[:4]]
    # the image's border is not the mask's edge: the thing goes on out of view
    edge = inside & ~np.logical_and.reduce([s | b for s, b in zip(same[:4], beyond, strict=True)])
    interior = inside & ~edge
    residual = np.full(z.shape, np.inf)
    judged = np.zeros(z.shape, bool)
    for (dv, du), same_d in zip(_NEIGHBOURS, same, strict=True):
        beside = same_d & _shifted(interior, dv, du, False)
        z1 = _shifted(z, dv, du, 0.0)
        z2 = _shifted(z, 2 * dv, 2 * du, 0.0)
        further = beside & (_shifted(ids_d, 2 * dv, 2 * du, -1) == ids_d)
        r = np.minimum(np.abs(z - z1), np.where(further, np.abs(z - (2 * z1 - z2)), np.inf))
        residual = np.where(beside, np.minimum(residual, r), residual)
        judged |= beside
    tolerance = DEPTH_EDGE_MIN_M + DEPTH_EDGE_PER_M * z
    # Where no interior judges (a thin mask), a sample behind a neighbour of its own mask
    # by more than the tolerance is the rim on what lies behind the thin thing.
    behind = np.zeros(z.shape, bool)
    for (dv, du), same_d in zip(_NEIGHBOURS, same, strict=True):
        behind |= same_d & (z - _shifted(z, dv, du, 0.0) > tolerance)
    return inside & ~(edge & np.where(judged, residual > tolerance, behind))


SMOOTH_FROM_M = 2.5
"""Depth is smoothed (`smooth_depth`) from this range on: nearer, a depth sensor's range
noise (about a centimetre at 2.5 m on a structured-light sensor, docs/evaluation.md
"Geometry") is under half the map's voxel, and the views a voxel fuses average it out;
farther it grows with the square of the range into a skin thicker than the thing."""
SMOOTH_RIDGE = 1e-3
"""A slope no neighbour pins down (a pole one sample wide, a lone sample) is taken as flat."""
_WINDOW = ((0, 0), *_NEIGHBOURS)
"""(dv, du) of a sample and its 8 neighbours: the window of the plane fit."""


def _plane_centre_rows() -> np.ndarray:
    """float [512, 9]: for each set of a window's samples in the fit (bit k: _WINDOW[k]),
    the weights that give the least-squares plane's depth at the centre (the first row of
    the fit's inverse normal matrix times the design), zero for samples not in the fit."""
    design = np.array([[1.0, du, dv] for dv, du in _WINDOW])
    rows = np.zeros((512, 9))
    for pattern in range(512):
        used = np.array([(pattern >> k) & 1 for k in range(9)], float)
        normal = design.T @ (used[:, None] * design) + np.diag([0.0, SMOOTH_RIDGE, SMOOTH_RIDGE])
        if used.any():
            rows[pattern] = np.linalg.solve(normal, design.T * used)[0]
    return rows


_PLANE_CENTRE = _plane_centre_rows()


def smooth_depth(ids_d: np.ndarray, depth_m: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """float [h, w]: each kept sample's depth replaced by the plane fitted (least squares,
    depth over pixel offsets) to it and its kept 3x3 neighbours of the same mask whose depth
    continues its surface (within DEPTH_EDGE_MIN_M + DEPTH_EDGE_PER_M * depth), read at the
    sample, for the samples at SMOOTH_FROM_M or farther; every other pixel as it was.

    ids_d: int [h, w] the mask (instance id, 0 = none); keep: bool [h, w] the samples lifted
    (`depth_edge_keep`). A depth sensor's range noise is per pixel and grows with the square
    of the range (docs/architecture.md): a far view's samples scatter a surface into a skin
    several centimetres thick, and its outermost samples set the box. Inside a mask the
    plane's value is the mean of the 9 samples, about a third of the scatter; on the mask's
    edge, where the neighbours lie on one side, the plane (unlike their mean) keeps a slanted
    surface where it is. A neighbour across a depth step (another thing, the wall behind) is
    not in the fit. The fit's weights depend only on which samples are in it: one table
    of 512 rows (`_PLANE_CENTRE`)."""
    rows = np.nonzero(keep & (depth_m >= SMOOTH_FROM_M))
    if len(rows[0]) == 0:
        return depth_m
    ids = np.where(keep, ids_d, 0).astype(np.int64)
    z = np.where(keep, depth_m, 0.0).astype(np.float64)
    tolerance = (DEPTH_EDGE_MIN_M + DEPTH_EDGE_PER_M * z)[rows]
    centre = z[rows]
    pattern = np.zeros(len(centre), np.int64)
    window = np.zeros((len(centre), 9))
    for k, (dv, du) in enumerate(_WINDOW):
        zn = _shifted(z, dv, du, 0.0)[rows]
        same = (_shifted(ids, dv, du, 0)[rows] == ids[rows]) & (np.abs(zn - centre) <= tolerance)
        pattern |= same.astype(np.int64) << k
        window[:, k] = zn
    out = np.array(depth_m, dtype=np.float64, copy=True)
    out[rows] = np.einsum("nk,nk->n", _PLANE_CENTRE[pattern], window)
    return out.astype(depth_m.dtype, copy=False)


def lift_detection(
    mask_rgb: np.ndarray,
    depth_m: np.ndarray,
    intrinsics: tuple[float, float, float, float],
    pose: np.ndarray,
    max_depth_m: float,
    edge_test: bool = True,
) -> np.ndarray:
    """World points [N, 3] of one detection: its RGB-resolution mask sampled at the depth
    pixels, less the edge samples whose depth leaves the mask's surface (`depth_edge_keep`;
    every sample with `edge_test` False).

    mask_rgb: bool [H, W]; depth_m: float32 [h, w] (downsampled or not).
    """
    height, width = mask_rgb.shape
    u_rgb, v_rgb = depth_to_rgb_pixel_grid((depth_m.shape[1], depth_m.shape[0]), (width, height))
    valid = valid_depth_mask(depth_m, max_depth_m)
    mask_d = mask_rgb[np.ix_(v_rgb, u_rgb)] & valid
    if edge_test:
        mask_d = depth_edge_keep(mask_d, depth_m, valid)
    depth_m = smooth_depth(mask_d, depth_m, mask_d)
    vd, ud = np.nonzero(mask_d)
    return backproject(u_rgb[ud], v_rgb[vd], depth_m[vd, ud], intrinsics, pose)


def lift_instances_batched(
    instance_image: np.ndarray,
    instance_ids: list[int],
    depth_m: np.ndarray,
    intrinsics: tuple[float, float, float, float],
    pose: np.ndarray,
    max_depth_m: float,
) -> dict[int, np.ndarray]:
    """World points of many detections at once: one pass over the depth image.

    instance_image: uint16 [H, W] at RGB size. Returns {instance_id: float32 [N, 3]}; the same
    points `lift_detection` gives for each id's mask, computed without per-object image passes.
    """
    height, width = instance_image.shape
    u_rgb, v_rgb = depth_to_rgb_pixel_grid((depth_m.shape[1], depth_m.shape[0]), (width, height))
    ids_d = instance_image[np.ix_(v_rgb, u_rgb)]
    keep = depth_edge_keep(ids_d, depth_m, valid_depth_mask(depth_m, max_depth_m))
    depth_m = smooth_depth(ids_d, depth_m, keep)
    vd, ud = np.nonzero(keep)
    ids = ids_d[vd, ud]
    points = backproject(u_rgb[ud], v_rgb[vd], depth_m[vd, ud], intrinsics, pose)
    order = np.argsort(ids, kind="stable")
    ids, points = ids[order], points[order]
    bounds = np.searchsorted(ids, np.asarray(instance_ids, ids.dtype))
    ends = np.searchsorted(ids, np.asarray(instance_ids, ids.dtype), side="right")
    return {iid: points[b:e] for iid, b, e in zip(instance_ids, bounds, ends, strict=True)}


def lift_in_patch(
    instance_image: np.ndarray,
    instance_id: int,
    box_px: tuple[int, int, int, int],
    patch_depth_m: np.ndarray,
    intrinsics: tuple[float, float, float, float],
    pose: np.ndarray,
    max_depth_m: float,
) -> np.ndarray:
    """World points [N, 3] of one detection from a full-resolution depth patch of its box.

    instance_image: uint16 [H, W] at RGB size; box_px (x0, y0, x1, y1) half-open, the patch's
    box; patch_depth_m: float32 [y1 - y0, x1 - x0]. Every mask pixel inside the box with
    valid depth becomes a point (the depth co-design for small detections).
    """
    x0, y0, x1, y1 = box_px
    mask = instance_image[y0:y1, x0:x1] == instance_id
    # A detector's mask boundary is where it bleeds onto what lies behind or under the
    # object; at full resolution there are pixels to spare, so the boundary is not lifted.
    inner = ndimage.binary_erosion(mask, iterations=PATCH_EROSION_PX)
    if inner.sum() >= PATCH_MIN_INNER_PX:
        mask = inner
    mask = mask & valid_depth_mask(patch_depth_m, max_depth_m)
    patch_depth_m = smooth_depth(mask, patch_depth_m, mask)
    v, u = np.nonzero(mask)
    return backproject(u + x0, v + y0, patch_depth_m[v, u], intrinsics, pose)


def _voxel_keys(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """int64 [N] key of each point's voxel, ordered like the voxels' (x, y, z) indices.

    21 bits per axis, counted from the points' own lowest voxel, so any cloud spanning up
    to 2^21 voxels per axis (52 km at 2.5 cm) packs exactly; a wider one is ranked per axis
    first (slower, same order)."""
    idx = np.floor(points / voxel_m).astype(np.int64)
    if len(idx) == 0:
        return np.zeros(0, np.int64)
    idx -= idx.min(axis=0)
    if idx.max() >= 1 << 21:
        idx = np.stack([np.unique(a, return_inverse=True)[1].ravel() for a in idx.T], axis=1)
    return (idx[:, 0] << 42) | (idx[:, 1] << 21) | idx[:, 2]


def voxel_downsample(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """One point per occupied voxel (the mean of its points), float32 [M, 3], M <= N, in
    voxel-key order; the input itself when no two points share a voxel."""
    if len(points) == 0:
        return EMPTY_POINTS
    keys = _voxel_keys(points, voxel_m)
    order = np.argsort(keys)
    first = _run_starts(keys[order])
    if first.all():
        return points.astype(np.float32, copy=False)
    starts = np.flatnonzero(first)
    counts = np.diff(np.append(starts, len(points)))
    sums = np.add.reduceat(points[order].astype(np.float64), starts, axis=0)
    return (sums / counts[:, None]).astype(np.float32)


def _run_starts(sorted_keys: np.ndarray) -> np.ndarray:
    """bool [N]: where a run of equal keys starts in a sorted key array."""
    first = np.ones(len(sorted_keys), bool)
    first[1:] = sorted_keys[1:] != sorted_keys[:-1]
    return first


def voxel_count(points: np.ndarray, voxel_m: float) -> int:
    """How many voxels the points occupy: len(voxel_sample(points, voxel_m)), at a sixth of
    its cost (a sort of the keys, no per-voxel choice)."""
    if len(points) == 0:
        return 0
    return int(np.count_nonzero(_run_starts(np.sort(_voxel_keys(points, voxel_m)))))


def voxel_merge(
    points: np.ndarray, support: np.ndarray, voxel_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """One point per occupied voxel, the support-weighted mean of its points, and the sum
    of their support: float32 [M, 3] and float32 [M], M <= N, in voxel-key order.

    support: float [N] how many views each point stands for (an observation's points 1
    each). A voxel's running mean over views cuts a surface's range noise by about the
    square root of the views that saw it, and its support says how many did."""
    if len(points) == 0:
        return EMPTY_POINTS, np.zeros(0, np.float32)
    keys = _voxel_keys(points, voxel_m)
    order = np.argsort(keys)
    starts = np.flatnonzero(_run_starts(keys[order]))
    weight = support[order].astype(np.float64)
    sums = np.add.reduceat(points[order].astype(np.float64) * weight[:, None], starts, axis=0)
    total = np.add.reduceat(weight, starts)
    return (sums / total[:, None]).astype(np.float32), total.astype(np.float32)


def _voxel_pick(points: np.ndarray, voxel_m: float, support: np.ndarray | None) -> np.ndarray:
    """Index [M] of one point per occupied voxel, in voxel-key order: the best supported
    (when `support`), then the one nearest the voxel's centre."""
    keys = _voxel_keys(points, voxel_m)
    offset = points / voxel_m - np.floor(points / voxel_m) - 0.5
    order = np.argsort(keys)
    first = _run_starts(keys[order])
    dist = np.einsum("ij,ij->i", offset, offset)[order]
    if support is not None:  # the most views first (a view counts 1, a distance under 0.75)
        dist = dist - support[order]
    run = np.cumsum(first) - 1
    nearest = np.flatnonzero(dist == np.minimum.reduceat(dist, np.flatnonzero(first))[run])
    nearest = nearest[_run_starts(run[nearest])]  # one per voxel where distances tie
    return order[nearest]


def voxel_sample(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """One real point per occupied voxel: the one nearest the voxel's centre, float32 [M, 3],
    in voxel-key order.

    Unlike the mean, a sample stays on the surface where a coarse voxel straddles an edge;
    nearest-to-centre keeps every surface point within about half a voxel of a sample.
    One quicksort of the keys, then the minimum distance per run of equal keys (about half
    the cost of a two-key lexsort by key and distance).
    """
    if len(points) == 0:
        return EMPTY_POINTS
    return points[_voxel_pick(points, voxel_m, None)].astype(np.float32, copy=False)


def voxel_sample_supported(
    points: np.ndarray, support: np.ndarray, voxel_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """`voxel_sample` that keeps per voxel its best supported point (ties: nearest the
    centre) and gives it the voxel's whole support: float32 [M, 3], float32 [M]."""
    if len(points) == 0:
        return EMPTY_POINTS, np.zeros(0, np.float32)
    picked = _voxel_pick(points, voxel_m, support)
    keys = _voxel_keys(points, voxel_m)
    _, voxel_of = np.unique(keys, return_inverse=True)
    total = np.bincount(voxel_of.ravel(), weights=support.astype(np.float64))
    return (
        points[picked].astype(np.float32, copy=False),
        total[voxel_of.ravel()[picked]].astype(np.float32),
    )


def cap_points(
    points: np.ndarray,
    max_points: int,
    voxel_m: float,
    start_m: float | None = None,
    max_spacing_m: float | None = None,
) -> tuple[np.ndarray, float]:
    """At most `max_points` points that still cover the whole object, and their spacing.

    Voxel de-duplication at `voxel_m` first; if that is still over the cap, one real point
    per voxel of the finest coarser voxel that fits (uniform coverage beats random
    dropping). The search starts at `start_m` when given (an object's current spacing: a
    merge into a capped object keeps at least that spacing, so the cap costs one or two
    samplings instead of a search), else at the estimate for a surface (n ~ 1 / voxel^2),
    and grows by that estimate until the voxel count fits; then samples once. Deterministic.
    max_spacing_m: the spacing never grows past this, even if more than `max_points` remain
    (a cap by surface density for large objects).
    Returns (float32 [M, 3], M <= max_points unless max_spacing_m stops the search, the voxel
    in metres).
    """
    capped, spacing, _ = cap_points_supported(
        points, None, max_points, voxel_m, start_m, max_spacing_m
    )
    return capped, spacing


def cap_points_supported(
    points: np.ndarray,
    support: np.ndarray | None,
    max_points: int,
    voxel_m: float,
    start_m: float | None = None,
    max_spacing_m: float | None = None,
) -> tuple[np.ndarray, float, np.ndarray | None]:
    """`cap_points` that carries each point's support (float [N], views it stands for;
    None: unknown, as `cap_points`): voxels at `voxel_m` merge as `voxel_merge`, a coarser
    voxel keeps its best supported point with the voxel's whole support.
    Returns (points float32 [M, 3], spacing in metres, support float32 [M] or None)."""
    if support is None:
        points = voxel_downsample(points, voxel_m)
    else:
        points, support = voxel_merge(points, support, voxel_m)
    if len(points) <= max_points:
        return points, voxel_m, support
    if start_m is None:
        spacing = voxel_m * np.sqrt(len(points) / max_points)
    else:
        spacing = max(voxel_m, start_m)
    ceiling_m = np.inf if max_spacing_m is None else max(voxel_m, max_spacing_m)
    spacing = min(spacing, ceiling_m)
    count = voxel_count(points, spacing)
    extent_m = float(np.ptp(points, axis=0).max()) + voxel_m
    while count > max_points and spacing < min(4 * extent_m, ceiling_m):
        spacing = min(ceiling_m, spacing * max(1.02, 1.005 * np.sqrt(count / max_points)))
        count = voxel_count(points, spacing)
    if support is None:
        best = voxel_sample(points, spacing)
    else:
        best, support = voxel_sample_supported(points, support, spacing)
    if (
        len(best) > max_points and spacing < ceiling_m
    ):  # a cap below the 2x2x2 voxels any grid can straddle
        keep = np.linspace(0, len(best) - 1, max_points).astype(np.intp)
        return best[keep], float(spacing), None if support is None else support[keep]
    return best, float(spacing), support


def bbox_of(points: np.ndarray) -> np.ndarray:
    """Axis-aligned box [x0, y0, z0, x1, y1, z1] (float64) of points [N >= 1, 3]."""
    return np.concatenate([points.min(axis=0), points.max(axis=0)]).astype(np.float64)


def project_to_pixels(
    points: np.ndarray, pose: np.ndarray, intrinsics: tuple[float, float, float, float]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World points float [N, 3] through a camera-to-world pose [4, 4] (OpenCV camera) to
    float64 (u, v) pixel centres (rounded, NaN or inf behind the camera) and z metres."""
    pose = np.asarray(pose, np.float64)
    cam = (points.astype(np.float64) - pose[:3, 3]) @ pose[:3, :3]
    fx, fy, cx, cy = intrinsics
    z = cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.floor(fx * cam[:, 0] / z + cx + 0.5)
        v = np.floor(fy * cam[:, 1] / z + cy + 0.5)
    return u, v, z


def pixels_of(image: np.ndarray, u: np.ndarray, v: np.ndarray, rgb_width: int) -> np.ndarray:
    """The values of an image at the RGB size divided by an integer ratio (depth, instance
    ids) under integer RGB pixels (u, v): each of its pixels stands for a ratio x ratio block."""
    ratio = max(1, round(rgb_width / image.shape[1]))
    return image[
        np.minimum(v // ratio, image.shape[0] - 1), np.minimum(u // ratio, image.shape[1] - 1)
    ]


def bbox_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two boxes [x0, y0, z0, x1, y1, z1] (0 when both are
    empty); flat boxes get a 1 mm thickness so that a flat thing still has a volume."""
    a_lo, a_hi = a[:3], np.maximum(a[3:], a[:3] + 1e-3)
    b_lo, b_hi = b[:3], np.maximum(b[3:], b[:3] + 1e-3)
    inter = np.prod(np.clip(np.minimum(a_hi, b_hi) - np.maximum(a_lo, b_lo), 0, None))
    union = np.prod(a_hi - a_lo) + np.prod(b_hi - b_lo) - inter
    return float(inter / union) if union > 0 else 0.0


def bbox_inside_fraction(a: np.ndarray, b: np.ndarray) -> float:
    """The fraction of box `a`'s volume inside box `b` (boxes as in `bbox_iou`)."""
    a_lo, a_hi = a[:3], np.maximum(a[3:], a[:3] + 1e-3)
    b_lo, b_hi = b[:3], np.maximum(b[3:], b[:3] + 1e-3)
    inter = np.prod(np.clip(np.minimum(a_hi, b_hi) - np.maximum(a_lo, b_lo), 0, None))
    return float(inter / np.prod(a_hi - a_lo))


def box_growth(a: np.ndarray, b: np.ndarray, margin_m: float) -> float:
    """How many times box `b` grows in volume when it takes in box `a` (boxes as in
    `bbox_iou`, both grown by margin_m on every side first, so that a flat box has a
    volume): 1.0 when `a` lies inside `b`."""
    lo_a, hi_a = a[:3] - margin_m, np.maximum(a[3:], a[:3]) + margin_m
    lo_b, hi_b = b[:3] - margin_m, np.maximum(b[3:], b[:3]) + margin_m
    union = np.maximum(hi_a, hi_b) - np.minimum(lo_a, lo_b)
    return float(np.prod(union) / max(float(np.prod(hi_b - lo_b)), 1e-12))


def bbox_iou_matrix(boxes_a: np.ndarray, boxes_b: np.ndarray) -> np.ndarray:
    """float [n, m]: `bbox_iou` of box a_i and box b_j. boxes: [n, 6], [m, 6]."""
    a_lo, b_lo = boxes_a[:, :3], boxes_b[:, :3]
    a_hi = np.maximum(boxes_a[:, 3:], a_lo + 1e-3)
    b_hi = np.maximum(boxes_b[:, 3:], b_lo + 1e-3)
    sides = np.minimum(a_hi[:, None], b_hi[None]) - np.maximum(a_lo[:, None], b_lo[None])
    inter = np.prod(np.clip(sides, 0, None), axis=2)
    union = np.prod(a_hi - a_lo, axis=1)[:, None] + np.prod(b_hi - b_lo, axis=1)[None] - inter
    return np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)


def bbox_intersects_matrix(boxes_a: np.ndarray, boxes_b: np.ndarray, margin_m: float) -> np.ndarray:
    """bool [n, m]: box a_i grown by margin_m intersects box b_j. boxes: [n, 6], [m, 6]."""
    if len(boxes_a) == 0 or len(boxes_b) == 0:
        return np.zeros((len(boxes_a), len(boxes_b)), bool)
    lo = np.maximum(boxes_a[:, None, :3] - margin_m, boxes_b[None, :, :3])
    hi = np.minimum(boxes_a[:, None, 3:] + margin_m, boxes_b[None, :, 3:])
    return np.all(lo <= hi, axis=2)


def overlap_fraction(points: np.ndarray, tree: cKDTree, radius_m: float) -> float:
    """Fraction of `points` [N, 3] with a point of `tree` within radius_m (0 for no points)."""
    return float(overlap_fractions([points], tree, radius_m)[0])


def overlap_fractions(
    point_sets: list[np.ndarray], tree: cKDTree, radius_m: float, bbox: np.ndarray | None = None
) -> np.ndarray:
    """`overlap_fraction` of each point set against one tree, in one tree query.

    bbox: the box of the tree's points, if known: points farther than radius_m outside it
    cannot have a neighbour and skip the query (same result, less work).
    Returns float64 [len(point_sets)] (0 for an empty set or an empty tree).
    """
    sizes = np.array([len(p) for p in point_sets], np.intp)
    fractions = np.zeros(len(point_sets))
    nonempty = np.flatnonzero(sizes)
    if tree.n == 0 or len(nonempty) == 0:
        return fractions
    points = np.concatenate([point_sets[i] for i in nonempty])
    hit = np.zeros(len(points), np.intp)
    if bbox is None:
        near = slice(None)
    else:
        near = np.all((points >= bbox[:3] - radius_m) & (points <= bbox[3:] + radius_m), axis=1)
    # the query's bound is exclusive: "within radius_m" includes a point at radius_m
    dist, _ = tree.query(points[near], k=1, distance_upper_bound=np.nextafter(radius_m, np.inf))
    hit[near] = dist <= radius_m
    starts = np.cumsum(sizes[nonempty]) - sizes[nonempty]
    fractions[nonempty] = np.add.reduceat(hit, starts) / sizes[nonempty]
    return fractions


def _components(n: int, edges: np.ndarray) -> np.ndarray:
    """int64 [n]: the smallest node of each node's connected component, for undirected
    `edges` [E, 2] (union by hooking onto the smaller root, then pointer jumping; a few
    rounds of array operations, where a sparse-graph library spends its time converting)."""
    root = np.arange(n)
    a, b = edges[:, 0], edges[:, 1]
    while True:
        ra, rb = root[a], root[b]
        apart = ra != rb
        if not apart.any():
            return root
        np.minimum.at(root, np.maximum(ra, rb)[apart], np.minimum(ra, rb)[apart])
        while True:  # every node straight to its root
            jumped = root[root]
            if np.array_equal(jumped, root):
                break
            root = jumped


CORE_MIN_SHARE = 0.25
"""Least share of a cloud's points in core cells for outlier removal to judge it: a sparser
cloud (150 points over a sofa) is kept whole rather than cut to its one dense corner."""
PART_SHARE = 0.25
"""Outlier removal keeps every cluster of at least this share of the largest one's points..."""
PART_VIEWS = 3.0
"""...and, where the points' support is known, every cluster some point of which this many
views saw: a smaller part that keyframe after keyframe shows (a lamp's base under a big
shade) is the thing's; a stray that one or two views left is not. (Each clean-up that drops
a part restarts its count, so the part's best-seen point is the test, not its median.)"""


def remove_outliers(points: np.ndarray, eps_m: float, min_points: int = 5) -> np.ndarray:
    """The points `outlier_free` keeps (the input itself when it keeps them all)."""
    keep = outlier_free(points, eps_m, min_points)
    return points if keep.all() else points[keep]


def outlier_free(
    points: np.ndarray, eps_m: float, min_points: int = 5, support: np.ndarray | None = None
) -> np.ndarray:
    """bool [N], the points outlier removal keeps: keep the object's DBSCAN clusters of core cells: the largest, any other of at least
    PART_SHARE of its points (a lamp's base apart from its shade) or, given the points'
    support (float [N], views each point stands for), any with a point PART_VIEWS views saw
    (a smaller part many views showed), and the chains of cells
    too sparse to be core that reach them with `min_points` points or more (a surface's
    rim, a pole, a leg); a stray point or two is dropped even where it touches the thing.

    DBSCAN runs over cells of eps_m / 2, each cell a point at its points' mean weighing as
    many points: a cell is core when the cells within eps_m of it hold `min_points` points,
    and core cells within eps_m of each other share a cluster (a third of point-wise
    DBSCAN's cost: a cell has a few neighbours where a point has dozens).
    Keeps every point of a cloud too small to cluster, or too sparse at eps_m: under
    CORE_MIN_SHARE of its points in core cells (a device's capped copy, an imported map of a
    few hundred points a piece), where nothing tells a stray from the thing's own surface.
    """
    if support is not None and len(support) != len(points):
        raise ValueError(f"support has {len(support)} values for {len(points)} points")
    everything = np.ones(len(points), bool)
    if len(points) < 4 * min_points:
        return everything
    keys = _voxel_keys(points, eps_m / 2)
    _, cell_of, weight = np.unique(keys, return_inverse=True, return_counts=True)
    cell_of = cell_of.ravel()
    centres = np.zeros((len(weight), 3))
    np.add.at(centres, cell_of, points)
    centres /= weight[:, None]
    pairs = cKDTree(centres).query_pairs(eps_m, output_type="ndarray")
    near_weight = weight.copy()
    np.add.at(near_weight, pairs[:, 0], weight[pairs[:, 1]])
    np.add.at(near_weight, pairs[:, 1], weight[pairs[:, 0]])
    core = near_weight >= min_points
    linked = pairs[core[pairs[:, 0]] & core[pairs[:, 1]]]
    labels = np.where(core, _components(len(weight), linked), 0)
    if weight[core].sum() < CORE_MIN_SHARE * len(points):
        return everything  # too sparse at eps_m to tell a stray from the thing's own surface
    mass = np.bincount(labels[core], weights=weight[core], minlength=len(weight))
    big = mass >= PART_SHARE * mass.max()
    if support is not None:
        best = np.zeros(len(weight))
        np.maximum.at(best, labels[cell_of], np.where(core[cell_of], support, 0))
        big |= best >= PART_VIEWS
    kept_cell = core & big[labels]
    # The cells that are not core (a surface's rim, a pole, a leg, a stray) are kept as
    # chains: a chain of at least `min_points` points reaching a kept cluster is a part of
    # the thing; a stray point or two touching it is not.
    sparse = ~core
    chain = _components(len(weight), pairs[sparse[pairs[:, 0]] & sparse[pairs[:, 1]]])
    chain_mass = np.bincount(chain, weights=np.where(sparse, weight, 0), minlength=len(weight))
    touching = pairs[kept_cell[pairs[:, 0]] != kept_cell[pairs[:, 1]]]
    from_kept = kept_cell[touching[:, 0]]
    reached = np.where(from_kept, touching[:, 1], touching[:, 0])
    cluster = labels[np.where(from_kept, touching[:, 0], touching[:, 1])]
    on_sparse = sparse[reached]
    reached, cluster = reached[on_sparse], cluster[on_sparse]
    # ...and so is a short chain that bridges two kept clusters (a gap in a pole)
    links = np.unique(np.stack([chain[reached], cluster], 1), axis=0)
    bridges = np.bincount(links[:, 0], minlength=len(weight))
    part = (bridges >= 2) | ((bridges >= 1) & (chain_mass >= min_points))
    kept_cell |= sparse & part[chain]
    return kept_cell[cell_of]


SUPPORT_SHARE = 0.2
"""Clean-up keeps a point whose support (the views that saw its voxel) is at least this share
of its object's well-seen support (the 90th percentile of its points')..."""
SUPPORT_PERCENTILE = 90
"""...that percentile."""


def well_supported(support: np.ndarray) -> np.ndarray:
    """bool [N]: the points enough views agree on, from their support float [N].

    A surface seen from k keyframes has its voxels hit by most of them; a range-noise tail,
    a mask's rim on the table under a mug or a neighbour's edge lands in a voxel only a few
    views hit. A point is kept when its support reaches SUPPORT_SHARE of the object's
    SUPPORT_PERCENTILE-th percentile; an object seen in a view or two keeps every point
    (nothing to tell a stray from a part seen once)."""
    if len(support) == 0:
        return np.ones(0, bool)
    threshold = SUPPORT_SHARE * float(np.percentile(support, SUPPORT_PERCENTILE))
    return support >= threshold


LOCAL_SUPPORT_SHARE = 0.2
"""During the walk a point is kept when its support is at least this share of the best
support among its SURFACE_NEIGHBOURS nearest points (`locally_supported`)."""


def locally_supported(points: np.ndarray, support: np.ndarray) -> np.ndarray:
    """bool [N]: the points whose support (float [N]) reaches LOCAL_SUPPORT_SHARE of the
    best among their SURFACE_NEIGHBOURS nearest points.

    The walk's own rule: a part of the thing only a few views have shown so far (its
    neighbours seen as rarely) stays until more views come, while a range-noise tail or a
    mask's rim next to a surface many views agree on goes."""
    if len(points) <= SURFACE_NEIGHBOURS:
        return np.ones(len(points), bool)
    _, nearest = cKDTree(points).query(points, k=SURFACE_NEIGHBOURS)
    return support >= LOCAL_SUPPORT_SHARE * support[nearest].max(axis=1)


SURFACE_NEIGHBOURS = 16
"""Points whose local plane a point is projected onto (`onto_local_surface`)."""
PLANAR_SPREAD = 0.25
"""A neighbourhood is a surface when its second-largest spread (variance) is at least this
share of its largest: a pole's or a leg's neighbours (spread along one line) are not
moved."""


def onto_local_surface(
    points: np.ndarray, k: int = SURFACE_NEIGHBOURS, support: np.ndarray | None = None
) -> np.ndarray:
    """Each point moved onto the plane fitted to its k nearest points (itself included),
    where they form a surface (PLANAR_SPREAD): float32 [N, 3].

    A depth sensor's noise lies along its rays, so a surface seen from a few metres grows a
    skin several centimetres thick that sets its box; the local plane of k points is about
    sqrt(k) times closer to the true surface than one noisy point. An edge or a corner moves
    by at most its neighbourhood's flattening; a thin part (no second spread) stays.

    support: float [N], the views each point stands for (`MapObject.support`); given it, the
    plane is fitted with each point weighted by its support: a voxel's mean of s views has
    1/s of one view's range variance, so the voxels many views agree on pin the plane, and a
    far view's lone sample off the surface (support 1, beside voxels a dozen views hit) no
    longer tilts it towards itself."""
    if len(points) <= k:
        return points
    if support is not None and len(support) != len(points):
        raise ValueError(f"support has {len(support)} values for {len(points)} points")
    _, nearest = cKDTree(points).query(points, k=k)
    around = points[nearest].astype(np.float64)
    if support is None:
        weight = np.full(nearest.shape, 1.0 / k)
    else:
        weight = np.maximum(support.astype(np.float64), 1e-6)[nearest]
        weight /= weight.sum(axis=1, keepdims=True)
    mean = np.einsum("nk,nki->ni", weight, around)
    centred = around - mean[:, None]
    spread, axes = np.linalg.eigh((centred * weight[:, :, None]).transpose(0, 2, 1) @ centred)
    normal = axes[:, :, 0]
    surface = spread[:, 1] >= PLANAR_SPREAD * spread[:, 2]
    offset = np.einsum("ni,ni->n", points - mean, normal) * surface
    return (points - offset[:, None] * normal).astype(np.float32)
