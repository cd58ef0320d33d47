"""A minimal device for server tests: analytic frames, the real encoder, a timed WebSocket."""

from __future__ import annotations

import asyncio
import time

import httpx
import msgpack
import numpy as np
import websockets
from analytic_world import INTRINSICS, Rect, render_rects

from client_sim.encoder import FrameEncoder

TIMEOUT_S = 20.0


def frame_message(rects: list[Rect], seq: int, cam_xy=(0.0, 0.0), t: float | None = None) -> dict:
    """A v1 frame of the analytic scene, encoded like a device would (depth ÷2, zstd depth:
    test_server's bad-frame variants corrupt a zstd depth image); `t` defaults to seq / 30."""
    full = render_rects(rects, cam_xy=cam_xy, ratio=1, seq=seq)
    rgb = np.full((*full.depth_m.shape, 3), 128, np.uint8)
    return (
        FrameEncoder(2, depth_codec="zstd")
        .encode(
            seq=seq,
            t=seq / 30 if t is None else t,
            rgb=rgb,
            depth_m=full.depth_m,
            pose=full.pose,
            intrinsics=INTRINSICS,
            instance_ids=full.instance_ids,
            instances=full.instances,
        )
        .message
    )


async def send_and_collect(ws, messages: list, timeout_s: float = TIMEOUT_S) -> list[dict]:
    """Send each message, then read until one reply per message has arrived."""
    for message in messages:
        await ws.send(message if isinstance(message, bytes | str) else msgpack.packb(message))
    replies = []
    while len(replies) < len(messages):
        raw = await asyncio.wait_for(ws.recv(), timeout_s)
        replies.append(msgpack.unpackb(raw))
    return replies


async def stream(url: str, messages: list, headers=None) -> list[dict]:
    async with websockets.connect(url, additional_headers=headers, max_size=None) as ws:
        return await send_and_collect(ws, messages)


async def stream_in_step(url: str, messages: list, headers=None) -> list[dict]:
    """Send one frame at a time, waiting for its answer (a device at its mapping rate)."""
    async with websockets.connect(url, additional_headers=headers, max_size=None) as ws:
        return [(await send_and_collect(ws, [m]))[0] for m in messages]


def wait_settled(server_url: str, sid: str, headers=None, timeout_s: float = TIMEOUT_S) -> None:
    """Wait until no stream of `sid` is counted: a closed stream's settle (run after its socket
    closed) has committed and published, so what a reader sees next is the stored map."""
    deadline = time.monotonic() + timeout_s
    while True:
        r = httpx.get(f"{server_url}/v1/sessions/{sid}", headers=headers, timeout=timeout_s)
        assert r.status_code == 200, r.text
        if r.json()["streams"] == 0:
            return
        if time.monotonic() > deadline:
            raise AssertionError(f"session {sid} still counts a stream after {timeout_s:g} s")
        time.sleep(0.02)  # a polling period, not synchronisation
