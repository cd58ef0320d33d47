"""Restart and crash (kill -9) recovery: nothing acknowledged is lost."""

from __future__ import annotations

import asyncio

import httpx
import msgpack
import pytest
import websockets
from analytic_world import Rect
from devices import TIMEOUT_S, frame_message, stream_in_step, wait_settled

from app.server.runner import ServerProcess, free_port

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]

SCENE = [
    Rect(1, "chair", -0.6, -0.3, -0.1, 0.3, 2.0),
    Rect(2, "refrigerator", 0.1, -0.8, 0.9, 0.8, 2.5),
]
KNOBS = {
    "keyframe_interval": 1,
    "min_observations": 2,
    "min_mapping_bbox_area": 100,
    "local_map_update_frequency": 1,
}


async def collect_updates(url: str, since: int, until_seq: int) -> tuple[dict, int]:
    held = {}
    async with websockets.connect(f"{url}?since={since}", max_size=None) as sub:
        seq = since
        while True:
            delta = msgpack.unpackb(await asyncio.wait_for(sub.recv(), TIMEOUT_S))
            if delta["full"]:
                held = {}
            for up in delta["upserts"]:
                held[up["id"]] = (up["version"], up["label"])
            for oid in delta["removed"]:
                held.pop(oid, None)
            seq = delta["seq"]
            if seq >= until_seq:
                return held, seq


@pytest.mark.parametrize("how", ["restart", "kill -9"])
def test_the_server_comes_back_with_everything_it_acknowledged(tmp_path, how):
    port = free_port()
    server = ServerProcess(tmp_path, port).start()
    ws_base = f"ws://127.0.0.1:{port}"
    try:
        sid = httpx.post(f"{server.url}/v1/sessions", json={"name": "home", "knobs": KNOBS}).json()[
            "session_id"
        ]
        frames = [frame_message(SCENE, i, cam_xy=(0.02 * i, 0.0)) for i in range(4)]
        replies = asyncio.run(stream_in_step(f"{ws_base}/v1/sessions/{sid}/stream", frames))
        assert all(r["type"] == "ack" for r in replies)
        wait_settled(server.url, sid)  # what a reader sees next is what the store keeps
        before = httpx.get(
            f"{server.url}/v1/sessions/{sid}/objects", params={"points": True}
        ).json()
        seq_before = httpx.get(f"{server.url}/v1/sessions/{sid}").json()["update_seq"]
        # a subscriber that applied everything up to some earlier seq
        held, applied = asyncio.run(collect_updates(f"{ws_base}/v1/sessions/{sid}/updates", 0, 1))
        assert len(before) == 2 and seq_before >= 2
        if how == "kill -9":
            server.kill9()
        else:
            server.stop()

        server = ServerProcess(tmp_path, port).start()
        after = httpx.get(f"{server.url}/v1/sessions/{sid}/objects", params={"points": True}).json()
        assert after == before
        assert httpx.get(f"{server.url}/v1/sessions/{sid}").json()["update_seq"] == seq_before
        assert [s["name"] for s in httpx.get(f"{server.url}/v1/sessions").json()] == ["home"]

        # the subscriber resumes from its seq and ends up with the whole map
        resumed, _ = asyncio.run(
            collect_updates(f"{ws_base}/v1/sessions/{sid}/updates", applied, seq_before)
        )
        held.update(resumed)
        assert held == {o["id"]: (o["version"], o["label"]) for o in after}

        # and mapping continues with new ids and a growing seq
        more = [
            frame_message([*SCENE, Rect(3, "lamp", -1.2, -0.9, -0.8, -0.4, 2.2)], 10 + i)
            for i in range(2)
        ]
        asyncio.run(stream_in_step(f"{ws_base}/v1/sessions/{sid}/stream", more))
        stats = httpx.get(f"{server.url}/v1/sessions/{sid}").json()
        assert stats["update_seq"] > seq_before and stats["objects"] == 3
    finally:
        server.stop()
