"""A keyframe's ack names the places the living map doubts (docs/protocol.md, `doubted`),
through a real server on loopback: after a keyframe sees through a confirmed mug's place,
its ack holds that place (centre, radius, t_ready); before, the list is empty; a session
without negative evidence never sends the field."""

from __future__ import annotations

import asyncio

import httpx
import numpy as np
import pytest
from analytic_world import Rect
from devices import frame_message, stream_in_step

pytestmark = pytest.mark.timeout(120)

WALL = Rect(9, "whiteboard", -3.0, -2.0, 3.0, 2.0, 3.0)
MUG = Rect(1, "mug", -0.5, -0.2, -0.3, 0.0, 2.0)
KNOBS = {"keyframe_interval": 1, "min_observations": 2, "min_mapping_bbox_area": 100}
LATER_T = 600.0


def acks_of_a_mug_taken_away(server, **knobs) -> list[dict]:
    """Three frames with the mug, then one (ten minutes later) of the wall where it stood."""
    frames = [frame_message([WALL, MUG], seq, cam_xy=(0.05 * seq, 0.0), t=seq) for seq in range(3)]
    frames.append(frame_message([WALL], 3, t=LATER_T))
    with httpx.Client(base_url=server.url) as client:
        body = {"knobs": {**KNOBS, **knobs}}
        sid = client.post("/v1/sessions", json=body).json()["session_id"]
    replies = asyncio.run(stream_in_step(f"{server.ws_url}/v1/sessions/{sid}/stream", frames))
    assert [r["type"] for r in replies] == ["ack"] * len(frames)
    return replies


def test_the_ack_of_a_keyframe_that_sees_through_a_place_names_it(live_server):
    acks = acks_of_a_mug_taken_away(live_server())
    assert [a["doubted"] for a in acks[:3]] == [[], [], []]
    (place,) = acks[3]["doubted"]
    np.testing.assert_allclose(place[:3], [-0.4, -0.1, 2.0], atol=0.05)
    assert 0.0 < place[3] < 0.2
    assert place[4] > LATER_T  # the evidence must span removal_min_span_s from its first


def test_without_negative_evidence_the_ack_has_no_doubted_places(live_server):
    acks = acks_of_a_mug_taken_away(live_server(), negative_evidence=False)
    assert all("doubted" not in a for a in acks)
