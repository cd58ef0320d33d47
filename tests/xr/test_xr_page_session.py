"""The real-device page's session handling in real Chromium against a real server: creating
a session it can stream into, the server's refusal when it cannot, joining one, and a
tracking reset stopping the stream rather than mapping into a moved frame."""

from __future__ import annotations

import httpx
import pytest
from fake_xr_browser import open_with_fake_xr, wait_until
from scene_feed import SceneFeed
from xr_device import Phone, RuntimeOptions

pytestmark = [pytest.mark.slow, pytest.mark.timeout(300)]


def test_a_server_without_models_refuses_the_pages_session_and_the_page_names_the_flag(
    xr_page, live_server
):
    server = live_server()  # detections only: a page's frames carry none
    open_with_fake_xr(xr_page, f"{server.url}/xr", SceneFeed(Phone(), n_frames=2))
    xr_page.fill("#session-name", "kitchen")
    xr_page.click("#create-form button[type=submit]")
    wait_until(xr_page, "() => !document.querySelector('#banner').hidden")
    banner = xr_page.inner_text("#banner")
    assert "could not be created" in banner and "--perception" in banner
    assert httpx.get(f"{server.url}/v1/sessions", timeout=10).json() == []


def test_joining_a_session_reads_its_perception_and_warnings_first(xr_page, live_server):
    server = live_server()
    created = httpx.post(f"{server.url}/v1/sessions", json={"name": "hall"}, timeout=10).json()
    sid, token = created["session_id"], created["token"]
    requested: list[str] = []
    xr_page.on("request", lambda request: requested.append(request.url))
    open_with_fake_xr(
        xr_page, f"{server.url}/xr#session={sid}&token={token}", SceneFeed(Phone(), n_frames=2)
    )
    wait_until(
        xr_page, "() => document.querySelector('#session-info').textContent.includes('perception')"
    )
    info = xr_page.inner_text("#session-info")
    assert "“hall”" in info and "perception detections" in info
    assert "create a session for this page" in info
    # The token left the address bar (kept in the tab's storage, as the dashboard keeps it).
    assert token not in xr_page.url and f"session={sid}" in xr_page.url
    # Everything the page loaded came from this server (its modules, the vendored msgpack).
    assert any(url.endswith("/msgpack-msgpack@3.1.3/dist.esm/index.mjs") for url in requested)
    assert all(url.startswith(server.url) or url.startswith("data:") for url in requested)


def test_a_tracking_reset_stops_the_stream_instead_of_mapping_a_moved_frame(
    xr_page, live_server, tmp_path
):
    from app.perception.models.tiny import write_tiny_models

    server = live_server(perception="models", models_dir=str(write_tiny_models(tmp_path / "m")))
    created = httpx.post(
        f"{server.url}/v1/sessions",
        json={"perception": "models", "up": "+y", "knobs": {"keyframe_interval": 1}},
        timeout=30,
    ).json()
    sid, token = created["session_id"], created["token"]
    feed = SceneFeed(Phone(), n_frames=40, options=RuntimeOptions(on_walk_end="hold"))
    open_with_fake_xr(xr_page, f"{server.url}/xr#session={sid}&token={token}", feed)
    wait_until(xr_page, "() => !document.querySelector('#start-ar').disabled")
    xr_page.click("#start-ar")
    wait_until(xr_page, "() => (window.semanticxr.counters || {}).acked >= 2", timeout_s=120)

    xr_page.evaluate("fakeXR.resetReferenceSpace()")
    wait_until(xr_page, "() => !window.semanticxr.streaming")
    assert "reset" in xr_page.inner_text("#banner")
    assert xr_page.inner_text("#connection") == "stopped"
    sent = xr_page.evaluate("window.semanticxr.counters.frames")
    # The walk goes on; nothing more is sent.
    frames_now = xr_page.evaluate("fakeXR.xrFrames")
    wait_until(xr_page, f"() => fakeXR.xrFrames >= {frames_now + 30}")
    assert xr_page.evaluate("window.semanticxr.counters.frames") == sent
