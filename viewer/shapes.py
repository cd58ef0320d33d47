"""Shapes of the viewer's scene: box edges as line segments, the first camera that frames the
map beside the GUI panel, and the floor grid under it (pure helpers, no viser)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from viewer.palette import Rgb

# The 12 edges of a box as pairs of corner indices; corner k has x = bit 0, y = bit 1, z = bit 2.
_BOX_EDGES = np.array(
    [(0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7), (0, 4), (1, 5), (2, 6), (3, 7)]
)
_CORNER_BITS = np.array([[(k >> axis) & 1 for axis in range(3)] for k in range(8)], bool)


def box_segments(bboxes: np.ndarray) -> np.ndarray:
    """float32 [12 * N, 2, 3]: the edges of N axis-aligned boxes [N, 6] (x0 y0 z0 x1 y1 z1)."""
    bboxes = np.asarray(bboxes, np.float32).reshape(-1, 6)
    lo, hi = bboxes[:, None, :3], bboxes[:, None, 3:]
    corners = np.where(_CORNER_BITS[None], hi, lo)  # [N, 8, 3]
    return corners[:, _BOX_EDGES].reshape(-1, 2, 3)


def segment_colors(colors: list[Rgb]) -> np.ndarray:
    """uint8 [12 * N, 2, 3]: each box's colour on both ends of its 12 edges."""
    per_box = np.asarray(colors, np.uint8).reshape(-1, 1, 1, 3)
    return np.broadcast_to(per_box, (per_box.shape[0], 12, 2, 3)).reshape(-1, 2, 3).copy()


PANEL_PX = 400
"""Width the GUI panel covers on the right of the page ("large" controls: 24 em + margins)."""
VIEW_DIRECTION = (0.55, 0.45)
"""The first camera looks from aside (this much along a horizontal diagonal) and above."""
FRAME_MARGIN = 1.08
"""Slack around the map's bounding sphere when framing it."""
FLOOR_MARGIN_M = 0.25
"""How far the floor grid reaches past the map's footprint (before rounding)."""
FLOOR_STEP_M = 0.5
"""The floor grid's edges lie on multiples of this (its cell size)."""


@dataclass(frozen=True)
class CameraView:
    """Where a camera stands and what it looks at, world metres."""

    position: tuple[float, float, float]
    look_at: tuple[float, float, float]


def frame_view(
    bounds: tuple[np.ndarray, np.ndarray],
    up: np.ndarray,
    fov_y: float,
    aspect: float,
    panel_share: float = 0.0,
) -> CameraView:
    """A camera that shows the whole box `bounds` (min, max corners) from above and aside,
    in the part of the screen the GUI panel leaves free.

    up: unit up vector of the world. fov_y: vertical field of view (radians); aspect: width /
    height of the canvas; panel_share: the share of the canvas width the panel covers on the
    right. The box's bounding sphere fits in the free part's field of view, and the aim is
    shifted right so that the map is centred in the free part, not under the panel.
    """
    lo, hi = (np.asarray(b, np.float64) for b in bounds)
    up = np.asarray(up, np.float64)
    center = (lo + hi) / 2
    radius = max(float(np.linalg.norm(hi - lo)) / 2, 0.25) * FRAME_MARGIN
    panel_share = min(max(panel_share, 0.0), 0.6)
    tan_y = np.tan(fov_y / 2)
    tan_x = aspect * tan_y  # half-width of the screen at distance 1
    free_tan = min(tan_y, (1 - panel_share) * tan_x)  # the free part, half its width
    distance = radius / np.sin(np.arctan(free_tan))
    side = np.ones(3) - np.abs(up)  # a horizontal diagonal: the two axes that are not up
    side = -side / np.linalg.norm(side)
    back = VIEW_DIRECTION[0] * side + VIEW_DIRECTION[1] * up
    back /= np.linalg.norm(back)
    right = np.cross(-back, up)
    right /= np.linalg.norm(right)
    # NDC x of the free part's centre is -panel_share; shift the aim the other way.
    look_at = center + right * panel_share * distance * tan_x
    position = look_at + back * distance
    return CameraView(tuple(position.tolist()), tuple(look_at.tolist()))  # type: ignore[arg-type]


@dataclass(frozen=True)
class FloorGrid:
    """A grid on the map's floor: the plane at the lowest box face along up, spanning the
    map's footprint plus a margin, its edges on multiples of FLOOR_STEP_M (so it changes only
    when the footprint crosses one)."""

    plane: str
    """viser's plane name: the two horizontal axes ("xy" when z is up)."""
    position: tuple[float, float, float]
    """The grid's centre, metres."""
    width: float
    """Extent along the plane's first axis, metres."""
    height: float
    """Extent along the plane's second axis, metres."""


def floor_grid(bounds: tuple[np.ndarray, np.ndarray] | None, up: np.ndarray) -> FloorGrid | None:
    """The floor grid under the box `bounds` (None when the map is empty).

    up: a unit axis vector (+-x, +-y, +-z). The floor is the lowest box face along up: the
    minimum of that coordinate when up is positive, the maximum when it is negative.
    """
    if bounds is None:
        return None
    lo, hi = (np.asarray(b, np.float64) for b in bounds)
    up = np.asarray(up, np.float64)
    axis = int(np.argmax(np.abs(up)))
    first, second = (a for a in range(3) if a != axis)
    position = np.zeros(3)
    position[axis] = lo[axis] if up[axis] > 0 else hi[axis]
    extents = []
    for a in (first, second):
        start = np.floor((lo[a] - FLOOR_MARGIN_M) / FLOOR_STEP_M) * FLOOR_STEP_M
        end = np.ceil((hi[a] + FLOOR_MARGIN_M) / FLOOR_STEP_M) * FLOOR_STEP_M
        position[a] = (start + end) / 2
        extents.append(float(end - start))
    plane = "xyz"[first] + "xyz"[second]
    return FloorGrid(plane, tuple(position.tolist()), extents[0], extents[1])  # type: ignore[arg-type]
