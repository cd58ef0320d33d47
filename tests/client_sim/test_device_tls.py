"""The emulated device against a `serve --https` server on loopback: its REST calls, its
stream socket and its updates socket all trust the server's certificate through the one SSL
context given (`semanticxr device --tls-ca`); without it, nothing connects."""

from __future__ import annotations

import asyncio

import pytest
from analytic_world import KITCHEN, RectSource
from helpers_device import FAST_KNOBS, assert_local_map_equals, synced_state, wait_until

from app.client import trusting
from app.config import Knobs, updated_knobs
from client_sim.streaming import DeviceClient

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]


def test_a_device_streams_over_wss_and_its_local_map_equals_the_servers(live_server):
    server = live_server(https=True, api_key="secret")
    trust = trusting(server.certificate.cert_path)

    async def scenario():
        sid, token, answer = await DeviceClient.create_session(
            server.url, knobs=FAST_KNOBS, api_key="secret", ssl_context=trust
        )
        knobs = updated_knobs(Knobs(), answer["knobs"])
        device = DeviceClient(server.url, sid, token, knobs=knobs, ssl_context=trust)
        following = asyncio.create_task(device.follow_updates())
        try:
            stats = await device.stream(RectSource(KITCHEN, 8), fps=None, max_in_flight=1)
            seq, objects = await synced_state(device, server.url, sid, token, verify=trust)
        finally:
            await device.stop()
            await asyncio.wait_for(following, 15)
        return stats, objects, device

    stats, objects, device = asyncio.run(scenario())
    assert device.ws_url.startswith("wss://")
    assert (stats.frames_sent, stats.acks, stats.errors) == (8, 8, 0)
    assert sorted(o["label"] for o in objects) == ["chair", "refrigerator"]
    assert_local_map_equals(device.local_map, objects, device.knobs.max_object_points_client)


def test_a_device_without_the_certificate_sends_nothing_and_says_why(live_server):
    server = live_server(https=True)
    trust = trusting(server.certificate.cert_path)

    async def scenario():
        sid, token, _ = await DeviceClient.create_session(server.url, ssl_context=trust)
        logs: list[str] = []
        device = DeviceClient(server.url, sid, token, on_log=logs.append)  # the system's CAs
        streaming = asyncio.create_task(device.stream(RectSource(KITCHEN, 3), fps=None))
        await wait_until(
            lambda: any("CERTIFICATE_VERIFY_FAILED" in line for line in logs),
            what="the device saying its socket was refused",
        )
        await device.stop()  # it would retry for ever
        return await asyncio.wait_for(streaming, 15)

    stats = asyncio.run(scenario())
    assert (stats.frames_sent, stats.acks) == (0, 0)
