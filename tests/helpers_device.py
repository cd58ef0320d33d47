"""Shared pieces of the device end-to-end tests: session knobs, comparison with the server's
map, and condition polling (never sleeps as synchronisation). Their frames come from the
analytic test world (tests/analytic_world.py)."""

from __future__ import annotations

import asyncio
import ssl
import time
from collections.abc import Callable

import httpx
import numpy as np

WAIT_S = 20.0

FAST_KNOBS = {
    "keyframe_interval": 1,
    "min_observations": 2,
    "min_mapping_bbox_area": 100,
    "local_map_update_frequency": 1,
    "depth_downsampling_ratio": 4,
}
"""Every frame mapped and published, objects confirmed on their second view."""


async def wait_until(
    condition: Callable[[], bool], timeout_s: float = WAIT_S, what: str = ""
) -> None:
    """Poll `condition` until true; AssertionError naming `what` after `timeout_s`."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what or condition}")
        await asyncio.sleep(0.02)  # a polling period, not synchronisation


async def server_state(
    server_url: str, sid: str, token: str, verify: ssl.SSLContext | bool = True
) -> tuple[int, list[dict]]:
    """(update_seq, confirmed objects with points) straight from the server (no proxy);
    verify: what an https:// server's certificate is checked against."""
    headers = {"Authorization": f"Bearer {token}"}
    async with httpx.AsyncClient(
        base_url=server_url, headers=headers, timeout=10, verify=verify
    ) as http:
        stats = (await http.get(f"/v1/sessions/{sid}")).json()
        objects = (await http.get(f"/v1/sessions/{sid}/objects", params={"points": True})).json()
    return stats["update_seq"], objects


def assert_local_map_equals(local_map, objects: list[dict], max_points: int) -> None:
    """The local map holds exactly `objects` (GET /objects?points=true) at client resolution:
    the same ids, versions and labels, and the same points row for row, equal within the
    storage's rounding. The wire carries float16 (within one float16 spacing at the value),
    the map keeps uint8 offsets in the object's box (within `points_step` / 2 per axis) and
    the REST body rounds to 0.1 mm."""
    expected = {o["id"]: (o["version"], o["label"]) for o in objects}
    assert local_map.snapshot() == expected
    for obj in objects:
        held = local_map.get(obj["id"])
        assert len(held["points"]) == len(obj["points"]) <= max_points, obj["label"]
        if not len(obj["points"]):
            continue
        served = np.asarray(obj["points"], np.float64)
        float16_spacing = np.spacing(np.abs(served).astype(np.float16)).astype(np.float64)
        tolerance = np.asarray(held["points_step"]) / 2 + float16_spacing + 1e-4
        assert np.all(np.abs(held["points"] - served) <= tolerance), obj["label"]
