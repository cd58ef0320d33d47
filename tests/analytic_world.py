"""The analytic test world: labelled rectangles on planes facing the camera.

The camera stands at (x, y, 0) with identity rotation, looking along world +z; rectangle i
lies in the plane z = depth_m and covers [x0, x1] x [y0, y1]. Depth and instance ids are
exact, no renderer needed. The same world feeds the engine (`render_rects`, a FrameInput)
and the device (`RectSource`, a FrameSource), so server and device tests see one scene.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from app.perception.base import FrameInput
from client_sim.sources.base import FrameSource, SourceFrame

WIDTH_PX, HEIGHT_PX = 320, 240
INTRINSICS = (277.0, 277.0, 159.5, 119.5)


@dataclass(frozen=True)
class Rect:
    """A labelled rectangle in the plane z = depth_m, covering [x0, x1] x [y0, y1] (metres)."""

    instance_id: int
    label: str
    x0: float
    y0: float
    x1: float
    y1: float
    depth_m: float


KITCHEN = (
    Rect(1, "chair", -0.6, -0.3, -0.1, 0.3, 2.0),
    Rect(2, "refrigerator", 0.1, -0.8, 0.9, 0.8, 2.5),
)
BATHROOM = (
    Rect(3, "bathtub", 3.8, 0.0, 4.6, 0.5, 2.2),
    Rect(4, "toilet", 3.0, -0.2, 3.5, 0.4, 2.0),
)


def _rasterize(
    rects, cam_xy: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict]]:
    """(depth_m float32 [H, W], instance_ids uint16 [H, W], camera pose [4, 4], the visible
    instances with score 0.9) at full resolution; nearer rectangles occlude farther ones."""
    fx, fy, cx, cy = INTRINSICS
    u, v = np.meshgrid(np.arange(WIDTH_PX), np.arange(HEIGHT_PX))
    depth_m = np.zeros((HEIGHT_PX, WIDTH_PX), np.float32)
    ids = np.zeros((HEIGHT_PX, WIDTH_PX), np.uint16)
    for rect in sorted(rects, key=lambda r: -r.depth_m):  # far to near: near wins
        x = (u - cx) / fx * rect.depth_m + cam_xy[0]
        y = (v - cy) / fy * rect.depth_m + cam_xy[1]
        inside = (x >= rect.x0) & (x <= rect.x1) & (y >= rect.y0) & (y <= rect.y1)
        depth_m[inside] = rect.depth_m
        ids[inside] = rect.instance_id
    pose = np.eye(4)
    pose[0, 3], pose[1, 3] = cam_xy
    present = set(np.unique(ids).tolist()) - {0}
    instances = [
        {"id": r.instance_id, "label": r.label, "score": 0.9}
        for r in rects
        if r.instance_id in present
    ]
    return depth_m, ids, pose, instances


def render_rects(
    rects: list[Rect], cam_xy: tuple[float, float] = (0.0, 0.0), ratio: int = 2, seq: int = 0
) -> FrameInput:
    """The engine's input for a camera at (x, y, 0): depth downsampled by `ratio` (nearest,
    the centre pixel of each block), instance ids at full size."""
    depth_full, ids, pose, instances = _rasterize(rects, cam_xy)
    depth = depth_full[ratio // 2 :: ratio, ratio // 2 :: ratio][
        : HEIGHT_PX // ratio, : WIDTH_PX // ratio
    ]
    return FrameInput(
        seq=seq,
        t=seq / 30.0,
        pose=pose,
        intrinsics=INTRINSICS,
        rgb_size=(WIDTH_PX, HEIGHT_PX),
        depth_m=np.ascontiguousarray(depth),
        instance_ids=ids,
        instances=instances,
    )


class RectSource(FrameSource):
    """Frames of labelled rectangles seen by a camera at (x, 0, 0), sliding `step_m` along x
    per frame from `start_x_m`. Exact depth at RGB size, exact instance ids (score 0.9), one
    flat colour per instance. rects: the scene, or a function of the frame index giving the
    rectangles in view on that frame."""

    def __init__(
        self,
        rects: tuple[Rect, ...] | Callable[[int], list[Rect]],
        n_frames: int,
        start_x_m: float = 0.0,
        step_m: float = 0.01,
        name: str = "rects",
    ):
        self.rects, self.n_frames = rects, n_frames
        self.start_x_m, self.step_m = start_x_m, step_m
        self.name = name

    def __len__(self) -> int:
        return self.n_frames

    def frame(self, index: int) -> SourceFrame:
        index = self._check_index(index)
        cam_x_m = self.start_x_m + self.step_m * index
        rects = self.rects(index) if callable(self.rects) else self.rects
        depth_m, ids, pose, instances = _rasterize(rects, (cam_x_m, 0.0))
        rgb = np.full((HEIGHT_PX, WIDTH_PX, 3), 90, np.uint8)
        rgb[ids > 0] = (np.stack([ids * 70, ids * 130, ids * 40], -1)[ids > 0] % 256).astype(
            np.uint8
        )
        return SourceFrame(
            index=index,
            t=index / 30.0,
            rgb=rgb,
            depth_m=depth_m,
            pose=pose,
            intrinsics=INTRINSICS,
            instance_ids=ids,
            instances=instances,
        )
