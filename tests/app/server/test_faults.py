"""A full disk, for real: the server under a file-size limit refuses keyframes, says so, shows
only what it saved, recovers without a restart, and a kill -9 after it loses nothing shown.

`prlimit --fsize=N:unlimited` makes every write past N bytes in any file fail with EFBIG (CPython
ignores SIGXFSZ), as a full disk fails writes. In WAL mode SQLite first appends to the WAL;
when the WAL cannot grow the store folds it into the database and retries, so keyframes are
refused only once the database file itself cannot take the map (about N bytes of objects).
"""

from __future__ import annotations

import asyncio
import subprocess

import httpx
import msgpack
import pytest
import websockets
from analytic_world import Rect
from devices import TIMEOUT_S, frame_message

from app.server.runner import ServerProcess, free_port

pytestmark = [pytest.mark.slow, pytest.mark.timeout(120)]

FILE_SIZE_LIMIT_BYTES = 128 << 10
"""Above a fresh store (4 KiB database, ~40 KiB WAL) and the server's log; the map of the
row below outgrows it within a few dozen keyframes."""
ROW = [Rect(i + 1, f"thing {i}", 0.5 * i, -0.5, 0.5 * i + 0.4, 0.5, 2.0) for i in range(400)]
"""A long row of distinct objects: a camera sliding along it keeps adding new ones."""
KNOBS = {
    "keyframe_interval": 1,
    "min_observations": 1,
    "min_mapping_bbox_area": 100,
    "local_map_update_frequency": 1,
}
STEP_M = 0.25


def frame(index: int) -> bytes:
    cam_x = STEP_M * index
    in_view = [r for r in ROW if r.x1 > cam_x - 1.5 and r.x0 < cam_x + 1.5]
    return msgpack.packb(frame_message(in_view, index, cam_xy=(cam_x, 0.0)))


class Subscriber:
    """Follows a session's updates, holding {id: version} and the last seq applied."""

    def __init__(self, url: str, since: int | None = None):
        self.url, self.seq = url, since
        self.held: dict[int, int] = {}

    async def follow(self, until_seq: int | None = None) -> None:
        """Apply deltas until the socket closes (or seq >= until_seq)."""
        query = "" if self.seq is None else f"?since={self.seq}"
        try:
            async with websockets.connect(self.url + query, max_size=None) as ws:
                async for raw in ws:
                    delta = msgpack.unpackb(raw)
                    if delta["full"]:
                        self.held = {}
                    self.held.update({u["id"]: u["version"] for u in delta["upserts"]})
                    for oid in delta["removed"]:
                        self.held.pop(oid, None)
                    self.seq = delta["seq"]
                    if until_seq is not None and self.seq >= until_seq:
                        return
        except websockets.ConnectionClosed:
            return


async def wait_for(condition, timeout_s: float = TIMEOUT_S) -> None:
    async with asyncio.timeout(timeout_s):
        while not await condition():
            await asyncio.sleep(0.1)  # polling a server that offers nothing to wait on


def the_map(objects: list[dict]) -> dict[int, int]:
    return {o["id"]: o["version"] for o in objects}


def persist_failures(metrics: str) -> float:
    line = next(
        x for x in metrics.splitlines() if x.startswith("semanticxr_persist_failures_total ")
    )
    return float(line.split()[1])


def test_a_full_disk_refuses_keyframes_shows_only_what_was_saved_and_recovers(tmp_path):
    asyncio.run(full_disk_scenario(tmp_path))


async def full_disk_scenario(tmp_path) -> None:
    port = free_port()
    server = ServerProcess(
        tmp_path,
        port,
        log_level="info",
        prefix=["prlimit", f"--fsize={FILE_SIZE_LIMIT_BYTES}:unlimited", "--"],
    )
    await asyncio.to_thread(server.start)
    try:
        async with httpx.AsyncClient(base_url=server.url, timeout=TIMEOUT_S) as rest:
            created = await rest.post("/v1/sessions", json={"name": "full", "knobs": KNOBS})
            sid = created.json()["session_id"]
            updates_url = f"{server.ws_url}/v1/sessions/{sid}/updates"
            live = Subscriber(updates_url)
            following = asyncio.create_task(live.follow())
            async with websockets.connect(f"{server.ws_url}/v1/sessions/{sid}/stream") as ws:
                index = 0

                async def send() -> dict:
                    nonlocal index
                    await ws.send(await asyncio.to_thread(frame, index))
                    index += 1
                    return msgpack.unpackb(await asyncio.wait_for(ws.recv(), TIMEOUT_S))

                # Stream until the disk is full.
                while (reply := await send())["type"] == "ack":
                    assert index < 200, "the file-size limit never hit"
                assert reply["code"] == "storage_unavailable", reply
                assert "retry later" in reply["message"]
                assert index > 3  # the map had grown before the limit hit
                # A subscriber that stops here, in the middle of the failure streak.
                stopped = Subscriber(updates_url)
                await stopped.follow(
                    until_seq=(await rest.get(f"/v1/sessions/{sid}")).json()["update_seq"]
                )

                health = await rest.get("/healthz")
                assert health.status_code == 503, health.text
                assert health.json()["status"] == "unavailable" and health.json()["reason"]
                assert int(health.headers["retry-after"]) >= 1
                assert persist_failures((await rest.get("/metrics")).text) >= 1
                # While the disk stays full every keyframe is refused; queries still answer.
                seq_durable = (await rest.get(f"/v1/sessions/{sid}")).json()["update_seq"]
                for _ in range(3):
                    assert (await send())["code"] == "storage_unavailable"
                assert (await rest.get(f"/v1/sessions/{sid}")).json()["update_seq"] == seq_durable
                query = await rest.get(f"/v1/sessions/{sid}/query", params={"text": "thing"})
                assert query.status_code == 200 and query.json()["results"]
                assert (await rest.get("/healthz")).status_code == 503
                assert server.output().count("storage failing") == 1  # one ERROR a streak

                # Room again: the periodic probe notices without a keyframe; keyframes map.
                await asyncio.to_thread(
                    subprocess.run,
                    ["prlimit", "--pid", str(server.pid), "--fsize=unlimited:unlimited"],
                    check=True,
                )

                async def healthy() -> bool:
                    return (await rest.get("/healthz")).status_code == 200

                await wait_for(healthy)
                assert "storage recovered" in server.output()
                for _ in range(5):
                    reply = await send()
                    assert reply["type"] == "ack" and reply["keyframe"], reply

            seq = (await rest.get(f"/v1/sessions/{sid}")).json()["update_seq"]
            assert seq > seq_durable

            async def caught_up() -> bool:
                return live.seq is not None and live.seq >= seq

            await wait_for(caught_up)
            shown = the_map((await rest.get(f"/v1/sessions/{sid}/objects")).json())
            assert live.held == shown  # the subscriber holds exactly the server's map

        await asyncio.to_thread(server.kill9)
        following.cancel()
        server = ServerProcess(tmp_path, port)
        await asyncio.to_thread(server.start)
        async with httpx.AsyncClient(base_url=server.url, timeout=TIMEOUT_S) as rest:
            after = the_map((await rest.get(f"/v1/sessions/{sid}/objects")).json())
            assert after == shown  # ids and versions: exactly what was shown before the crash
            assert (await rest.get(f"/v1/sessions/{sid}")).json()["update_seq"] == seq
        for subscriber in (stopped, live):  # each resumes from its last seq
            await subscriber.follow(until_seq=seq)
            assert subscriber.held == after
    finally:
        await asyncio.to_thread(server.stop)
