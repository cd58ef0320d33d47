"""A tiny analytic RGB-D scene for engine tests: labelled rectangles on planes facing the camera.

The camera looks along world +z with identity rotation; rectangle i lies in the plane
z = depth_m and covers [x0, x1] x [y0, y1]. Exact depth and instance ids, no renderer needed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.protocol import FrameInput

WIDTH, HEIGHT = 320, 240
INTRINSICS = (277.0, 277.0, 159.5, 119.5)


@dataclass
class Rect:
    instance_id: int
    label: str
    x0: float
    y0: float
    x1: float
    y1: float
    depth_m: float


def render_rects(
    rects: list[Rect], cam_xy: tuple[float, float] = (0.0, 0.0), ratio: int = 2, seq: int = 0
) -> FrameInput:
    """A frame seeing `rects` from a camera at (x, y, 0); nearer rectangles occlude farther."""
    fx, fy, cx, cy = INTRINSICS
    pose = np.eye(4)
    pose[0, 3], pose[1, 3] = cam_xy
    u, v = np.meshgrid(np.arange(WIDTH), np.arange(HEIGHT))
    depth_full = np.zeros((HEIGHT, WIDTH), np.float32)
    ids = np.zeros((HEIGHT, WIDTH), np.uint16)
    for rect in sorted(rects, key=lambda r: -r.depth_m):  # far to near: near wins
        x = (u - cx) / fx * rect.depth_m + cam_xy[0]
        y = (v - cy) / fy * rect.depth_m + cam_xy[1]
        inside = (x >= rect.x0) & (x <= rect.x1) & (y >= rect.y0) & (y <= rect.y1)
        depth_full[inside] = rect.depth_m
        ids[inside] = rect.instance_id
    # nearest downsampling: the centre pixel of each ratio x ratio block
    depth = depth_full[ratio // 2 :: ratio, ratio // 2 :: ratio][
        : HEIGHT // ratio, : WIDTH // ratio
    ]
    present = set(np.unique(ids).tolist()) - {0}
    return FrameInput(
        seq=seq,
        t=seq / 30.0,
        pose=pose,
        intrinsics=INTRINSICS,
        rgb_size=(WIDTH, HEIGHT),
        depth_m=np.ascontiguousarray(depth),
        instance_ids=ids,
        instances=[
            {"id": r.instance_id, "label": r.label, "score": 0.9}
            for r in rects
            if r.instance_id in present
        ],
    )
