"""A session's up axis through a real server on loopback: set at creation (422 naming `up`
otherwise), inferred from the poses of the keyframes it receives (XR style Y-up, our
synthetic Z-up walk), reported on the session record, kept across a restart on the real
SQLite file, carried by export and import, and used by relational questions."""

from __future__ import annotations

import asyncio
import math
import sqlite3
from pathlib import Path

import httpx
import numpy as np
import pytest
from devices import stream_in_step
from relation_scene import SCENE, TO_Y_UP, map_export

from app.mapping.places import UP_STABLE_KEYFRAMES
from app.protocol.rest import QueryResult
from app.server.settings import STORE_FILE
from client_sim.encoder import FrameEncoder
from world.rooms import make_scene
from world.trajectory import walk_trajectory

pytestmark = pytest.mark.timeout(180)

API_KEY = "up-test-key"
KNOBS = {"keyframe_interval": 1}


def look(forward, world_up, position=(0.0, 0.0, 0.0)) -> np.ndarray:
    """A camera-to-world pose (OpenCV camera: x right, y down, z forward) looking along
    `forward`, its right side level with `world_up`'s horizon."""
    forward = np.asarray(forward, np.float64) / np.linalg.norm(forward)
    right = np.cross(forward, world_up)
    right /= np.linalg.norm(right)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2] = right, np.cross(forward, right), forward
    pose[:3, 3] = position
    return pose


def xr_poses(n: int, seed: int = 0) -> list[np.ndarray]:
    """`n` poses of a headset in a Y-up world (OpenXR's): looking about the room, pitched
    from 35° down to 10° up, standing 1.6 m above the floor."""
    rng = np.random.default_rng(seed)
    poses = []
    for _ in range(n):
        yaw, pitch = rng.uniform(0, 2 * math.pi), math.radians(rng.uniform(-35, 10))
        horizontal = np.array([math.sin(yaw), 0.0, -math.cos(yaw)])
        forward = math.cos(pitch) * horizontal + math.sin(pitch) * np.array([0.0, 1.0, 0.0])
        poses.append(look(forward, [0.0, 1.0, 0.0], (2.0, 1.6, -1.5)))
    return poses


def posed_frames(poses: list[np.ndarray]) -> list[dict]:
    """One v1 frame per pose: no depth and no detections (only the pose matters here)."""
    encoder = FrameEncoder(2, depth_codec="zstd")
    rgb = np.full((48, 64, 3), 128, np.uint8)
    depth = np.zeros((48, 64), np.float32)
    return [
        encoder.encode(seq, seq / 30, rgb, depth, pose, (60.0, 60.0, 31.5, 23.5)).message
        for seq, pose in enumerate(poses)
    ]


@pytest.fixture
def server(live_server):
    return live_server(api_key=API_KEY)


def client(server) -> httpx.Client:
    return httpx.Client(
        base_url=server.url, headers={"Authorization": f"Bearer {API_KEY}"}, timeout=60
    )


@pytest.fixture
def http(server):
    with client(server) as c:
        yield c


def stream_poses(server, sid: str, poses: list[np.ndarray]) -> None:
    replies = asyncio.run(
        stream_in_step(
            f"{server.ws_url}/v1/sessions/{sid}/stream",
            posed_frames(poses),
            {"Authorization": f"Bearer {API_KEY}"},
        )
    )
    assert [r["type"] for r in replies] == ["ack"] * len(poses), replies


def up_of(http: httpx.Client, sid: str) -> tuple[str, str]:
    """(up, up_source) as the session's record says, checked against the list's entry."""
    record = http.get(f"/v1/sessions/{sid}").json()
    (listed,) = [s for s in http.get("/v1/sessions").json() if s["session_id"] == sid]
    assert (listed["up"], listed["up_source"]) == (record["up"], record["up_source"])
    return record["up"], record["up_source"]


def created(http: httpx.Client, **body) -> str:
    reply = http.post("/v1/sessions", json={"knobs": KNOBS, **body})
    assert reply.status_code == 201, reply.text
    return reply.json()["session_id"]


# ---------------------------------------------------------------------- set at creation
@pytest.mark.parametrize("up", ["+x", "-x", "+y", "-y", "+z", "-z"])
def test_a_session_may_set_its_up(http, up):
    sid = created(http, up=up)
    assert up_of(http, sid) == (up, "set")


def test_without_a_setting_up_is_z_by_default_until_the_poses_say(http):
    assert up_of(http, created(http)) == ("+z", "default")


@pytest.mark.parametrize("up", ["y", "+Y", "up", "z+", "", 1, None, ["+y"]])
def test_an_up_that_is_not_an_axis_gets_422_naming_up(http, up):
    before = len(http.get("/v1/sessions").json())
    reply = http.post("/v1/sessions", json={"up": up})
    if up is None:  # JSON null: no setting
        assert reply.status_code == 201, reply.text
        return
    assert reply.status_code == 422, reply.text
    assert reply.json()["detail"].startswith("up:"), reply.json()
    assert len(http.get("/v1/sessions").json()) == before


def test_a_set_up_survives_a_restart_on_the_sqlite_file(server, live_server, tmp_path):
    with client(server) as http:
        sid = created(http, up="-x")
        stream_poses(server, sid, xr_poses(UP_STABLE_KEYFRAMES + 2))  # poses never override it
        assert up_of(http, sid) == ("-x", "set")
    server.stop()
    rows = sqlite_rows(tmp_path / "data" / STORE_FILE)
    assert rows[sid] == ("-x", "set")
    again = live_server(api_key=API_KEY)
    with client(again) as http:
        assert up_of(http, sid) == ("-x", "set")


def sqlite_rows(path: Path) -> dict[str, tuple]:
    with sqlite3.connect(path) as db:
        return {
            sid: (up, source)
            for sid, up, source in db.execute("SELECT session_id, up, up_source FROM sessions")
        }


# ---------------------------------------------------------------------- inferred from poses
def test_up_is_inferred_from_xr_poses_and_kept_across_a_restart(server, live_server, tmp_path):
    with client(server) as http:
        sid = created(http)
        stream_poses(server, sid, xr_poses(UP_STABLE_KEYFRAMES - 1))
        assert up_of(http, sid) == ("+z", "default")  # not settled yet
        stream_poses(server, sid, xr_poses(2, seed=1))
        assert up_of(http, sid) == ("+y", "inferred")
    server.stop()
    assert sqlite_rows(tmp_path / "data" / STORE_FILE)[sid] == ("+y", "inferred")
    again = live_server(api_key=API_KEY)
    with client(again) as http:
        assert up_of(http, sid) == ("+y", "inferred")
        # settled: poses of another world never flip it
        z_up = [look([1.0, 0.0, -0.3], [0.0, 0.0, 1.0])] * (3 * UP_STABLE_KEYFRAMES)
        stream_poses(again, sid, z_up)
        assert up_of(http, sid) == ("+y", "inferred")


def test_up_is_inferred_from_our_synthetic_z_up_walk(server, http):
    sid = created(http)
    walk = walk_trajectory(make_scene("apartment", 0), 3 * UP_STABLE_KEYFRAMES, seed=3)
    stream_poses(server, sid, walk)
    assert up_of(http, sid) == ("+z", "inferred")


def test_a_few_tilted_poses_do_not_settle_or_flip_up(server, http):
    """A device that starts looking straight down at the floor (its up then points along the
    floor, +x here) still settles +y, this Y-up world's up, once it looks about the room."""
    sid = created(http)
    at_the_floor = look([0.0, -1.0, 0.0], [1.0, 0.0, 0.0])
    assert np.allclose(-at_the_floor[:3, 1], [1.0, 0.0, 0.0])
    stream_poses(server, sid, [at_the_floor] * 3)
    assert up_of(http, sid) == ("+z", "default")
    stream_poses(server, sid, xr_poses(UP_STABLE_KEYFRAMES))
    assert up_of(http, sid) == ("+z", "default")  # the mean still leans on the floor's look
    stream_poses(server, sid, xr_poses(2 * UP_STABLE_KEYFRAMES, seed=2))
    assert up_of(http, sid) == ("+y", "inferred")


# ---------------------------------------------------------------------- export and import
def test_export_carries_a_settled_up_and_import_keeps_it(server, http):
    for body, expected in [({"up": "-y"}, ("-y", "set")), ({}, ("+y", "inferred"))]:
        sid = created(http, **body)
        stream_poses(server, sid, xr_poses(UP_STABLE_KEYFRAMES))
        export = http.get(f"/v1/sessions/{sid}/export").json()
        assert (export["session"]["up"], export["session"]["up_source"]) == expected
        imported = http.post("/v1/sessions/import", json=export)
        assert imported.status_code == 201, imported.text
        assert up_of(http, imported.json()["session_id"]) == expected
    unsettled = http.get(f"/v1/sessions/{created(http)}/export").json()
    assert "up" not in unsettled["session"] and "up_source" not in unsettled["session"]
    unsettled["session"]["up"] = "sideways"
    refused = http.post("/v1/sessions/import", json=unsettled)
    assert refused.status_code == 422 and "session.up" in refused.json()["detail"]


# ---------------------------------------------------------------------- relations
def y_up_scene_export() -> dict:
    """tests/relation_scene.py's room turned Y-up, as an import (no poses: default up)."""
    return map_export(SCENE, "relations, Y-up", KNOBS, turn=TO_Y_UP)


QUESTIONS = [
    ("the mug on the desk", 10, "on", 1),
    ("which chair is next to the sofa", 21, "next_to", 4),
    ("what is under the table", 30, "under", 3),
]


def ask(http, sid, text) -> QueryResult:
    reply = http.get(f"/v1/sessions/{sid}/query", params={"text": text, "points": "false"})
    assert reply.status_code == 200, reply.text
    return QueryResult.model_validate(reply.json(), strict=True)


def test_relational_questions_on_a_y_up_map_answer_right_without_a_setting(server, http):
    created_ = http.post("/v1/sessions/import", json=y_up_scene_export())
    assert created_.status_code == 201, created_.text
    sid = created_.json()["session_id"]
    # measured along z (the default), the Y-up room's tables stand on their sides
    wrong = [ask(http, sid, text).results[0] for text, *_ in QUESTIONS]
    assert [(h.id, h.relation and h.relation.kind) for h in wrong] != [
        (expected, kind) for _, expected, kind, _ in QUESTIONS
    ]
    stream_poses(server, sid, xr_poses(UP_STABLE_KEYFRAMES))
    assert up_of(http, sid) == ("+y", "inferred")
    for text, expected, kind, anchor in QUESTIONS:
        result = ask(http, sid, text)
        best = result.results[0]
        assert best.id == expected, (text, [(h.id, h.label) for h in result.results])
        assert best.relation is not None and best.relation.kind == kind
        assert [(a.id, a.label) for a in best.relation.anchors] == [(anchor, SCENE[anchor][0])]
        assert result.match
        # places are told along the same up: the mug rests on the desk
        if text == "the mug on the desk":
            assert best.place is not None and (best.place.relation, best.place.id) == ("on", 1)
    assert not ask(http, sid, "the mug under the sofa").match
