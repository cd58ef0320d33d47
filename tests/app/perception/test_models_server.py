"""A server with `--perception models` maps frames sent without detections and answers a
query through the normal protocol (tiny random models: plumbing, not quality)."""

from __future__ import annotations

import asyncio

import httpx
import pytest
from analytic_world import Rect
from devices import frame_message, stream_in_step

from app.perception.models.tiny import TINY_PREFIX
from app.perception.models.weights import CPU_PROFILE

pytestmark = [pytest.mark.timeout(180), pytest.mark.slow]

SCENE = [
    Rect(1, "chair", -0.6, -0.3, -0.1, 0.3, 2.0),
    Rect(2, "table", 0.1, -0.2, 0.7, 0.4, 2.6),
    Rect(3, "wall", -3.0, -3.0, 3.0, 3.0, 4.0),
]
KNOBS = {"keyframe_interval": 1, "min_observations": 1, "min_mapping_bbox_area": 16}


def frame_without_detections(seq: int) -> dict:
    message = frame_message(SCENE, seq, cam_xy=(0.02 * seq, 0.0))
    del message["detections"]  # what a real headset sends: RGB, depth and pose only
    return message


@pytest.mark.parametrize("mode", ["semanticxr", "baseline"])
def test_a_models_session_maps_frames_without_detections_and_answers_a_query(
    live_server, tiny_models_dir, mode
):
    server = live_server(perception="models", models_dir=tiny_models_dir)
    created = httpx.post(
        f"{server.url}/v1/sessions", json={"mode": mode, "knobs": KNOBS}, timeout=30
    ).json()
    embedding = {"model": TINY_PREFIX + CPU_PROFILE.embedder.folder, "dim": 32}
    assert created["embedding"] == embedding  # the session announces CLIP's text tower
    sid = created["session_id"]

    frames = [frame_without_detections(seq) for seq in range(3)]
    replies = asyncio.run(stream_in_step(f"{server.ws_url}/v1/sessions/{sid}/stream", frames))
    assert [r["type"] for r in replies] == ["ack"] * 3

    stats = httpx.get(f"{server.url}/v1/sessions/{sid}", timeout=10).json()
    assert (stats["perception"], stats["keyframes"]) == ("models", 3)
    assert stats["objects"] > 0 and stats["embedding"] == embedding
    answer = httpx.get(
        f"{server.url}/v1/sessions/{sid}/query", params={"text": "a chair", "k": 3}, timeout=30
    )
    assert answer.status_code == 200 and answer.json()["results"]
