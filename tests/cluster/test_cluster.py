"""Map shards on Ray behind two gateways: routing, relaying, and shard failures that lose
nothing acknowledged (docs/architecture.md "Many devices")."""

from __future__ import annotations

import asyncio
import os
import signal

import httpx
import msgpack
import pytest
import websockets
from analytic_world import Rect
from conftest import poll
from devices import frame_message

pytestmark = [pytest.mark.cluster, pytest.mark.slow, pytest.mark.timeout(300)]

SCENE = [
    Rect(1, "chair", -0.6, -0.3, -0.1, 0.3, 2.0),
    Rect(2, "refrigerator", 0.1, -0.8, 0.9, 0.8, 2.5),
]
LAMP = Rect(3, "lamp", -1.2, -0.9, -0.8, -0.4, 2.2)
KNOBS = {
    "keyframe_interval": 1,
    "min_observations": 2,
    "min_mapping_bbox_area": 100,
    "local_map_update_frequency": 1,
}
REPLY_TIMEOUT_S = 60.0
"""Longest one frame's reply may take, a failover included (lease + claim + reload)."""


def create(gateway_url: str, name: str) -> str:
    answer = httpx.post(
        f"{gateway_url}/v1/sessions", json={"name": name, "knobs": KNOBS}, timeout=60
    )
    assert answer.status_code == 201, answer.text
    return answer.json()["session_id"]


def objects(gateway_url: str, sid: str) -> dict[int, str]:
    answer = httpx.get(f"{gateway_url}/v1/sessions/{sid}/objects", timeout=60)
    assert answer.status_code == 200, answer.text
    return {o["id"]: o["label"] for o in answer.json()}


def stats(gateway_url: str, sid: str) -> dict:
    answer = httpx.get(f"{gateway_url}/v1/sessions/{sid}", timeout=60)
    assert answer.status_code == 200, answer.text
    return answer.json()


async def send(ws, message: dict) -> dict:
    await ws.send(msgpack.packb(message))
    return msgpack.unpackb(await asyncio.wait_for(ws.recv(), REPLY_TIMEOUT_S))


def failovers(gateway_url: str, kind: str) -> float:
    """How many sockets of `kind` the gateway moved to another shard so far."""
    for line in httpx.get(f"{gateway_url}/gateway/metrics").text.splitlines():
        if line.startswith(f'semanticxr_gateway_failovers_total{{kind="{kind}"}}'):
            return float(line.split()[-1])
    return 0.0


class Follower:
    """An update subscriber: the map it holds and the last seq it applied."""

    def __init__(self) -> None:
        self.held: dict[int, str] = {}
        self.seq = -1

    async def run(self, url: str) -> None:
        async with websockets.connect(url, max_size=None) as sub:
            async for raw in sub:
                delta = msgpack.unpackb(raw)
                if delta["full"]:
                    self.held.clear()
                for up in delta["upserts"]:
                    self.held[up["id"]] = up["label"]
                for oid in delta["removed"]:
                    self.held.pop(oid, None)
                self.seq = delta["seq"]

    async def reach(self, seq: int, task: asyncio.Task) -> None:
        while self.seq < seq:
            if task.done():  # the subscription ended: its socket was closed
                task.result()
                raise AssertionError(f"the subscriber stopped at seq {self.seq}")
            await asyncio.sleep(0.05)


def test_a_session_streamed_through_one_gateway_is_served_by_both(cluster):
    a, b = cluster.gateways
    sid = create(a.url, "two gateways")

    async def walk() -> list[dict]:
        async with websockets.connect(f"{a.ws_url}/v1/sessions/{sid}/stream", max_size=None) as ws:
            return [
                await send(ws, frame_message(SCENE, i, cam_xy=(0.02 * i, 0.0))) for i in range(4)
            ]

    replies = asyncio.run(walk())
    assert [r["type"] for r in replies] == ["ack"] * 4
    assert objects(a.url, sid) == objects(b.url, sid) == {1: "chair", 2: "refrigerator"}
    hits = httpx.get(f"{b.url}/v1/sessions/{sid}/query", params={"text": "a fridge", "k": 1}).json()
    assert hits["results"][0]["label"] == "refrigerator"
    owner, epoch = cluster.owner(sid)
    assert owner in cluster.live_shards() and epoch >= 1
    # the listing and unknown sessions answer through any gateway as a server would
    assert sid in {s["session_id"] for s in httpx.get(f"{b.url}/v1/sessions").json()}
    assert httpx.get(f"{b.url}/v1/sessions/0123456789abcdef").status_code == 404
    assert httpx.get(f"{a.url}/healthz").json()["shards"] == sorted(cluster.live_shards())


@pytest.mark.parametrize("fault", ["kill -9", "SIGSTOP"])
def test_a_shard_failure_mid_stream_loses_nothing_acknowledged(cluster, fault):
    """The owner dies (or hangs) with a keyframe in flight: the device's socket stays up,
    every frame gets exactly one reply, the session moves to a live shard, and a subscriber
    on the other gateway follows it across the move with nothing acknowledged lost. A hung
    shard that wakes up finds its claim gone and drops the session (its writes refused)."""
    cluster.wait_for_shards()
    a, b = cluster.gateways
    sid = create(a.url, f"failure {fault}")
    follower = Follower()

    async def scenario() -> tuple[list[dict], dict[int, str]]:
        async with websockets.connect(f"{a.ws_url}/v1/sessions/{sid}/stream", max_size=None) as ws:
            replies = [
                await send(ws, frame_message(SCENE, i, cam_xy=(0.02 * i, 0.0))) for i in range(4)
            ]
            acked = await asyncio.to_thread(objects, b.url, sid)
            owner, epoch = cluster.owner(sid)
            subscriber = asyncio.create_task(
                follower.run(f"{b.ws_url}/v1/sessions/{sid}/updates?since=0")
            )
            await asyncio.wait_for(follower.reach(0, subscriber), REPLY_TIMEOUT_S)  # connected
            # a keyframe in flight when the owner fails
            await ws.send(msgpack.packb(frame_message([*SCENE, LAMP], 4, cam_xy=(0.1, 0.0))))
            pid = cluster.signal(owner, signal.SIGKILL if fault == "kill -9" else signal.SIGSTOP)
            try:
                replies.append(msgpack.unpackb(await asyncio.wait_for(ws.recv(), REPLY_TIMEOUT_S)))
                await asyncio.to_thread(
                    poll, lambda: cluster.owner(sid)[1] > epoch, REPLY_TIMEOUT_S, "a new claim"
                )
                for i in range(5, 8):
                    frame = frame_message([*SCENE, LAMP], i, cam_xy=(0.02 * i, 0.0))
                    replies.append(await send(ws, frame))
            finally:
                if fault == "SIGSTOP":
                    os.kill(pid, signal.SIGCONT)
            final_seq = (await asyncio.to_thread(stats, b.url, sid))["update_seq"]
            await asyncio.wait_for(follower.reach(final_seq, subscriber), REPLY_TIMEOUT_S)
            subscriber.cancel()
            return replies, acked

    moves_before = failovers(a.url, "stream"), failovers(b.url, "updates")
    replies, acked = asyncio.run(scenario())
    # both sockets moved (the device's and the subscriber's), neither closed
    assert failovers(a.url, "stream") > moves_before[0]
    assert failovers(b.url, "updates") > moves_before[1]
    assert [r["seq"] for r in replies] == list(range(8)), replies
    assert all(r["type"] == "ack" for r in replies), replies
    after = objects(a.url, sid)
    assert acked.items() <= after.items()  # nothing acknowledged before the failure is lost
    assert "lamp" in after.values()  # and mapping went on after it
    assert objects(b.url, sid) == after == follower.held
    if fault == "SIGSTOP":
        owner, _ = cluster.owner(sid)

        def dropped_it() -> bool:
            live = cluster.live_shards()
            return any(
                "semanticxr_sessions_taken_over_total 1.0"
                in httpx.get(f"{url}/metrics", timeout=5).text
                for name, url in live.items()
                if name != owner
            )

        poll(dropped_it, 30, "the woken shard dropped the session it lost")
    cluster.wait_for_shards()


def test_bad_cluster_flags_exit_2_naming_the_flag(tmp_path, pg_url):
    import subprocess
    import sys

    def serve(*flags: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            [sys.executable, "-m", "app.cli", "serve", "--port", "0", *flags],
            capture_output=True,
            text=True,
            timeout=120,
            # Ray Client gives up on an unreachable head after seconds, not its default 30
            env={
                **os.environ,
                "RAY_CLIENT_INITIAL_CONNECTION_TIMEOUT_S": "1",
                "RAY_CLIENT_MAX_CONNECTION_TIMEOUT_S": "2",
            },
        )

    sqlite = serve("--cluster", "auto", "--data-dir", str(tmp_path))
    assert sqlite.returncode == 2 and "--store postgresql://" in sqlite.stderr
    zero = serve("--cluster", "auto", "--shards", "0", "--store", pg_url)
    assert zero.returncode == 2 and "shards" in zero.stderr
    wrong_store = serve("--cluster", "auto", "--store", "postgresql://x:secret@127.0.0.1:1/db")
    assert wrong_store.returncode == 2 and "--store" in wrong_store.stderr
    assert "secret" not in wrong_store.stderr  # the password is not shown
    unreachable = serve("--cluster", "ray://127.0.0.1:1", "--store", pg_url)
    assert unreachable.returncode == 2 and "--cluster ray://127.0.0.1:1" in unreachable.stderr
    gateway = subprocess.run(
        [sys.executable, "-m", "app.cli", "gateway", "--data-dir", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert gateway.returncode == 2 and "--store" in gateway.stderr


def test_the_database_restarting_under_a_stream_loses_nothing_acknowledged(cluster, pg_cluster):
    """PostgreSQL goes down mid-stream: keyframes get storage_unavailable (every frame still
    one reply), the gateway's /healthz says 503 with Retry-After, queries answer from the
    shards' memory; once it is back, the same socket maps again, with nothing acked lost
    and no process restarted."""
    cluster.wait_for_shards()
    a, b = cluster.gateways
    sid = create(a.url, "database restart")

    async def scenario() -> tuple[dict[int, str], list[dict]]:
        async with websockets.connect(f"{a.ws_url}/v1/sessions/{sid}/stream", max_size=None) as ws:
            for i in range(4):
                assert (await send(ws, frame_message(SCENE, i)))["type"] == "ack"
            acked = await asyncio.to_thread(objects, b.url, sid)
            await asyncio.to_thread(pg_cluster.stop)
            try:
                down = await send(ws, frame_message([*SCENE, LAMP], 4))
                health = await asyncio.to_thread(httpx.get, f"{b.url}/healthz")
                assert health.status_code == 503 and "Retry-After" in health.headers
                assert await asyncio.to_thread(objects, a.url, sid) == acked
            finally:
                await asyncio.to_thread(pg_cluster.start)
            replies, seq = [down], 5
            while replies[-1]["type"] != "ack" or not replies[-1]["keyframe"]:
                assert seq < 200, replies[-3:]
                replies.append(await send(ws, frame_message([*SCENE, LAMP], seq)))
                seq += 1
                await asyncio.sleep(0.1)
            return acked, replies

    acked, replies = asyncio.run(scenario())
    assert replies[0]["type"] == "error" and replies[0]["code"] == "storage_unavailable"
    after = objects(a.url, sid)
    assert acked.items() <= after.items()
    poll(lambda: httpx.get(f"{b.url}/healthz").status_code == 200, 30, "the gateway healthy again")
    cluster.wait_for_shards()
