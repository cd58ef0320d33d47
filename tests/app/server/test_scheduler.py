"""Fairness (docs/architecture.md, "Fairness"): mapping work is round-robin across sessions with a
pending keyframe; no session waits behind more than one keyframe of each other session."""

from __future__ import annotations

import asyncio
import itertools
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import httpx
import msgpack
import pytest
import websockets
from analytic_world import Rect
from devices import frame_message

from app.perception import BACKENDS
from app.perception.detections import DetectionsBackend
from app.server.scheduler import RoundRobinScheduler

pytestmark = pytest.mark.timeout(120)


def assert_round_robin(order: list[str], keys: set[str]) -> None:
    """Between two consecutive turns of one key, every other key had at most one turn."""
    for key in keys:
        turns = [i for i, k in enumerate(order) if k == key]
        for a, b in itertools.pairwise(turns):
            between = order[a + 1 : b]
            assert all(between.count(k) <= 1 for k in keys - {key}), (key, between, order)


async def run_sessions(scheduler, jobs_per_key: dict[str, int], slow: dict[str, threading.Event]):
    """Each key runs its jobs one after another (as a session's map loop does); returns the
    order in which jobs started."""
    started: list[str] = []

    def job(key: str) -> None:
        started.append(key)
        if key in slow:
            assert slow[key].wait(30)

    async def session(key: str) -> None:
        for _ in range(jobs_per_key[key]):
            await scheduler.run(key, job, key)

    await asyncio.gather(*(session(k) for k in jobs_per_key))
    return started


def test_one_worker_serves_waiting_keys_in_turn():
    with ThreadPoolExecutor(1) as pool:
        order = asyncio.run(run_sessions(RoundRobinScheduler(pool, 1), dict(a=5, b=3, c=4), {}))
    assert order[:9] == ["a", "b", "c"] * 3
    assert_round_robin(order, {"a", "b", "c"})


def test_a_slow_key_holds_one_worker_while_the_others_take_turns_on_the_rest():
    gate = threading.Event()

    async def scenario() -> list[str]:
        with ThreadPoolExecutor(2) as pool:
            scheduler = RoundRobinScheduler(pool, 2)
            slow = asyncio.create_task(run_sessions(scheduler, {"slow": 1}, {"slow": gate}))
            while "slow" not in scheduler._running:  # noqa: ASYNC110 - the slow job took its worker
                await asyncio.sleep(0.001)
            order = await run_sessions(scheduler, dict(a=4, b=4), {})  # all done, gate still shut
            gate.set()
            await slow
            return order

    assert asyncio.run(scenario()) == ["a", "b"] * 4


def test_a_key_never_runs_two_jobs_at_once_and_a_cancelled_wait_gives_its_turn_away():
    async def scenario() -> list[str]:
        with ThreadPoolExecutor(2) as pool:
            scheduler = RoundRobinScheduler(pool, 2)
            gate = threading.Event()
            first = asyncio.create_task(scheduler.run("a", gate.wait, 30))
            await asyncio.sleep(0)
            second = asyncio.create_task(scheduler.run("a", lambda: "second"))
            await asyncio.sleep(0.05)
            assert not second.done() and scheduler.waiting == ["a"]  # a free worker, yet waits
            second.cancel()
            await asyncio.sleep(0)
            assert scheduler.waiting == []
            gate.set()
            await first
            return [await scheduler.run("b", lambda: "b")]

    assert asyncio.run(scenario()) == ["b"]


# ---------------------------------------------------------------- through the real server
SESSION_OF_SEQ = 1000
"""Frames of session i carry seqs from i * SESSION_OF_SEQ: the backend tells sessions apart."""


class PacedBackend(DetectionsBackend):
    """The device's detections after a pause; session 0's keyframes are the slow ones."""

    name = "paced"

    def __init__(self) -> None:
        self.order: list[int] = []
        self._lock = threading.Lock()

    def detect(self, frame, sent):
        session = frame.seq // SESSION_OF_SEQ
        with self._lock:
            self.order.append(session)
        time.sleep(0.4 if session == 0 else 0.1)  # mapping work made slow honestly: it waits
        return super().detect(frame, sent)


@pytest.fixture
def paced(monkeypatch) -> list[PacedBackend]:
    made: list[PacedBackend] = []

    def factory(options=None) -> PacedBackend:
        made.append(PacedBackend())
        return made[-1]

    monkeypatch.setitem(BACKENDS, "paced", factory)
    return made


async def keep_streaming(url: str, first_seq: int, frames: int) -> list[dict]:
    """A device sending every 30 ms whatever comes back (it always has a keyframe waiting)."""
    chair = Rect(1, "chair", -0.6, -0.3, -0.1, 0.3, 2.0)
    messages = [msgpack.packb(frame_message([chair], first_seq + i)) for i in range(frames)]
    async with websockets.connect(url, max_size=None) as ws:

        async def send_all() -> None:
            for message in messages:
                await ws.send(message)
                await asyncio.sleep(0.03)  # the device's frame period

        sender = asyncio.create_task(send_all())
        replies = [msgpack.unpackb(await asyncio.wait_for(ws.recv(), 60)) for _ in messages]
        await sender
        return replies


def test_sessions_take_turns_mapping_and_a_slow_one_delays_nobody_more_than_one_keyframe(
    live_server, paced
):
    server = live_server(perception="paced", mapping_workers=1)
    knobs = {"keyframe_interval": 1, "min_observations": 1, "min_mapping_bbox_area": 100}
    urls = []
    for _ in range(3):
        sid = httpx.post(f"{server.url}/v1/sessions", json={"knobs": knobs}, timeout=10).json()
        urls.append(f"{server.ws_url}/v1/sessions/{sid['session_id']}/stream")

    async def three() -> list[list[dict]]:
        return await asyncio.gather(
            *(keep_streaming(url, i * SESSION_OF_SEQ, 60) for i, url in enumerate(urls))
        )

    replies = asyncio.run(three())
    (backend,) = paced
    order = [str(s) for s in backend.order]
    while_all_stream = order[: len(order) * 2 // 3]  # before any device has stopped sending
    assert all(while_all_stream.count(s) >= 2 for s in "012"), order  # turns to compare
    assert_round_robin(while_all_stream, {"0", "1", "2"})
    for session in replies:  # every frame answered: mapped, or dropped for a newer one
        assert all(r["type"] == "ack" for r in session)
        assert any(r["keyframe"] for r in session)
