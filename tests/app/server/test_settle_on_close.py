"""A stream that closes leaves its map settled: a stray clean-up had not yet visited is gone
once the device has stopped."""

from __future__ import annotations

import asyncio

import httpx
import pytest
import websockets
from analytic_world import Rect
from devices import frame_message, send_and_collect, wait_settled

from app.protocol.frame import DETECTIONS_FIELD, INSTANCES_FIELD

pytestmark = pytest.mark.timeout(120)

KNOBS = {
    "keyframe_interval": 1,
    "min_observations": 2,
    "min_mapping_bbox_area": 100,
    "local_map_update_frequency": 1,
    "cleanup_interval": 1000,  # no clean-up during the walk: only settling removes the stray
}
WALL = Rect(9, "whiteboard", -3.0, -2.0, 3.0, 2.0, 3.0)
MUG = Rect(1, "mug", -0.3, -0.2, 0.0, 0.1, 2.0)
STRAY = Rect(1, "mug", 0.8, 0.8, 0.86, 0.86, 2.0)
"""A patch of the mug's mask far from it, in one frame only (a detector's slip)."""


def _mug_box(server, sid: str) -> list[float]:
    objects = httpx.get(f"{server.url}/v1/sessions/{sid}/objects", timeout=10).json()
    (mug,) = [o for o in objects if o["label"] == "mug"]
    return mug["bbox"]


def _streams(server, sid: str) -> int:
    return httpx.get(f"{server.url}/v1/sessions/{sid}", timeout=10).json()["streams"]


def _frame(rects: list[Rect], seq: int) -> dict:
    """A v1 frame; a detection whose mask has two parts is listed once."""
    message = frame_message(rects, seq)
    detections = message[DETECTIONS_FIELD]
    detections[INSTANCES_FIELD] = list({d["id"]: d for d in detections[INSTANCES_FIELD]}.values())
    return message


def test_a_closed_stream_settles_its_map(live_server):
    server = live_server()
    sid = httpx.post(f"{server.url}/v1/sessions", json={"knobs": KNOBS}, timeout=10).json()[
        "session_id"
    ]
    frames = [_frame([WALL, MUG] + ([STRAY] if i == 4 else []), i) for i in range(5)]

    async def stream_then_close() -> float:
        url = f"{server.ws_url}/v1/sessions/{sid}/stream"
        async with websockets.connect(url, max_size=None) as ws:
            replies = []
            for m in frames:
                replies.append((await send_and_collect(ws, [m]))[0])
            assert all(r["type"] == "ack" for r in replies), replies
            assert _streams(server, sid) == 1
            return _mug_box(server, sid)[3]  # x1 while streaming

    x1_streaming = asyncio.run(stream_then_close())
    assert x1_streaming > 0.75  # the stray is in the mug's box while the device streams
    # No stream counted: the close has settled the map, and what a reader sees is settled.
    wait_settled(server.url, sid, timeout_s=30)
    assert _mug_box(server, sid)[3] < 0.1  # the mug's own box
