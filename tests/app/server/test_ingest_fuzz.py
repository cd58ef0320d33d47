"""Mutation fuzzing of the frame socket through a real uvicorn: whatever a frame holds, it
gets exactly one answer, errors name a field, and the map only ever holds finite geometry.

Each mutated frame is a valid one with 1-3 fields deleted, retyped, truncated or bit-flipped
(a deterministic generator: a failure names its seed and index). This is how a bit-flipped
pose lifting to points beyond float32 was found.
"""

from __future__ import annotations

import asyncio
import copy
import random
import re

import httpx
import msgpack
import numpy as np
import pytest
import websockets
from analytic_world import Rect, RectSource
from devices import TIMEOUT_S, frame_message

from app.config import Knobs
from app.mapping.validation import MAX_WORLD_M
from app.protocol import SIGHTINGS_SUBPROTOCOL
from client_sim.encoder import FrameEncoder

pytestmark = pytest.mark.timeout(180)

CHAIR = Rect(1, "chair", -0.6, -0.3, -0.1, 0.3, 2.0)
TABLE = Rect(2, "table", 0.1, -0.4, 0.9, 0.2, 2.4)
JUNK = [None, True, -1, 0, 2**63 - 1, -(2**63), 1e308, float("nan"), float("inf"), "", "x" * 300]
JUNK += [b"", b"\x00" * 10, [], {}, [1, 2, 3], {"a": 1}, 3.5, "frame"]
FIELD = re.compile(r"^[a-z_]+(\.[a-z_]+|\[\d+\])*(\.[a-z_]+)*: ")


def _paths(obj, prefix=()):
    if isinstance(obj, dict):
        for key, value in obj.items():
            yield (*prefix, key)
            yield from _paths(value, (*prefix, key))
    elif isinstance(obj, list):
        for i, value in enumerate(obj[:3]):
            yield (*prefix, i)
            yield from _paths(value, (*prefix, i))


def _mutate(message: dict, rng: random.Random) -> dict:
    out = copy.deepcopy(message)
    paths = list(_paths(out))
    for _ in range(rng.randint(1, 3)):
        path = rng.choice(paths)
        parent = out
        try:
            for key in path[:-1]:
                parent = parent[key]
            value = parent[path[-1]]
            roll = rng.random()
            if roll < 0.3 and isinstance(parent, dict):
                del parent[path[-1]]
            elif roll < 0.7 and isinstance(value, bytes) and value:
                flipped = bytearray(value)
                for _ in range(rng.randint(1, 4)):
                    flipped[rng.randrange(len(flipped))] ^= 1 << rng.randrange(8)
                cut = rng.randint(0, len(flipped)) if rng.random() < 0.3 else len(flipped)
                parent[path[-1]] = bytes(flipped[:cut])
            else:
                parent[path[-1]] = rng.choice(JUNK)
        except (KeyError, IndexError, TypeError):
            pass  # an earlier mutation removed the way there
    return out


@pytest.mark.parametrize("seed", [0, 1])
def test_every_mutated_frame_gets_one_answer_and_the_map_stays_finite(live_server, seed):
    server = live_server(max_bad_frames=10**6)
    valid = [frame_message([CHAIR, TABLE], seq, cam_xy=(0.03 * seq, 0.0)) for seq in range(4)]
    rng = random.Random(seed)
    with httpx.Client(base_url=server.url) as c:
        knobs = {"keyframe_interval": 1, "min_observations": 1, "min_mapping_bbox_area": 100}
        sid = c.post("/v1/sessions", json={"knobs": knobs}).json()["session_id"]

        async def run() -> list[tuple[int, dict]]:
            answers = []
            url = f"{server.ws_url}/v1/sessions/{sid}/stream"
            async with websockets.connect(url, max_size=None) as ws:
                for i in range(300):
                    message = _mutate(valid[i % len(valid)], rng)
                    await ws.send(msgpack.packb(message))
                    answer = msgpack.unpackb(await asyncio.wait_for(ws.recv(), TIMEOUT_S))
                    answers.append((i, answer))
                for message in valid:  # still serving, and still mapping
                    await ws.send(msgpack.packb(message))
                    answers.append(
                        (-1, msgpack.unpackb(await asyncio.wait_for(ws.recv(), TIMEOUT_S)))
                    )
            return answers

        answers = asyncio.run(run())
        objects = c.get(f"/v1/sessions/{sid}/objects", params={"points": "true"}).json()

    for i, answer in answers:
        assert answer["type"] in ("ack", "error"), (seed, i, answer)
        if answer["type"] == "error":
            assert answer["code"] == "bad_frame" and FIELD.match(answer["message"]), (
                seed,
                i,
                answer,
            )
    assert all(answer["type"] == "ack" for i, answer in answers if i < 0)
    assert sum(answer["type"] == "error" for _, answer in answers) > 100  # the fuzzer bites
    assert {o["label"] for o in objects} >= {"chair", "table"}
    for obj in objects:
        assert np.isfinite(obj["bbox"]).all() and np.isfinite(obj["points"]).all(), obj["id"]
        # A bit-flipped pose may still be a plausible one; never one beyond the world's edge.
        assert np.abs(obj["bbox"]).max() <= MAX_WORLD_M + Knobs().max_depth_m, obj["bbox"]


def test_every_mutated_sighting_gets_one_answer_and_the_map_stays_finite(live_server):
    # the sightings extension: a whole frame (a keyframe), then sightings, all mutated
    server = live_server(max_bad_frames=10**6)
    source = RectSource([CHAIR, TABLE], 4, step_m=0.03)
    valid = [frame_message([CHAIR, TABLE], 0)] + [
        FrameEncoder(2).encode_source_frame_as_sighting(source.frame(seq)).message
        for seq in range(1, 4)
    ]
    rng = random.Random(2)
    with httpx.Client(base_url=server.url) as c:
        knobs = {"min_observations": 2, "min_mapping_bbox_area": 100}
        sid = c.post("/v1/sessions", json={"knobs": knobs}).json()["session_id"]

        async def run() -> list[tuple[int, dict]]:
            answers = []
            url = f"{server.ws_url}/v1/sessions/{sid}/stream"
            async with websockets.connect(
                url, max_size=None, subprotocols=[SIGHTINGS_SUBPROTOCOL]
            ) as ws:
                assert ws.subprotocol == SIGHTINGS_SUBPROTOCOL
                for i in range(200):
                    message = _mutate(valid[i % len(valid)], rng)
                    await ws.send(msgpack.packb(message))
                    answers.append(
                        (i, msgpack.unpackb(await asyncio.wait_for(ws.recv(), TIMEOUT_S)))
                    )
                for message in valid * 2:  # still serving, and still mapping
                    await ws.send(msgpack.packb(message))
                    answers.append(
                        (-1, msgpack.unpackb(await asyncio.wait_for(ws.recv(), TIMEOUT_S)))
                    )
            return answers

        answers = asyncio.run(run())
        objects = c.get(f"/v1/sessions/{sid}/objects", params={"points": "true"}).json()

    for i, answer in answers:
        assert answer["type"] in ("ack", "error"), (i, answer)
        if answer["type"] == "error":
            assert answer["code"] == "bad_frame" and FIELD.match(answer["message"]), (i, answer)
    assert all(answer["type"] == "ack" for i, answer in answers if i < 0)
    assert sum(answer["type"] == "error" for _, answer in answers) > 50  # the fuzzer bites
    assert {o["label"] for o in objects} >= {"chair", "table"}
    for obj in objects:
        assert np.isfinite(obj["bbox"]).all() and np.isfinite(obj["points"]).all(), obj["id"]
