"""The session's stats say the frames walked, and of them those received whole and those
received as sightings, through a real server on loopback: our device with the sightings
extension sends its keyframes whole and sightings between them. The store keeps the counts,
so they come back after the session is unloaded and after a restart."""

from __future__ import annotations

import asyncio

import pytest
from analytic_world import Rect, RectSource

from app.client import SessionApi
from app.client.rest import list_sessions
from app.config import Knobs, updated_knobs
from app.protocol import SessionStats, SessionSummary
from client_sim.streaming import DeviceClient

pytestmark = pytest.mark.timeout(120)

CHAIR = Rect(1, "chair", -0.6, -0.3, -0.1, 0.3, 2.0)
KNOBS = {"keyframe_interval": 5, "min_observations": 3, "min_mapping_bbox_area": 100}
FRAMES = 12
"""Keyframes 0, 5 and 10 go whole; the 9 frames between them go as sightings."""
WHOLE, SIGHTINGS = 3, 9


def walk_with_sightings(server) -> tuple[str, str]:
    """A new session walked by our device (the sightings extension offered and selected);
    (session id, token)."""

    async def scenario() -> tuple[str, str]:
        sid, token, answer = await DeviceClient.create_session(server.url, knobs=KNOBS)
        knobs = updated_knobs(Knobs(), answer["knobs"])
        device = DeviceClient(server.url, sid, token, knobs=knobs, on_log=lambda _: None)
        sent = await device.stream(RectSource([CHAIR], FRAMES), fps=None, max_in_flight=1)
        await device.stop()
        assert (sent.frames_sent, sent.sightings_sent, sent.errors) == (FRAMES, SIGHTINGS, 0)
        return sid, token

    return asyncio.run(scenario())


def stats(server, sid: str, token: str) -> SessionStats:
    async def fetch() -> SessionStats:
        async with SessionApi(server.url, sid, token) as api:
            return await api.fetch()

    return asyncio.run(fetch())


def listed(server, sid: str) -> SessionSummary:
    (entry,) = [s for s in asyncio.run(list_sessions(server.url)) if s.session_id == sid]
    return entry


def counts(figures: SessionStats | SessionSummary) -> tuple[int, int | None, int | None]:
    return figures.frames, figures.frames_whole, figures.sightings


def test_the_stats_count_the_frames_walked_whole_and_as_sightings_apart(live_server):
    server = live_server()
    sid, token = walk_with_sightings(server)
    walked = stats(server, sid, token)
    assert counts(walked) == (FRAMES, WHOLE, SIGHTINGS)
    assert walked.keyframes == WHOLE  # every whole frame is a keyframe on this socket
    assert counts(listed(server, sid)) == (FRAMES, WHOLE, SIGHTINGS)


def test_the_counts_come_back_after_an_unload_and_after_a_restart(live_server):
    server = live_server(max_resident_sessions=1)
    sid, token = walk_with_sightings(server)
    asyncio.run(DeviceClient.create_session(server.url))  # no room for both: sid is unloaded
    entry = listed(server, sid)
    assert not entry.resident and counts(entry) == (FRAMES, WHOLE, SIGHTINGS)  # the stored row
    assert counts(stats(server, sid, token)) == (FRAMES, WHOLE, SIGHTINGS)  # loaded again

    server.stop()
    server = live_server()
    assert counts(stats(server, sid, token)) == (FRAMES, WHOLE, SIGHTINGS)
