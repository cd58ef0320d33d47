"""The real-device page's answer path (static/xr/updates.mjs, answers.mjs, draw.mjs) in a real
headless Chromium against a real server on loopback: the map it follows, the answers it
gets (from the server, and from its local copy when the network is down), and what it draws
of them, read back pixel by pixel from WebGL2."""

from __future__ import annotations

import asyncio
import base64
import re
import time
from concurrent.futures import ThreadPoolExecutor
from urllib.parse import parse_qs, urlsplit

import httpx
import msgpack
import numpy as np
import pytest
from answers_page import (
    column_major,
    image_of,
    look_from,
    near_face_rect,
    open_answers_page,
    perspective,
    pixel_of,
)
from devices import stream_in_step
from living_world import AFTER, BEFORE, BOOK, KNOBS, WALK_2_T, walk
from relation_scene import SCENE as RELATION_SCENE
from relation_scene import scene_export

from app.protocol.delta import UPSERT_KEYS, DeltaMessage, UpsertEntry
from app.server.runner import ServerThread

# --- helpers ----------------------------------------------------------------------------------


def stream(server, sid: str, frames: list[dict]) -> None:
    """Stream frames one at a time (off Playwright's event loop, which owns this thread)."""
    url = f"{server.ws_url}/v1/sessions/{sid}/stream"
    with ThreadPoolExecutor(1) as pool:
        acks = pool.submit(asyncio.run, stream_in_step(url, frames)).result()
    assert all(a["type"] == "ack" for a in acks), acks


def update_seq(server, sid: str) -> int:
    return httpx.get(f"{server.url}/v1/sessions/{sid}", timeout=10).json()["update_seq"]


def server_objects(server, sid: str) -> list[dict]:
    answer = httpx.get(f"{server.url}/v1/sessions/{sid}/objects?points=true", timeout=10)
    assert answer.status_code == 200, answer.text
    return sorted(answer.json(), key=lambda o: o["id"])


def assert_holds_the_servers_map(held: list[dict], served: list[dict]) -> None:
    """Same ids, versions, labels, boxes, times and points (float16 on the wire)."""
    assert [o["id"] for o in held] == [o["id"] for o in served]
    for mine, theirs in zip(held, served, strict=True):
        for key in ("version", "label", "n_obs", "first_seen_t", "last_seen_t"):
            assert mine.get(key) == theirs[key], (mine["id"], key)
        assert np.allclose(mine["bbox"], theirs["bbox"], atol=1e-4), mine["id"]
        points = np.reshape(mine["points"], (-1, 3))
        assert points.shape == np.shape(theirs["points"]), mine["id"]
        assert np.allclose(points, theirs["points"], atol=2e-3), mine["id"]  # float16 steps


def follow(page, server, sid: str, token: str | None = None) -> None:
    """Start the page's MapFollower and wait until it has applied the server's newest seq."""
    page.evaluate("([sid, token]) => window.xr.follow(sid, token)", [sid, token])
    wait_for_seq(page, update_seq(server, sid))


def wait_for_seq(page, seq: int) -> None:
    page.wait_for_function(
        "seq => window.follower.connected && window.follower.lastSeq === seq", arg=seq
    )


def imported_office(server) -> str:
    """tests/relation_scene.py's room (three mugs on a desk, a shelf and a table; Z-up)."""
    created = httpx.post(
        f"{server.url}/v1/sessions/import", json=scene_export("office"), timeout=30
    )
    assert created.status_code == 201, created.text
    return created.json()["session_id"]


def packed(delta: DeltaMessage) -> str:
    return base64.b64encode(msgpack.packb(delta.pack())).decode()


def upsert(oid: int, version: int, label: str, points) -> UpsertEntry:
    points = np.asarray(points, np.float32)
    return UpsertEntry(
        oid,
        version,
        label,
        np.full(4, 0.5, np.float32),
        points,
        (*points.min(0).tolist(), *points.max(0).tolist()),
        n_obs=3,
        last_seen_t=12.5,
    )


# --- following the map ------------------------------------------------------------------------


@pytest.mark.timeout(120)
def test_the_page_speaks_the_protocols_upsert_keys(live_server, page):
    open_answers_page(page, live_server().url)
    assert page.evaluate("[...window.xr.updates.UPSERT_KEYS]") == list(UPSERT_KEYS)


@pytest.mark.timeout(120)
def test_deltas_apply_in_order_full_snapshots_replace_and_stale_ones_change_nothing(
    live_server, page
):
    open_answers_page(page, live_server().url)
    mug_points = [[0.5, 0.25, 1.0], [0.625, 0.375, 1.125], [0.123, -2.5, 3.3]]
    steps = [
        DeltaMessage(3, True, [upsert(1, 1, "mug", mug_points), upsert(2, 1, "desk", [[0, 0, 0]])]),
        DeltaMessage(5, False, [upsert(1, 2, "cup", mug_points[:2])], removed=[2]),
        DeltaMessage(6, False, [upsert(1, 1, "mug", mug_points)]),  # older version: stale
        DeltaMessage(4, False, [upsert(3, 1, "chair", mug_points)]),  # older seq: refused
        DeltaMessage(2, True, [upsert(3, 1, "chair", mug_points)]),  # a snapshot replaces all
    ]
    results = page.evaluate("m => window.xr.applyAll(m)", [packed(d) for d in steps])
    full, upserted, stale, refused, snapshot = results

    assert [o["id"] for o in full["held"]] == [1, 2]
    mug = full["held"][0]
    wire = np.asarray(mug_points, np.float16).astype(np.float32).ravel()
    assert mug["points"] == wire.tolist()  # float16 decoded exactly
    assert mug["embedding"] == [0.5] * 4 and mug["last_seen_t"] == 12.5
    assert np.allclose(mug["centroid"], wire.reshape(-1, 3).mean(0))
    assert upserted["summary"]["updated"] == [1] and upserted["summary"]["removed"] == [2]
    assert [(o["id"], o["version"], o["label"]) for o in upserted["held"]] == [(1, 2, "cup")]
    assert stale["summary"]["unchanged"] == [1] and stale["held"] == upserted["held"]
    assert refused["error"]["field"] == "seq" and refused["held"] == upserted["held"]
    assert [o["id"] for o in snapshot["held"]] == [3]
    assert snapshot["summary"]["removed"] == [1]


@pytest.mark.timeout(120)
def test_a_malformed_delta_is_refused_naming_its_field(live_server, page):
    open_answers_page(page, live_server().url)
    good = DeltaMessage(1, True, [upsert(1, 1, "mug", [[0, 0, 0]])]).pack()
    no_points = {
        **good,
        "upserts": [{k: v for k, v in good["upserts"][0].items() if k != "points"}],
    }
    odd_points = {**good, "upserts": [{**good["upserts"][0], "points": b"\x00" * 7}]}
    messages = [base64.b64encode(msgpack.packb(m)).decode() for m in (no_points, odd_points)]
    missing, odd = page.evaluate("m => window.xr.applyAll(m)", messages)
    assert missing["error"]["field"] == "upserts[0]" and "points" in missing["error"]["message"]
    assert odd["error"]["field"] == "upserts[0].points"


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_the_follower_holds_the_servers_map_and_resumes_after_a_restart(live_server, encoder, page):
    server = live_server()
    created = httpx.post(f"{server.url}/v1/sessions", json={"name": "room", "knobs": KNOBS})
    sid, token = created.json()["session_id"], created.json()["token"]
    stream(server, sid, walk(BEFORE, 0.0))
    sockets: list[str] = []
    page.on("websocket", lambda ws: sockets.append(ws.url))
    open_answers_page(page, server.url)
    follow(page, server, sid, token)
    assert_holds_the_servers_map(page.evaluate("window.xr.held()"), server_objects(server, sid))
    book = next(o["id"] for o in server_objects(server, sid) if o["label"] == BOOK.label)
    seq_before = page.evaluate("window.follower.lastSeq")

    # The server goes away and comes back on the same port and data dir; the room changes.
    server.stop()
    page.wait_for_function(
        "() => window.follower.state === 'waiting'"
    )  # a function: a string is eval'd, which the CSP forbids
    restarted = ServerThread(server.settings, encoder).start()
    try:
        stream(restarted, sid, walk(AFTER, WALK_2_T))
        wait_for_seq(page, update_seq(restarted, sid))
        served = server_objects(restarted, sid)
        held = page.evaluate("window.xr.held()")
        deltas = page.evaluate("window.xr.log.deltas")
    finally:
        restarted.stop()

    assert_holds_the_servers_map(held, served)
    assert book not in [o["id"] for o in held]  # taken away while the page was away
    first, *reopened = [parse_qs(urlsplit(url).query) for url in sockets]
    assert "since" not in first and first["token"] == [token]
    assert reopened and all(q["since"] == [str(seq_before)] for q in reopened)
    after = [d for d in deltas if d["seq"] > seq_before]
    assert after and not any(d["full"] for d in after)  # resumed, not started over
    assert any(book in d["removed"] for d in after)
    changed = [d["seq"] for d in deltas if d["added"] or d["updated"] or d["removed"]]
    assert changed == sorted(set(changed))  # none applied twice, none out of order


# --- asking -----------------------------------------------------------------------------------


def rest_answer(server, sid: str, text: str, **params) -> dict:
    answer = httpx.get(
        f"{server.url}/v1/sessions/{sid}/query",
        params={"text": text, "k": 5, "points": "true", **params},
        timeout=10,
    )
    assert answer.status_code == 200, answer.text
    return answer.json()


def assert_same_answer(asked: dict, served: dict) -> None:
    assert asked["source"] == "server" and asked["note"] is None
    assert (asked["text"], asked["match"]) == (served["text"], served["match"])
    assert [h["id"] for h in asked["results"]] == [h["id"] for h in served["results"]]
    for mine, theirs in zip(asked["results"], served["results"], strict=True):
        for key in ("label", "score", "relevance", "bbox", "centroid", "state", "place"):
            assert mine[key] == theirs[key], (mine["id"], key)
        assert np.allclose(mine["points"], np.ravel(theirs["points"]), atol=1e-5)
        if theirs["relation"] is None:
            assert mine["relation"] is None
            continue
        assert mine["relation"]["kind"] == theirs["relation"]["kind"]
        assert mine["relation"]["degree"] == theirs["relation"]["degree"]
        assert [(a["id"], a["label"]) for a in mine["relation"]["anchors"]] == [
            (a["id"], a["label"]) for a in theirs["relation"]["anchors"]
        ]


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_asked_online_the_page_gets_the_servers_answer(live_server, page):
    server = live_server()
    sid = imported_office(server)
    open_answers_page(page, server.url)
    follow(page, server, sid)
    held = {o["id"]: o for o in page.evaluate("window.xr.held()")}

    asked = page.evaluate(
        "t => window.xr.asked(t, {sid: window.follower.sid})", "the mug on the desk"
    )
    served = rest_answer(server, sid, "the mug on the desk")
    assert_same_answer(asked, served)
    best = served["results"][0]
    assert best["id"] == 10 and asked["match"]
    (anchor,) = asked["results"][0]["relation"]["anchors"]
    assert anchor["label"] == "desk"  # its geometry filled in, to draw it
    assert np.allclose(anchor["bbox"], held[anchor["id"]]["bbox"], atol=1e-4)
    assert len(anchor["points"]) == len(held[anchor["id"]]["points"])
    assert asked["words"] == f"mug — on the desk ({best['relation']['degree']:.2f})"

    where = [0.9, -1.5, 1.0]  # near the chair at the desk: "closest to me" needs the asker
    asked = page.evaluate(
        "([t, from]) => window.xr.asked(t, {sid: window.follower.sid, from, k: 3})",
        ["the chair closest to me", where],
    )
    served = rest_answer(server, sid, "the chair closest to me", k=3, **{"from": "0.9,-1.5,1.0"})
    assert_same_answer(asked, served)
    assert (
        served["results"][0]["id"] == 20 and served["results"][0]["relation"]["kind"] == "closest"
    )

    asked = page.evaluate("t => window.xr.asked(t, {sid: window.follower.sid})", "xyzzy plugh")
    served = rest_answer(server, sid, "xyzzy plugh")
    assert_same_answer(asked, served)
    closest = served["results"][0]
    assert not asked["match"]
    assert asked["words"] == (
        f"no match for “xyzzy plugh” — closest: {closest['label']} ({closest['relevance']:.2f})"
    )


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_with_the_network_cut_the_page_answers_from_its_copy_by_label_words(
    live_server, context, page
):
    server = live_server()
    sid = imported_office(server)
    open_answers_page(page, server.url)
    follow(page, server, sid)

    context.set_offline(True)
    asked = page.evaluate(
        "t => window.xr.asked(t, {sid: window.follower.sid})", "the mug on the desk"
    )
    assert asked["source"] == "local"
    assert asked["note"] == (
        f"offline: answered from the local copy by label words; {len(RELATION_SCENE)} objects held"
    )
    # the mugs (named first), then the desk; nothing is calibrated, nothing said about "on"
    assert [h["id"] for h in asked["results"]] == [10, 11, 12, 1]
    assert asked["match"] and asked["words"] == "mug (by label, offline)"
    assert all(h["relevance"] is None and h["relation"] is None for h in asked["results"])
    assert len(asked["results"][0]["points"]) > 0  # the follower's points, to draw

    asked = page.evaluate(
        "t => window.xr.asked(t, {sid: window.follower.sid})", "where are my keys"
    )
    assert asked["source"] == "local" and not asked["match"] and asked["results"] == []
    assert (
        asked["words"] == "no match for “where are my keys” (offline: no label held shares a word)"
    )


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_a_server_that_does_not_answer_in_time_is_taken_as_out_of_reach(live_server, page):
    server = live_server()
    sid = imported_office(server)
    open_answers_page(page, server.url)
    follow(page, server, sid)
    page.route(re.compile(r"/query\?"), lambda route: None)  # the request hangs: never answered
    started = time.monotonic()
    asked = page.evaluate(
        "t => window.xr.asked(t, {sid: window.follower.sid, timeoutMs: 500})", "the sofa"
    )
    assert time.monotonic() - started < 5
    assert asked["source"] == "local" and [h["id"] for h in asked["results"]] == [4]


@pytest.mark.timeout(120)
def test_a_refusal_is_an_error_not_an_offline_answer(live_server, page):
    server = live_server(api_key="sesame")
    open_answers_page(page, server.url)
    page.evaluate("window.xr.auth.setToken('no-such-session', 'wrong')")
    asked = page.evaluate("t => window.xr.asked(t, {sid: 'no-such-session'})", "the sofa")
    assert asked["error"]["name"] == "Error" and asked["error"]["status"] == 403


# --- drawing ----------------------------------------------------------------------------------

PROJECTION = perspective(90.0)
VIEW = look_from((0.0, 1.6, 0.0))  # eye height, looking down -z (WebXR's y-up frame)
MUG_BOX = [-0.5, 1.1, -2.5, 0.5, 2.1, -2.0]
DESK_BOX = [1.2, 1.1, -2.5, 1.8, 1.5, -2.0]


def box_points(bbox) -> list[float]:
    """Two points on the box's near face: its centre and a quarter across."""
    x0, y0, _, x1, y1, z1 = bbox
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    return [cx, cy, z1, (3 * x0 + x1) / 4, cy, z1]


def hit(oid, label, bbox, relevance, relation=None) -> dict:
    centre = [(bbox[i] + bbox[i + 3]) / 2 for i in range(3)]
    return {
        "id": oid,
        "label": label,
        "score": relevance,
        "relevance": relevance,
        "bbox": bbox,
        "centroid": centre,
        "points": box_points(bbox),
        "relation": relation,
    }


def answer(*hits, match=True) -> dict:
    return {"text": "the mug", "match": match, "results": list(hits), "source": "server"}


def render(page, server, the_answer, objects=(), via_follower=False) -> tuple[np.ndarray, dict]:
    """Draw `the_answer` with the known camera; objects: what the follower holds."""
    open_answers_page(page, server.url)
    rendered = page.evaluate(
        "([a, p, v, o, f]) => window.xr.render(a, p, v, o, f)",
        [the_answer, column_major(PROJECTION), column_major(VIEW), list(objects), via_follower],
    )
    assert rendered["glError"] == 0
    return image_of(rendered), rendered


def is_orange(rgba) -> bool:
    r, g, b, a = (int(v) for v in rgba)
    return a > 0 and r > 0.8 * a and 0.2 * a < g < 0.45 * a and b < 0.1 * a


def is_teal(rgba) -> bool:
    r, g, b, a = (int(v) for v in rgba)
    return a > 200 and r < 30 and 130 < g < 170 and 115 < b < 155


def around(image, column, row, radius=2) -> np.ndarray:
    """The pixels within `radius` of (column, row), as [n, 4]."""
    c, r = round(column), round(row)
    return image[r - radius : r + radius + 1, c - radius : c + radius + 1].reshape(-1, 4)


@pytest.mark.timeout(120)
def test_the_best_hit_is_drawn_orange_where_its_box_projects_and_nothing_elsewhere(
    live_server, page
):
    image, rendered = render(page, live_server(), answer(hit(10, "mug", MUG_BOX, 0.93)))
    left, top, right, bottom = near_face_rect(MUG_BOX, PROJECTION, VIEW)
    assert (left, top, right, bottom) == (75, 75, 125, 125)  # the known camera's known box
    middle = (top + bottom) // 2
    for column, row in [(left, middle), (right, middle), ((left + right) // 2, bottom)]:
        assert any(is_orange(p) for p in around(image, column, row)), (column, row)
    across_left_edge = image[middle, left - 4 : left + 5]
    assert sum(is_orange(p) for p in across_left_edge) >= 2  # wider than WebGL's 1-pixel lines
    centre = pixel_of(box_points(MUG_BOX)[:3], PROJECTION, VIEW)
    assert any(is_orange(p) for p in around(image, *centre))  # a point
    assert rendered["label"] == "mug (0.93)"
    # the label: a plate above the box, white text on it
    above = image[: top - 2, left - 20 : right + 20]
    assert above[..., 3].max() > 200 and (above[..., :3].min(axis=-1) > 200).any()
    # nothing beside or below the box, nor inside it between its edges and its points
    assert not image[bottom + 4 :].any()
    assert not image[:, : left - 25].any() and not image[:, right + 25 :].any()
    assert not image[middle + 6 : bottom - 6, left + 8 : (left + right) // 2 - 8].any()


@pytest.mark.timeout(120)
def test_an_anchor_is_drawn_teal_and_joined_to_the_target(live_server, page):
    relation = {"kind": "on", "anchors": [{"id": 1, "label": "desk"}], "degree": 0.87}
    desk = {**hit(1, "desk", DESK_BOX, 1.0), "relation": None}  # as the follower holds it
    mug_on_the_desk = answer(hit(10, "mug", MUG_BOX, 0.93, relation))
    image, rendered = render(page, live_server(), mug_on_the_desk, [desk], via_follower=True)
    assert rendered["label"] == "mug — on the desk (0.87)"
    left, top, right, bottom = near_face_rect(DESK_BOX, PROJECTION, VIEW)
    middle = (top + bottom) // 2
    for column, row in [(right, middle), ((left + right) // 2, bottom)]:
        assert any(is_teal(p) for p in around(image, column, row)), (column, row)
    assert not any(is_orange(p) for p in around(image, right, middle))
    # the line from the mug's centre to the desk's, drawn between the two boxes
    start = np.array(pixel_of(desk["centroid"], PROJECTION, VIEW))
    end = np.array(pixel_of(hit(10, "mug", MUG_BOX, 1)["centroid"], PROJECTION, VIEW))
    between = start + 0.46 * (end - start)  # clear of both boxes' edges
    assert around(image, *between, radius=1)[:, 3].max() > 200
    assert not image[bottom + 4 :].any()


@pytest.mark.timeout(120)
def test_no_match_draws_nothing_at_all(live_server, page):
    weak = hit(10, "mug", MUG_BOX, 0.12)
    image, rendered = render(page, live_server(), answer(weak, match=False))
    assert rendered["label"] is None
    assert not image.any()


@pytest.mark.timeout(120)
def test_other_confident_hits_are_dimmer_and_weak_ones_are_not_drawn(live_server, page):
    other_box = [-1.5, 1.1, -2.5, -0.9, 1.5, -2.0]
    weak_box = [0.8, 1.1, -2.5, 1.4, 1.5, -2.0]
    image, _ = render(
        page,
        live_server(),
        answer(
            hit(10, "mug", MUG_BOX, 0.93),
            hit(11, "mug", other_box, 0.81),
            hit(5, "bowl", weak_box, 0.2),
        ),
    )
    left, top, right, bottom = near_face_rect(other_box, PROJECTION, VIEW)
    edge = around(image, left, (top + bottom) // 2)
    dim = [p for p in edge if is_orange(p)]
    assert dim and max(int(p[3]) for p in dim) < 160  # half as opaque as the best
    left, top, right, bottom = near_face_rect(weak_box, PROJECTION, VIEW)
    assert not image[top - 3 : bottom + 4, left - 3 : right + 4].any()


@pytest.mark.timeout(120)
def test_an_edge_that_passes_behind_the_viewer_runs_off_the_screen_not_across_it(live_server, page):
    around_me = [-0.5, 1.1, -2.0, 0.5, 2.1, 2.0]  # from 2 m ahead to 2 m behind the eye
    image, rendered = render(
        page, live_server(), answer({**hit(7, "rug", around_me, 0.9), "points": []})
    )
    # the edge from the near face's lower left corner towards the eye leaves the screen at its
    # lower left corner (clipped at the near plane); the same edge unclipped would run back
    # across the screen through its centre
    for column, row in [(50, 150), (25, 175)]:
        assert any(is_orange(p) for p in around(image, column, row)), (column, row)
    assert not image[90:110, 90:110].any()
    assert rendered["label"] == "rug (0.90)"  # set, but its place is behind: not drawn
    drawn = image[image[..., 3] > 0]
    assert len(drawn) and all(is_orange(p) for p in drawn)  # no label plate, no text
