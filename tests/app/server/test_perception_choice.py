"""Perception chosen by settings and per session; backends see keyframes only."""

from __future__ import annotations

import asyncio
import threading

import httpx
import pytest
from analytic_world import Rect
from devices import frame_message, stream_in_step

from app.perception import BACKENDS
from app.perception.detections import DetectionsBackend

pytestmark = pytest.mark.timeout(120)

CHAIR = Rect(1, "chair", -0.6, -0.3, -0.1, 0.3, 2.0)
KNOBS = {"keyframe_interval": 3, "min_observations": 1, "min_mapping_bbox_area": 100}


class CountingBackend(DetectionsBackend):
    """The device's detections, counting the frames it is asked about."""

    name = "counting"

    def __init__(self) -> None:
        self.seqs: list[int] = []
        self._lock = threading.Lock()

    def detect(self, frame, sent):
        with self._lock:
            self.seqs.append(frame.seq)
        return super().detect(frame, sent)


@pytest.fixture
def counting(monkeypatch) -> list[CountingBackend]:
    """Registers the `counting` backend for this test; lists every instance made."""
    made: list[CountingBackend] = []

    def factory(options) -> CountingBackend:
        made.append(CountingBackend())
        return made[-1]

    monkeypatch.setitem(BACKENDS, "counting", factory)
    return made


def create(server, **body) -> httpx.Response:
    return httpx.post(f"{server.url}/v1/sessions", json=body, timeout=10)


def test_a_session_choosing_a_backend_the_server_did_not_load_gets_422_naming_the_flag(
    live_server, counting
):
    server = live_server()  # loads detections only, though `counting` is registered
    for name in ("counting", "sam-9000"):
        answer = create(server, perception=name)
        assert answer.status_code == 422
        assert "--perception" in answer.json()["detail"] and repr(name) in answer.json()["detail"]
    assert httpx.get(f"{server.url}/v1/sessions", timeout=10).json() == []


def test_non_keyframes_never_reach_the_backend(live_server, counting):
    server = live_server(perception="counting")
    created = create(server, knobs=KNOBS).json()  # the server's first backend by default
    sid = created["session_id"]
    frames = [frame_message([CHAIR], seq) for seq in range(9)]
    replies = asyncio.run(stream_in_step(f"{server.ws_url}/v1/sessions/{sid}/stream", frames))

    assert [r["keyframe"] for r in replies] == [seq % 3 == 0 for seq in range(9)]
    (backend,) = counting
    assert backend.seqs == [0, 3, 6]
    stats = httpx.get(f"{server.url}/v1/sessions/{sid}", timeout=10).json()
    assert (stats["perception"], stats["keyframes"], stats["objects"]) == ("counting", 3, 1)


def test_a_bad_non_keyframe_is_still_refused_without_perception(live_server, counting):
    server = live_server(perception="counting")
    sid = create(server, knobs=KNOBS).json()["session_id"]
    good = frame_message([CHAIR], 0)
    unlabelled = frame_message([CHAIR], 1)
    unlabelled["detections"]["instances"] = []  # the instance image still shows id 1
    replies = asyncio.run(
        stream_in_step(f"{server.ws_url}/v1/sessions/{sid}/stream", [good, unlabelled])
    )
    assert replies[0]["type"] == "ack" and replies[0]["keyframe"]
    assert replies[1]["type"] == "error" and replies[1]["message"].startswith(
        "detections.instances: "
    )
    assert counting[0].seqs == [0]


def test_a_sessions_perception_survives_a_restart(live_server, counting):
    first = live_server(perception="detections,counting")
    default = create(first).json()["session_id"]
    chosen = create(first, perception="counting", knobs=KNOBS).json()["session_id"]
    first.stop()

    again = live_server()  # started without --perception counting
    stats = {
        sid: httpx.get(f"{again.url}/v1/sessions/{sid}", timeout=10).json()["perception"]
        for sid in (default, chosen)
    }
    assert stats == {default: "detections", chosen: "counting"}
    frames = [frame_message([CHAIR], seq) for seq in range(4)]
    asyncio.run(stream_in_step(f"{again.ws_url}/v1/sessions/{chosen}/stream", frames))
    assert counting[-1].seqs == [0, 3]  # the restored session maps with its own backend
