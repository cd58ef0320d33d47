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
STATE_READS = 5
"""How many times `server_state` reads the objects while commits land between its reads."""

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
    """(update_seq, confirmed objects with points) straight from the server (no proxy), one
    state: the seq is read before and after the objects, and again if a commit came between
    (a closed stream settles its map after its last ack). verify: what an https:// server's
    certificate is checked against."""
    headers = {"Authorization": f"Bearer {token}"}
    async with httpx.AsyncClient(
        base_url=server_url, headers=headers, timeout=10, verify=verify
    ) as http:
        seq = (await http.get(f"/v1/sessions/{sid}")).json()["update_seq"]
        for _ in range(STATE_READS):
            objects = (
                await http.get(f"/v1/sessions/{sid}/objects", params={"points": True})
            ).json()
            seq, before = (await http.get(f"/v1/sessions/{sid}")).json()["update_seq"], seq
            if seq == before:
                break
    return seq, objects


async def synced_state(
    device, server_url: str, sid: str, token: str, verify: ssl.SSLContext | bool = True
) -> tuple[int, list[dict]]:
    """The server's (update_seq, objects) once `device` has applied exactly that seq: an
    update the device applied past it (the settle) is read again. AssertionError if the
    device does not catch up within WAIT_S."""
    deadline = time.monotonic() + WAIT_S
    while True:
        seq, objects = await server_state(server_url, sid, token, verify)
        remaining = deadline - time.monotonic()
        assert await device.wait_synced(seq, max(0.0, remaining)), (
            f"local seq {device.local_map.seq} < {seq}"
        )
        if device.local_map.seq == seq or time.monotonic() > deadline:
            return seq, objects


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
