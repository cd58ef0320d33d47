"""A subscriber that stops reading is closed with 1013 (counted, logged) long before the ping
timeout, and resumes with `since` to end equal to the server (docs/faults.md,
"No client can stall the server")."""

from __future__ import annotations

import asyncio
import logging
import socket
import time

import httpx
import msgpack
import pytest
import websockets
from analytic_world import Rect
from devices import frame_message, stream_in_step
from websockets.client import ClientProtocol
from websockets.frames import Close, Opcode
from websockets.uri import parse_uri

pytestmark = [pytest.mark.slow, pytest.mark.timeout(120)]

KNOBS = {
    "keyframe_interval": 1,
    "min_observations": 1,
    "min_mapping_bbox_area": 100,
    "local_map_update_frequency": 1,
}
RECTS = [
    Rect(i + 1, f"box {i}", x, y, x + 0.15, y + 0.15, 2.0)
    for i, (x, y) in enumerate(
        (-1.2 + 0.25 * col, -0.9 + 0.25 * row) for row in range(8) for col in range(10)
    )
]
"""Eighty objects: every keyframe changes all of them (deltas of ~150 KB)."""
FRAMES = 120
"""Enough updates to fill the kernel's socket buffers (several MB on loopback) and more."""
COUNTER = "semanticxr_slow_subscribers_closed_total"


def counter(url: str) -> float:
    for line in httpx.get(f"{url}/metrics", timeout=10).text.splitlines():
        if line.startswith(COUNTER + " "):
            return float(line.split()[1])
    raise AssertionError(f"{COUNTER} missing from /metrics")


class StalledSubscriber:
    """A real WebSocket client on a raw socket with a tiny receive buffer, that reads only
    when told to (websockets' sans-I/O protocol frames the bytes)."""

    def __init__(self, url: str):
        self.protocol = ClientProtocol(parse_uri(url), max_size=None)
        host, port = url.split("//")[1].split("/")[0].split(":")
        self.sock = socket.socket()
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # before connect
        self.sock.connect((host, int(port)))
        self.sock.settimeout(10)
        self.protocol.send_request(self.protocol.connect())
        self._flush()
        while self.protocol.handshake_exc is None and self.protocol.state.name == "CONNECTING":
            self.protocol.receive_data(self.sock.recv(4096))
        assert self.protocol.handshake_exc is None
        self.deltas: list[dict] = [
            msgpack.unpackb(e.data)
            for e in self.protocol.events_received()
            if getattr(e, "opcode", None) == Opcode.BINARY
        ]

    def _flush(self) -> None:
        for data in self.protocol.data_to_send():
            if data:
                self.sock.sendall(data)

    def read_to_the_end(self) -> Close | None:
        """Read everything the server sent until it closes; the close frame, if any."""
        close = None
        while close is None:
            data = self.sock.recv(1 << 16)
            if not data:
                self.protocol.receive_eof()
            else:
                self.protocol.receive_data(data)
            for event in self.protocol.events_received():
                if getattr(event, "opcode", None) == Opcode.BINARY:
                    self.deltas.append(msgpack.unpackb(event.data))
                elif getattr(event, "opcode", None) == Opcode.CLOSE:
                    close = Close.parse(event.data)
            if not data:
                break
        self._flush()
        self.sock.close()
        return close


async def resume(url: str, held: dict, since: int, until_seq: int) -> dict:
    async with websockets.connect(f"{url}?since={since}", max_size=None) as sub:
        while since < until_seq:
            delta = msgpack.unpackb(await asyncio.wait_for(sub.recv(), 20))
            apply(held, delta)
            since = delta["seq"]
    return held


def apply(held: dict, delta: dict) -> None:
    if delta["full"]:
        held.clear()
    for up in delta["upserts"]:
        held[up["id"]] = up["version"]
    for oid in delta["removed"]:
        held.pop(oid, None)


def test_a_subscriber_that_stops_reading_is_closed_with_1013_and_resumes_with_since(
    live_server, caplog
):
    server = live_server()
    assert counter(server.url) == 0  # present at 0 on a fresh server
    sid = httpx.post(f"{server.url}/v1/sessions", json={"knobs": KNOBS}, timeout=10).json()[
        "session_id"
    ]
    stream = f"{server.ws_url}/v1/sessions/{sid}/stream"
    updates = f"{server.ws_url}/v1/sessions/{sid}/updates"
    frames = [frame_message(RECTS, seq, cam_xy=(0.01 * seq, 0.0)) for seq in range(FRAMES)]
    asyncio.run(stream_in_step(stream, frames[:2]))

    caplog.set_level(logging.WARNING, logger="app.server.routes.ws")
    stalled = StalledSubscriber(f"{updates}?since=0")
    t0 = time.monotonic()
    asyncio.run(stream_in_step(stream, frames[2:]))  # one publication per keyframe
    deadline = time.monotonic() + 15
    while counter(server.url) < 1:
        assert time.monotonic() < deadline, "the stalled subscriber was never closed"
        time.sleep(0.05)  # a polling period
    closed_after_s = time.monotonic() - t0
    print(f"\nclosed {closed_after_s:.1f} s after it stopped reading")
    assert closed_after_s < 20  # the ping timeout would take 35-40 s

    close = stalled.read_to_the_end()
    assert close is not None and close.code == 1013
    assert "too slow" in close.reason and "since" in close.reason
    warnings = [r for r in caplog.records if "cannot keep up" in r.getMessage()]
    assert len(warnings) == 1 and warnings[0].levelno == logging.WARNING

    held: dict = {}
    for delta in stalled.deltas:
        apply(held, delta)
    last_seq = stalled.deltas[-1]["seq"]
    stats = httpx.get(f"{server.url}/v1/sessions/{sid}", timeout=10).json()
    assert last_seq < stats["update_seq"]  # it really fell behind
    resumed = asyncio.run(resume(updates, held, last_seq, stats["update_seq"]))
    objects = httpx.get(f"{server.url}/v1/sessions/{sid}/objects", timeout=10).json()
    assert resumed == {o["id"]: o["version"] for o in objects}
