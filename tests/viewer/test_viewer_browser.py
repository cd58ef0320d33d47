"""The viewer end to end: a real server on loopback, frames streamed by the device emulator,
the viewer following the session, and (where Debian's chromium is installed) a real headless
browser reading the scene viser mounted.

What the viewer shows is checked against the server's own view (GET /objects). Waits are on
conditions with deadlines, never sleeps.
"""

from __future__ import annotations

import asyncio
import contextlib
import re
import shutil
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path

import httpx
import numpy as np
import pytest
from analytic_world import BATHROOM, KITCHEN, RectSource
from helpers_device import FAST_KNOBS, server_state
from relation_scene import SCENE, scene_export

from app.client import create_session
from app.config import Knobs, updated_knobs
from app.server.runner import ServerThread, free_port
from app.server.settings import ServerSettings
from client_sim.sources.base import FrameSource
from client_sim.streaming import DeviceClient
from viewer.app import FLOOR_NODE, ViewerApp
from viewer.scene import (
    HIT_BOXES_NODE,
    RELATION_BOXES_NODE,
    RELATION_LINES_NODE,
    RelationHighlight,
    anchor_label_node,
    hit_label_node,
    points_node,
)
from viewer.shapes import PANEL_PX, frame_view

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]

ARTIFACTS = Path(__file__).resolve().parents[2] / "out" / "test-artifacts"
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
]
WAIT_S = 30.0
OBJECT_NODE = re.compile(r"^/objects/\d+$")

# Names of the scene nodes the page has mounted (viser 1.1.1 exposes its scene internals on
# window for end-to-end tests: nodeRefFromName maps a node's name to its three.js object,
# which is unset until mounted and deleted on removal).
MOUNTED_NODES_JS = """() => {
    const m = window.__viserMutable;
    return m ? Object.entries(m.nodeRefFromName).filter(([, ref]) => ref).map(([n]) => n) : null;
}"""


def chromium_path() -> str | None:
    """Debian's chromium or chromium-headless-shell (Playwright's own download cannot work
    offline)."""
    for name in ("chromium", "chromium-headless-shell"):
        for candidate in (f"/usr/bin/{name}", shutil.which(name)):
            if candidate and Path(candidate).exists():
                return candidate
    return None


def wait_for(condition: Callable[[], object], what: str, timeout_s: float = WAIT_S) -> object:
    """Poll `condition` until it returns something truthy (returned); fail after `timeout_s`."""
    deadline = time.monotonic() + timeout_s
    while not (result := condition()):
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")
        time.sleep(0.05)  # a polling period, not synchronisation
    return result


def server_on(port: int, data_dir: Path, encoder) -> ServerThread:
    """The real app on a fixed port and data dir, so that it can be stopped and started again
    where the viewer expects it (conftest's live_server picks a new port)."""
    settings = ServerSettings(host="127.0.0.1", port=port, data_dir=str(data_dir))
    return ServerThread(settings, encoder).start()


def new_session(server_url: str, api_key: str | None = None) -> tuple[str, str, Knobs]:
    sid, token, answer = asyncio.run(create_session(server_url, knobs=FAST_KNOBS, api_key=api_key))
    return sid, token, updated_knobs(Knobs(), answer["knobs"])


def stream(server_url: str, sid: str, token: str, knobs: Knobs, source: FrameSource) -> int:
    """Play `source` to the session (one frame in flight); the server's update seq after."""

    async def play() -> int:
        device = DeviceClient(server_url, sid, token, knobs=knobs)
        stats = await device.stream(source, fps=None, max_in_flight=1)
        await device.stop()
        assert stats.errors == 0 and stats.frames_sent == len(source)
        seq, _ = await server_state(server_url, sid, token)
        return seq

    return asyncio.run(play())


def objects_of(server_url: str, sid: str, token: str) -> dict[int, int]:
    """id -> version of the server's confirmed objects."""
    _, objects = asyncio.run(server_state(server_url, sid, token))
    return {o["id"]: o["version"] for o in objects}


def viewer_objects(app: ViewerApp) -> dict[int, int]:
    with app._lock:
        return {oid: obj.version for oid, obj in app.model.objects.items()}


@contextmanager
def running_viewer(server_url: str, sid: str, token: str) -> Iterator[ViewerApp]:
    app = ViewerApp(server_url, sid, token, port=0, stats_period_s=0.2)
    app.start()
    try:
        yield app
    finally:
        app.stop()


@contextmanager
def browser_page(url: str):
    executable = chromium_path()
    if executable is None:
        pytest.skip("no chromium: install Debian's chromium (or chromium-headless-shell)")
    playwright_api = pytest.importorskip("playwright.sync_api")
    with playwright_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=executable, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 800})
            page.goto(url)
            yield page
        finally:
            browser.close()


def test_the_browser_shows_one_point_cloud_per_confirmed_object_and_the_query_hits(
    live_server,
):
    server = live_server(api_key="secret")  # as deployed: the session token on every call
    sid, token, knobs = new_session(server.url, api_key="secret")
    seq = stream(server.url, sid, token, knobs, RectSource(KITCHEN, 6))
    expected = objects_of(server.url, sid, token)
    assert len(expected) == 2, "the kitchen has a chair and a refrigerator"

    with running_viewer(server.url, sid, token) as app:
        wait_for(lambda: app.applied_seq >= seq, f"the viewer to apply seq {seq}")
        assert viewer_objects(app) == expected
        wait_for(lambda: "| objects | 2 (viewer 2) |" in app.gui.stats.content, "the stats")
        assert "live" in app.gui.status.content

        with browser_page(app.url) as page:
            wanted = {points_node(oid) for oid in expected}

            def mounted_objects() -> set[str] | None:
                names = page.evaluate(MOUNTED_NODES_JS) or []
                shown = {n for n in names if OBJECT_NODE.match(n)}
                return shown if shown == wanted else None

            wait_for(mounted_objects, f"the page to mount {sorted(wanted)}")
            # where the device is: its newest pose, from the updates' device_pose
            assert "/device/frustum" in (page.evaluate(MOUNTED_NODES_JS) or [])
            assert FLOOR_NODE in (page.evaluate(MOUNTED_NODES_JS) or []), "the floor grid"

            # Enter in "Find" runs the query, as the Search button does
            find = page.locator("xpath=//*[text()='Find']/following::input[1]")  # no <label for>
            find.fill("refrigerator")
            find.press("Enter")
            wait_for(
                lambda: "for *refrigerator*" in app.gui.results.content,
                "Enter in Find to run the query",
            )
            assert HIT_BOXES_NODE in app.model.sink._handles
            app.clear_query()

            results = app.run_query("refrigerator", k=1)
            assert results[0]["label"] == "refrigerator"
            assert app.last_match is True
            assert "no confident match" not in app.gui.results.content
            wait_for(
                lambda: HIT_BOXES_NODE in (page.evaluate(MOUNTED_NODES_JS) or []),
                "the hit's box in the page",
            )
            ARTIFACTS.mkdir(parents=True, exist_ok=True)
            page.screenshot(path=str(ARTIFACTS / "viewer_kitchen_query.png"))

            nothing = app.run_query("xyzzy plugh", k=2)  # hits listed, none confident
            assert len(nothing) == 2 and app.last_match is False
            assert "no confident match" in app.gui.results.content

            app.clear_query()
            wait_for(
                lambda: HIT_BOXES_NODE not in (page.evaluate(MOUNTED_NODES_JS) or []),
                "the hit's box to go",
            )


def test_a_relational_answer_shows_its_target_and_anchor_joined_by_a_line(live_server):
    server = live_server()
    created = httpx.post(f"{server.url}/v1/sessions/import", json=scene_export(), timeout=30)
    assert created.status_code == 201, created.text
    sid, token = created.json()["session_id"], created.json()["token"]
    relation_names = {RELATION_BOXES_NODE, RELATION_LINES_NODE}  # labels are not three.js nodes

    with running_viewer(server.url, sid, token) as app:
        wait_for(lambda: len(viewer_objects(app)) == len(SCENE), "the imported map")
        with browser_page(app.url) as page:
            results = app.run_query("the mug on the desk", k=3)
            assert results[0]["id"] == 10 and app.last_match is True  # mug 10 is on desk 1
            assert app.model.relation == RelationHighlight(10, (1,), "on the desk")
            first, second = app.gui.results.content.splitlines()[2:4]
            assert re.match(r"1\. mug — on the desk \([01]\.\d\d\) — relevance", first), first
            assert re.match(r"2\. mug — not on the desk \(0\.\d\d\) — ", second), second
            labels = {hit_label_node(10), anchor_label_node(1)}
            assert app.model.sink._handles.keys() >= relation_names | labels
            wait_for(
                lambda: relation_names <= set(page.evaluate(MOUNTED_NODES_JS) or []),
                "the target's and anchor's boxes and the line between them in the page",
            )
            ARTIFACTS.mkdir(parents=True, exist_ok=True)
            page.screenshot(path=str(ARTIFACTS / "viewer_relation.png"))

            # nothing satisfies it: the sofa is shown, no mug singled out, no line
            app.run_query("the mug under the sofa", k=3)
            assert app.last_match is False and "no confident match" in app.gui.results.content
            assert app.model.relation == RelationHighlight(None, (4,), "under the sofa")
            assert RELATION_LINES_NODE not in app.model.sink._handles

            app.clear_query()
            assert not [n for n in app.model.sink._handles if n.startswith("/hits")]
            wait_for(
                lambda: not relation_names & set(page.evaluate(MOUNTED_NODES_JS) or []),
                "the relation's nodes to go from the page",
            )


def test_a_page_opened_on_an_empty_map_is_reframed_when_the_first_objects_arrive(live_server):
    server = live_server()
    sid, token, knobs = new_session(server.url)
    with running_viewer(server.url, sid, token) as app, browser_page(app.url):

        def page_camera():
            for client in app.server.get_clients().values():
                with contextlib.suppress(AssertionError):  # not reported yet
                    return client.camera if client.camera.image_width else None
            return None

        camera = wait_for(page_camera, "the page to report its camera")
        assert not app.model.objects
        # Playwright's sync API keeps an event loop running on this thread: stream on another.
        with ThreadPoolExecutor(1) as pool:
            seq = pool.submit(
                stream, server.url, sid, token, knobs, RectSource(KITCHEN, 6)
            ).result()
        wait_for(lambda: app.applied_seq >= seq, f"the viewer to apply seq {seq}")
        with app._lock:
            bounds = app.model.bounds()
        assert bounds is not None
        aspect = camera.image_width / camera.image_height
        wanted = frame_view(bounds, app.up, camera.fov, aspect, PANEL_PX / camera.image_width)
        # 2 cm: the page reports its camera back in float32, after its controls settle
        wait_for(
            lambda: (
                np.allclose(camera.look_at, wanted.look_at, atol=0.02)
                and np.allclose(camera.position, wanted.position, atol=0.02)
            ),
            "the page's camera to frame the map",
        )
        # and pages opened from now on start there too (for the assumed canvas size)
        assert np.linalg.norm(app.server.initial_camera.position) > 0


def test_the_viewer_shows_the_outage_and_resumes_from_its_seq_after_a_server_restart(
    tmp_path, encoder
):
    port = free_port()
    server = server_on(port, tmp_path / "data", encoder)
    try:
        sid, token, knobs = new_session(server.url)
        seq_before = stream(server.url, sid, token, knobs, RectSource(KITCHEN, 6))
        with running_viewer(server.url, sid, token) as app:
            wait_for(lambda: app.applied_seq >= seq_before, f"the viewer to apply {seq_before}")
            assert app.status.connected and app.status.last_since is None  # a full snapshot

            server.stop()
            wait_for(lambda: not app.status.connected, "the viewer to notice the server is gone")
            assert "disconnected — reconnecting" in app.gui.status.content

            server = server_on(port, tmp_path / "data", encoder)
            wait_for(lambda: app.status.connected, "the viewer to reconnect", timeout_s=20)
            assert app.status.reconnects == 1
            assert app.status.last_since == seq_before  # resumed, not resynced
            assert "live" in app.gui.status.content

            seq_after = stream(server.url, sid, token, knobs, RectSource(BATHROOM, 6, 4.0))
            assert seq_after > seq_before
            wait_for(lambda: app.applied_seq >= seq_after, f"the viewer to apply {seq_after}")
            assert viewer_objects(app) == objects_of(server.url, sid, token)
            assert {o.label for o in app.model.objects.values()} >= {"bathtub", "toilet"}
            assert app.status.full_snapshots == 1 and app.status.resyncs == 0
    finally:
        server.stop()


def test_the_viewer_command_takes_the_server_the_session_and_where_to_listen():
    import argparse

    from app.cli.viewer import add_parser, run

    parser = argparse.ArgumentParser()
    add_parser(parser.add_subparsers(dest="command"))
    args = parser.parse_args(
        ["viewer", "--server", "http://10.0.0.2:8000", "--session", "abc", "--port", "8090"]
    )
    assert (args.server, args.session, args.port, args.host) == (
        "http://10.0.0.2:8000",
        "abc",
        8090,
        "127.0.0.1",
    )
    assert args.func is run and args.up == "+z"
