"""LQ = SQ for questions about how things stand, end to end (docs/evaluation.md "Relations"):
a real server on loopback holds a room of duplicate categories in distinct relations
(imported), the device's local map is fed by the server's own update messages, and every
relational question is answered by the server (SQ, asked from where the device stands) and by
the local map (LQ, the link down) with the same top-1, relation kind, anchors and `match`,
degrees within 0.02."""

from __future__ import annotations

import asyncio
import json
import math

import pytest
from device_room import NEGATIVES, QUESTIONS, TO_Y_UP, VIEWER, room_export

from app.client import SessionApi
from app.client.rest import import_map
from app.config import Knobs, updated_knobs
from client_sim.querying import LQ, SQ, QueryRouter
from client_sim.streaming import DeviceClient

pytestmark = [pytest.mark.slow, pytest.mark.timeout(240)]

DEGREE_TOLERANCE = 0.02


@pytest.mark.parametrize("y_up", [False, True], ids=["z-up", "y-up session"])
def test_relational_questions_get_the_same_answer_from_the_server_and_the_local_map(
    live_server, encoder, y_up
):
    server = live_server()
    export = room_export(y_up)
    where = TO_Y_UP @ VIEWER if y_up else VIEWER

    async def scenario():
        created = await import_map(server.url, json.dumps(export).encode())
        sid, token = created["session_id"], created["token"]
        knobs = updated_knobs(Knobs(), created["knobs"])
        device = DeviceClient(server.url, sid, token, knobs=knobs)
        following = asyncio.create_task(device.follow_updates())
        try:
            async with SessionApi(server.url, sid, token) as api:
                seq = (await api.fetch()).update_seq
            assert await device.wait_synced(seq, 30), f"local seq {device.local_map.seq} < {seq}"
            assert len(device.local_map) == len(export["objects"])
            device.local_map.set_user_position(where)  # where the device stands
            link = {"rtt_ms": 1.0}
            router = QueryRouter(
                server.url, sid, token, device.local_map, encoder,
                rtt_ms=lambda: link["rtt_ms"], server_timeout_s=30.0,
            )  # fmt: skip
            answers = []
            async with router:
                for text in QUESTIONS:  # the same router, its link up, then down
                    link["rtt_ms"] = 1.0
                    server_answer = await router.query(text, k=5)
                    link["rtt_ms"] = math.inf
                    answers.append((text, server_answer, await router.query(text, k=5)))
            assert router.up == ("+y" if y_up else "+z")  # the record's, read while online
            return answers
        finally:
            await device.stop()
            await asyncio.wait_for(following, 15)

    for text, sq, lq in asyncio.run(scenario()):
        assert (sq.mode, lq.mode) == (SQ, LQ), text
        assert sq.results and lq.results, text
        server_best, device_best = sq.results[0], lq.results[0]
        assert server_best["relation"] is not None, f"{text}: the server answered it as plain"
        assert device_best["id"] == server_best["id"], (text, sq.results, lq.results)
        assert device_best["relation"]["kind"] == server_best["relation"]["kind"], text
        assert device_best["relation"]["anchors"] == server_best["relation"]["anchors"], text
        assert device_best["relation"]["degree"] == pytest.approx(
            server_best["relation"]["degree"], abs=DEGREE_TOLERANCE
        ), text
        assert lq.match == sq.match == (text not in NEGATIVES), text
