"""The living map through a real server on loopback: walk, change the room, walk again ten
minutes later; the map follows, dates what changed, remembers where things were, tells a
subscriber, and keeps it all across a restart."""

from __future__ import annotations

import asyncio
import math

import httpx
import msgpack
import numpy as np
import pytest
import websockets
from devices import TIMEOUT_S, stream_in_step
from helpers_device import assert_local_map_equals
from living_world import AFTER, BEFORE, KNOBS, WALK_2_T, frame, walk

from client_sim.local_map import LocalMap

pytestmark = pytest.mark.timeout(180)


def by_label(objects: list[dict]) -> dict[str, list[dict]]:
    out: dict[str, list[dict]] = {}
    for obj in objects:
        out.setdefault(obj["label"], []).append(obj)
    return out


async def subscribe_until(url: str, local_map: LocalMap, seq: int) -> list[dict]:
    """Apply deltas to the local map until it reaches `seq`; the deltas' changes."""
    changes: list[dict] = []
    async with websockets.connect(url, max_size=None) as ws:
        while True:
            message = msgpack.unpackb(await asyncio.wait_for(ws.recv(), TIMEOUT_S))
            local_map.apply_delta(message)
            changes += message.get("changes", [])
            if message["seq"] >= seq:
                return changes


@pytest.fixture
def revisited(live_server):
    """A server that mapped the first walk, then the second; (server, sid, walk-1 seq,
    the deltas' changes, the subscriber's local map)."""
    server = live_server()
    sid = httpx.post(f"{server.url}/v1/sessions", json={"knobs": KNOBS}, timeout=10).json()[
        "session_id"
    ]
    stream_url = f"{server.ws_url}/v1/sessions/{sid}/stream"
    acks = asyncio.run(stream_in_step(stream_url, walk(BEFORE, 0.0)))
    assert all(a["type"] == "ack" for a in acks), acks
    first_seq = acks[-1]["update_seq"]
    local_map = LocalMap(max_points_per_object=KNOBS.get("max_object_points_client", 200))

    async def second_walk() -> tuple[list[dict], list[dict]]:
        updates = f"{server.ws_url}/v1/sessions/{sid}/updates?since=0"
        catch_up = asyncio.create_task(subscribe_until(updates, local_map, first_seq))
        await catch_up
        acks = await stream_in_step(stream_url, walk(AFTER, WALK_2_T))
        seq = acks[-1]["update_seq"]
        changes = await subscribe_until(
            f"{server.ws_url}/v1/sessions/{sid}/updates?since={first_seq}", local_map, seq
        )
        return acks, changes

    acks, changes = asyncio.run(second_walk())
    assert all(a["type"] == "ack" for a in acks), acks
    return server, sid, first_seq, changes, local_map


def get(server, path: str, **params):
    return httpx.get(f"{server.url}/v1/sessions/{path}", params=params, timeout=10)


def test_the_map_follows_a_changed_room_and_keeps_its_history(revisited, live_server):
    server, sid, _, delta_changes, local_map = revisited
    objects = by_label(get(server, f"{sid}/objects").json())

    # moved: one mug, at its new place, with its old id; the book gone; the bin kept
    (mug,) = objects["mug"]
    assert np.allclose(mug["centroid"][:2], [0.6, 0.4], atol=0.05)
    assert "book" not in objects and len(objects["trash can"]) == 1
    assert mug["first_seen_t"] == 0.0 and mug["last_seen_t"] >= WALK_2_T
    assert objects["trash can"][0]["last_seen_t"] < WALK_2_T  # hidden since

    changes = get(server, f"{sid}/changes").json()["changes"]
    kinds = {(c["label"], c["kind"]) for c in changes}
    assert ("mug", "moved") in kinds and ("book", "removed") in kinds
    assert ("cardboard box", "added") in kinds and ("potted plant", "added") in kinds
    assert not any(c["label"] == "trash can" for c in changes)  # occlusion is no evidence
    # dated within 3 s of the first keyframe that showed the evidence (the first of walk 2)
    assert all(WALK_2_T <= c["t"] <= WALK_2_T + 3 for c in changes)
    moved = next(c for c in changes if c["kind"] == "moved")
    assert moved["id"] == mug["id"]
    assert np.allclose(moved["from"][:2], [-0.4, -0.1], atol=0.05)
    assert np.allclose(moved["to"][:2], [0.6, 0.4], atol=0.05)

    # where, in words, against the present map (up is -y here: the cameras' up)
    box_id = objects["cardboard box"][0]["id"]
    near_box = {"relation": "near", "id": box_id, "label": "cardboard box"}
    places = {(c["label"], c["kind"]): c["place"] for c in changes}
    assert places["mug", "moved"] == near_box  # its new place
    assert places["book", "removed"] == near_box  # where it was
    assert places["cardboard box", "added"]["label"] == "whiteboard"  # never itself
    # the subscriber heard every change and holds exactly the server's map
    assert {(c["id"], c["kind"]) for c in delta_changes} == {(c["id"], c["kind"]) for c in changes}
    served = get(server, f"{sid}/objects", points="true").json()
    assert_local_map_equals(local_map, served, 200)
    assert local_map.get(mug["id"])["last_seen_t"] == mug["last_seen_t"]

    # removed, not forgotten
    (book,) = [
        o for o in get(server, f"{sid}/objects", include="removed").json() if o["label"] == "book"
    ]
    assert book["state"] == "removed" and book["last_seen_t"] == 6.0
    answer = get(server, f"{sid}/query", text="where did I leave my book", include="removed", k=3)
    top = answer.json()["results"][0]
    assert (top["id"], top["state"], top["last_seen_t"]) == (book["id"], "removed", 6.0)
    assert top["place"] == near_box
    assert answer.json()["now_t"] == WALK_2_T + 6
    plain = get(server, f"{sid}/query", text="where did I leave my book", k=3).json()
    assert all(hit["state"] == "present" for hit in plain["results"])

    history = get(server, f"{sid}/objects/{mug['id']}/history").json()
    assert history["state"] == "present" and len(history["stays"]) == 2
    assert history["stays"][0]["t_to"] < WALK_2_T <= history["stays"][1]["t_from"]
    book_history = get(server, f"{sid}/objects/{book['id']}/history").json()
    assert book_history["state"] == "removed" and book_history["stays"][-1]["t_to"] == 6.0

    # filters
    assert [c["kind"] for c in get(server, f"{sid}/changes", kind="moved").json()["changes"]] == [
        "moved"
    ]
    assert get(server, f"{sid}/changes", since_t=WALK_2_T + 100).json()["changes"] == []
    assert get(server, f"{sid}/changes", until_t=WALK_2_T - 1).json()["changes"] == []

    # everything survives a restart
    server.stop()
    again = live_server()
    assert get(again, f"{sid}/changes").json()["changes"] == changes
    assert get(again, f"{sid}/objects/{mug['id']}/history").json() == history
    assert by_label(get(again, f"{sid}/objects").json())["mug"][0]["id"] == mug["id"]
    present = get(again, f"{sid}/objects").json()
    assert len(get(again, f"{sid}/objects", include="removed").json()) == len(present) + 1
    assert get(again, f"{sid}/query", text="book").json()["now_t"] == WALK_2_T + 6


@pytest.mark.parametrize(
    ("path", "params", "field"),
    [
        ("changes", {"since_t": "nan"}, "since_t"),
        ("changes", {"until_t": "inf"}, "until_t"),
        ("changes", {"since_t": "yesterday"}, "since_t"),
        ("changes", {"kind": "teleported"}, "kind"),
        ("changes", {"since_seq": "-1"}, "since_seq"),
        ("objects", {"include": "everything"}, "include"),
        ("query", {"text": "mug", "include": "ghosts"}, "include"),
    ],
)
def test_bad_history_parameters_get_422_naming_them(live_server, path, params, field):
    server = live_server()
    sid = httpx.post(f"{server.url}/v1/sessions", json={}, timeout=10).json()["session_id"]
    answer = get(server, f"{sid}/{path}", **params)
    assert answer.status_code == 422, answer.text
    assert field in answer.text


def test_history_of_an_unknown_object_is_404(live_server):
    server = live_server()
    sid = httpx.post(f"{server.url}/v1/sessions", json={}, timeout=10).json()["session_id"]
    assert get(server, f"{sid}/objects/12345/history").status_code == 404


def test_a_frame_whose_time_goes_backwards_is_mapped_and_history_keeps_arrival_order(
    live_server,
):
    server = live_server()
    sid = httpx.post(f"{server.url}/v1/sessions", json={"knobs": KNOBS}, timeout=10).json()[
        "session_id"
    ]
    url = f"{server.ws_url}/v1/sessions/{sid}/stream"
    frames = [frame(BEFORE, seq=i, t=100.0 - i, cam_x=0.03 * i) for i in range(4)]
    acks = asyncio.run(stream_in_step(url, frames))
    assert [a["type"] for a in acks] == ["ack"] * 4
    (mug,) = by_label(get(server, f"{sid}/objects").json())["mug"]
    assert (mug["first_seen_t"], mug["last_seen_t"]) == (100.0, 97.0)  # arrival order
    assert math.isfinite(get(server, f"{sid}/query", text="mug").json()["now_t"])


@pytest.mark.slow
def test_changes_and_history_acknowledged_survive_kill_9(tmp_path):
    from app.server.runner import ServerProcess, free_port

    port = free_port()
    server = ServerProcess(tmp_path, port).start()
    try:
        sid = httpx.post(f"{server.url}/v1/sessions", json={"knobs": KNOBS}, timeout=10).json()[
            "session_id"
        ]
        url = f"{server.ws_url}/v1/sessions/{sid}/stream"
        acks = asyncio.run(stream_in_step(url, walk(BEFORE, 0.0) + walk(AFTER, WALK_2_T)))
        assert all(a["type"] == "ack" for a in acks)  # every keyframe acknowledged: durable
        seen = {
            "changes": get(server, f"{sid}/changes").json(),
            "objects": get(server, f"{sid}/objects", include="removed", points="true").json(),
        }
        seen["histories"] = [
            get(server, f"{sid}/objects/{o['id']}/history").json() for o in seen["objects"]
        ]
        assert {c["kind"] for c in seen["changes"]["changes"]} == {"moved", "removed", "added"}
        server.kill9()
        server = ServerProcess(tmp_path, port).start()
        assert get(server, f"{sid}/changes").json() == seen["changes"]
        assert (
            get(server, f"{sid}/objects", include="removed", points="true").json()
            == seen["objects"]
        )
        assert [
            get(server, f"{sid}/objects/{o['id']}/history").json() for o in seen["objects"]
        ] == seen["histories"]
    finally:
        server.stop()
