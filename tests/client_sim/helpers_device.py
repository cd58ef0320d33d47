"""Shared pieces of the device end-to-end tests: an analytic frame source, session set-up,
comparison with the server's map, and condition polling (never sleeps as synchronisation)."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from dataclasses import dataclass

import httpx
import numpy as np

from client_sim.sources.base import FrameSource, SourceFrame

WIDTH_PX, HEIGHT_PX = 320, 240
INTRINSICS = (277.0, 277.0, 159.5, 119.5)
WAIT_S = 20.0

FAST_KNOBS = {
    "keyframe_interval": 1,
    "min_observations": 2,
    "min_mapping_bbox_area": 100,
    "local_map_update_frequency": 1,
    "depth_downsampling_ratio": 4,
}
"""Every frame mapped and published, objects confirmed on their second view."""


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


class RectSource(FrameSource):
    """Frames of labelled rectangles seen by a camera at (x, 0, 0) looking along world +z,
    sliding `step_m` along x per frame from `start_x_m`. Exact depth at RGB size, exact
    instance ids (score 0.9), one flat colour per instance."""

    def __init__(
        self,
        rects: tuple[Rect, ...],
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
        fx, fy, cx, cy = INTRINSICS
        u, v = np.meshgrid(np.arange(WIDTH_PX), np.arange(HEIGHT_PX))
        depth_m = np.zeros((HEIGHT_PX, WIDTH_PX), np.float32)
        ids = np.zeros((HEIGHT_PX, WIDTH_PX), np.uint16)
        for rect in sorted(self.rects, key=lambda r: -r.depth_m):  # far to near: near wins
            x = (u - cx) / fx * rect.depth_m + cam_x_m
            y = (v - cy) / fy * rect.depth_m
            inside = (x >= rect.x0) & (x <= rect.x1) & (y >= rect.y0) & (y <= rect.y1)
            depth_m[inside] = rect.depth_m
            ids[inside] = rect.instance_id
        rgb = np.full((HEIGHT_PX, WIDTH_PX, 3), 90, np.uint8)
        rgb[ids > 0] = (np.stack([ids * 70, ids * 130, ids * 40], -1)[ids > 0] % 256).astype(
            np.uint8
        )
        pose = np.eye(4)
        pose[0, 3] = cam_x_m
        present = set(np.unique(ids).tolist()) - {0}
        return SourceFrame(
            index=index,
            t=index / 30.0,
            rgb=rgb,
            depth_m=depth_m,
            pose=pose,
            intrinsics=INTRINSICS,
            instance_ids=ids,
            instances=[
                {"id": r.instance_id, "label": r.label, "score": 0.9}
                for r in self.rects
                if r.instance_id in present
            ],
        )


async def wait_until(
    condition: Callable[[], bool], timeout_s: float = WAIT_S, what: str = ""
) -> None:
    """Poll `condition` until true; AssertionError naming `what` after `timeout_s`."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what or condition}")
        await asyncio.sleep(0.02)  # a polling period, not synchronisation


async def server_state(server_url: str, sid: str, token: str) -> tuple[int, list[dict]]:
    """(update_seq, confirmed objects with points) straight from the server (no proxy)."""
    headers = {"Authorization": f"Bearer {token}"}
    async with httpx.AsyncClient(base_url=server_url, headers=headers, timeout=10) as http:
        stats = (await http.get(f"/v1/sessions/{sid}")).json()
        objects = (await http.get(f"/v1/sessions/{sid}/objects", params={"points": True})).json()
    return stats["update_seq"], objects


def assert_local_map_equals(local_map, objects: list[dict], max_points: int) -> None:
    """The local map holds exactly `objects` (GET /objects?points=true) at client resolution."""
    expected = {o["id"]: (o["version"], o["label"]) for o in objects}
    assert local_map.snapshot() == expected
    for obj in objects:
        held = local_map.get(obj["id"])
        assert len(held["points"]) == len(obj["points"]) <= max_points, obj["label"]
