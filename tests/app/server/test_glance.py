"""A glance is enough (docs/evaluation.md "Targets"), through a real server on loopback: a plain v1
client sends every frame whole, the server maps one in five (keyframe_interval 5) and counts
the detections of the others as sightings, so an object in clear view for 8 frames (about
1.5 s at 5 fps) is confirmed and published, while a detection of one frame never is. The
same holds for our device with the sightings extension (it sends only the keyframes
whole)."""

from __future__ import annotations

import asyncio

import httpx
import msgpack
import pytest
import websockets
from analytic_world import Rect, RectSource
from devices import TIMEOUT_S, frame_message, stream, stream_in_step

from app.client import SessionApi
from app.config import Knobs, updated_knobs
from app.protocol import SIGHTINGS_SUBPROTOCOL
from client_sim.encoder import FrameEncoder
from client_sim.streaming import DeviceClient, DeviceStats

pytestmark = pytest.mark.timeout(120)

CHAIR = Rect(1, "chair", -0.6, -0.3, -0.1, 0.3, 2.0)
MUG = Rect(2, "mug", 0.2, -0.1, 0.4, 0.1, 1.5)
VASE = Rect(3, "vase", 0.5, 0.2, 0.7, 0.4, 1.8)
FRAMES = 30
KNOBS = {"keyframe_interval": 5, "min_observations": 3, "min_mapping_bbox_area": 100}


def sweep(scene) -> list[dict]:
    """Whole v1 frames of a slow sideways sweep; scene(seq) -> the rectangles in view."""
    return [frame_message(scene(seq), seq, cam_xy=(0.005 * seq, 0.0)) for seq in range(FRAMES)]


def stream_to_new_session(server, frames: list[dict]) -> tuple[list[str], list[str]]:
    """Stream the frames one at a time (each waits for its ack); returns the labels of the
    confirmed objects (REST) and of everything a subscriber from the start receives."""
    with httpx.Client(base_url=server.url) as client:
        sid = client.post("/v1/sessions", json={"knobs": KNOBS}).json()["session_id"]
        replies = asyncio.run(stream_in_step(f"{server.ws_url}/v1/sessions/{sid}/stream", frames))
        assert [r["type"] for r in replies] == ["ack"] * len(frames)
        confirmed = sorted(o["label"] for o in client.get(f"/v1/sessions/{sid}/objects").json())

    async def subscribe() -> list[str]:
        async with websockets.connect(f"{server.ws_url}/v1/sessions/{sid}/updates?since=0") as ws:
            delta = msgpack.unpackb(await asyncio.wait_for(ws.recv(), TIMEOUT_S))
        return sorted(u["label"] for u in delta["upserts"])

    return confirmed, asyncio.run(subscribe())


@pytest.mark.parametrize("start", [6, 8])
def test_an_object_in_view_for_8_frames_of_a_sweep_is_confirmed_and_published(live_server, start):
    # one or two keyframes see the mug (seq 10, and 5 or 15 with a start of 6 or 8)
    frames = sweep(lambda seq: [CHAIR, MUG] if start <= seq < start + 8 else [CHAIR])
    confirmed, published = stream_to_new_session(live_server(), frames)
    assert confirmed == ["chair", "mug"]
    assert published == ["chair", "mug"]


@pytest.mark.parametrize("seq_of_vase", [10, 12])
def test_a_one_frame_detection_is_never_published(live_server, seq_of_vase):
    # on a keyframe (a candidate is made) or between two (only a sighting)
    frames = sweep(lambda seq: [CHAIR, VASE] if seq == seq_of_vase else [CHAIR])
    confirmed, published = stream_to_new_session(live_server(), frames)
    assert confirmed == ["chair"]
    assert published == ["chair"]


# --- the sightings extension: keyframes whole, sightings between them ----------------------


def stream_with_sightings(server, scene) -> tuple[list[str], DeviceStats]:
    """Our device, offering the sightings extension, plays the same sweep; returns the
    confirmed labels and the device's counters."""

    async def scenario():
        sid, token, answer = await DeviceClient.create_session(server.url, knobs=KNOBS)
        knobs = updated_knobs(Knobs(), answer["knobs"])
        device = DeviceClient(server.url, sid, token, knobs=knobs, on_log=lambda _: None)
        source = RectSource(scene, FRAMES, step_m=0.005)
        stats = await device.stream(source, fps=None, max_in_flight=1)
        async with SessionApi(server.url, sid, token) as api:
            objects = await api.objects()
        return sorted(o["label"] for o in objects), stats

    return asyncio.run(scenario())


def test_with_the_sightings_extension_a_glance_is_still_enough(live_server):
    confirmed, stats = stream_with_sightings(
        live_server(), lambda seq: [CHAIR, MUG] if 6 <= seq < 14 else [CHAIR]
    )
    assert confirmed == ["chair", "mug"]
    # the device sent 1 frame in 5 whole (the keyframes, all mapped), sightings between
    assert stats.frames_sent == FRAMES and stats.errors == 0
    assert stats.keyframes_acked == FRAMES // KNOBS["keyframe_interval"]
    assert stats.sightings_sent == FRAMES - stats.keyframes_acked


def test_with_the_sightings_extension_a_one_frame_detection_is_never_published(live_server):
    confirmed, _ = stream_with_sightings(
        live_server(), lambda seq: [CHAIR, VASE] if seq == 12 else [CHAIR]
    )
    assert confirmed == ["chair"]


def test_a_sighting_on_a_socket_that_did_not_negotiate_the_extension_is_refused(live_server):
    server = live_server()
    frame = RectSource([CHAIR], 2).frame(1)
    sighting = FrameEncoder(2).encode_source_frame_as_sighting(frame).message
    with httpx.Client(base_url=server.url) as client:
        sid = client.post("/v1/sessions", json={"knobs": KNOBS}).json()["session_id"]
    url = f"{server.ws_url}/v1/sessions/{sid}/stream"
    (reply,) = asyncio.run(stream(url, [sighting]))
    assert reply["type"] == "error" and reply["code"] == "bad_frame" and reply["seq"] == 1
    assert SIGHTINGS_SUBPROTOCOL in reply["message"]
