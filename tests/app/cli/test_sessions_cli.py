"""`semanticxr sessions`: list, show, export, import and delete against a real server."""

from __future__ import annotations

import asyncio
import json
import os
import re
import subprocess
import sys

import httpx
import numpy as np
import pytest
from analytic_world import KITCHEN
from devices import frame_message, stream_in_step

from app.cli import main
from app.cli.sessions import change_words, table
from app.protocol import SessionSummary

API_KEY = "cli-test-key"
KNOBS = {"keyframe_interval": 1, "min_observations": 2, "local_map_update_frequency": 1}
ON_TABLE = {"relation": "on", "id": 3, "label": "dining table"}
ON_DESK = {"relation": "on", "id": 4, "label": "desk"}
NEAR_SOFA = {"relation": "near", "id": 5, "label": "sofa"}
LONG_NAME = "a kitchen with a name far too long for any narrow terminal column at all"


@pytest.fixture
def server(live_server, monkeypatch):
    monkeypatch.setenv("SEMANTICXR_API_KEY", API_KEY)  # the default of --api-key
    return live_server(api_key=API_KEY)


def mapped_session(server) -> str:
    headers = {"Authorization": f"Bearer {API_KEY}"}
    sid = httpx.post(
        f"{server.url}/v1/sessions", json={"name": LONG_NAME, "knobs": KNOBS}, headers=headers
    ).json()["session_id"]
    frames = [frame_message(list(KITCHEN), i, cam_xy=(0.02 * i, 0.0)) for i in range(5)]
    asyncio.run(stream_in_step(f"{server.ws_url}/v1/sessions/{sid}/stream", frames, headers))
    return sid


def test_sessions_list_prints_a_table_that_fits_the_terminal(server):
    sid = mapped_session(server)
    env = {**os.environ, "COLUMNS": "80"}
    result = subprocess.run(
        [sys.executable, "-m", "app.cli", "sessions", "list", "--server", server.url],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
    )
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[0].split() == ["SESSION", "NAME", "MODE", "OBJECTS", "KEYFRAMES", "FRAMES"]
    assert lines[1].startswith(sid) and "…" in lines[1]
    assert all(len(line) <= 80 for line in lines)
    assert lines[1].split()[-3:] == [str(n) for n in _figures(server, sid)]


def _figures(server, sid: str) -> tuple[int, int, int]:
    stats = httpx.get(
        f"{server.url}/v1/sessions/{sid}", headers={"Authorization": f"Bearer {API_KEY}"}
    ).json()
    return stats["objects"], stats["keyframes"], stats["frames"]


def test_sessions_list_json_is_the_servers_answer(server, capsys):
    sid = mapped_session(server)
    assert main(["sessions", "list", "--server", server.url, "--json"]) == 0
    (row,) = json.loads(capsys.readouterr().out)
    assert row["session_id"] == sid and row["name"] == LONG_NAME


def test_a_table_stays_within_narrow_and_wide_terminals():
    rows = [
        SessionSummary(
            session_id="0" * 16,
            name=LONG_NAME,
            mode="semanticxr",
            objects=3,
            frames=10,
            keyframes=2,
            fps=0.0,
            update_seq=4,
        )
    ]
    for width in (70, 80, 200):
        assert all(len(line) <= width for line in table(rows, width).splitlines())
    assert LONG_NAME in table(rows, 200)


def test_sessions_export_writes_the_json_and_the_ply(server, tmp_path, capsys):
    import open3d as o3d

    sid = mapped_session(server)
    out_json, out_ply = tmp_path / "map.json", tmp_path / "map.ply"
    args = ["--server", server.url]
    assert main(["sessions", "export", sid, "--out", str(out_json), *args]) == 0
    assert main(["sessions", "export", sid, "--out", str(out_ply), "--format", "ply", *args]) == 0
    export = json.loads(out_json.read_text())
    assert export["format"] == "semanticxr-map" and export["objects"]
    cloud = o3d.t.io.read_point_cloud(str(out_ply))
    ids = cloud.point["object_id"].numpy().ravel()
    assert len(ids) == sum(len(o["points"]) for o in export["objects"])
    assert set(np.unique(ids)) == {o["id"] for o in export["objects"]}

    # import, then the imported session exports the same file
    capsys.readouterr()
    assert main(["sessions", "import", str(out_json), "--json", *args]) == 0
    new_sid = json.loads(capsys.readouterr().out)["session_id"]
    again = tmp_path / "again.json"
    assert main(["sessions", "export", new_sid, "--out", str(again), *args]) == 0
    assert again.read_bytes() == out_json.read_bytes()

    assert main(["sessions", "delete", new_sid, *args]) == 0
    assert main(["sessions", "show", sid, "--json", *args]) == 0
    capsys.readouterr()
    with pytest.raises(SystemExit):
        main(["sessions", "show", new_sid, *args])
    assert "HTTP 403" in capsys.readouterr().err  # deleted


def test_an_export_of_an_unknown_session_fails_and_writes_nothing(server, tmp_path, capsys):
    out = tmp_path / "map.json"
    with pytest.raises(SystemExit) as exit_:
        main(["sessions", "export", "nosuchsession", "--out", str(out), "--server", server.url])
    assert exit_.value.code == 1
    assert "HTTP 403" in capsys.readouterr().err
    assert not out.exists() and not list(tmp_path.glob("*.part"))


def test_an_import_over_the_body_limit_names_the_flag(live_server, tmp_path, capsys):
    server = live_server(max_body_bytes=1000)
    out = tmp_path / "big.json"
    out.write_text(json.dumps({"format": "semanticxr-map", "padding": "x" * 2000}))
    with pytest.raises(SystemExit):
        main(["sessions", "import", str(out), "--server", server.url])
    assert "--max-body-bytes" in capsys.readouterr().err


# --- recent changes ----------------------------------------------------------------------


def test_sessions_show_lists_the_recent_changes_in_words(server, capsys):
    import living_world as scene

    headers = {"Authorization": f"Bearer {API_KEY}"}
    sid = httpx.post(
        f"{server.url}/v1/sessions", json={"name": "room", "knobs": scene.KNOBS}, headers=headers
    ).json()["session_id"]
    url = f"{server.ws_url}/v1/sessions/{sid}/stream"
    for walk in (scene.walk(scene.BEFORE, 0.0), scene.walk(scene.AFTER, scene.WALK_2_T)):
        acks = asyncio.run(stream_in_step(url, walk, headers))
        assert all(a["type"] == "ack" for a in acks), acks

    assert main(["sessions", "show", sid, "--server", server.url]) == 0
    out = capsys.readouterr().out
    stats, changes = out.split("recent changes", 1)
    assert "keyframes" in stats
    lines = [line.strip() for line in changes.splitlines()[1:]]
    # each "<label> <kind> <place>, <ago>"; the walk goes on for a few seconds after them
    ago = r", (just now|\d s ago)"
    for expected in (
        "mug moved near the cardboard box",
        "book removed from near the cardboard box",
        "cardboard box added near the whiteboard",
        "potted plant added near the cardboard box",
    ):
        assert sum(bool(re.fullmatch(expected + ago, line)) for line in lines) == 1, lines
    assert len(lines) == 4

    assert main(["sessions", "show", sid, "--json", "--server", server.url]) == 0
    shown = json.loads(capsys.readouterr().out)
    assert shown["session_id"] == sid and shown["recent_changes"]["now_t"] == scene.WALK_2_T + 6
    listed = shown["recent_changes"]["changes"]
    assert {(c["label"], c["kind"]) for c in listed} == {
        ("mug", "moved"),
        ("book", "removed"),
        ("cardboard box", "added"),
        ("potted plant", "added"),
    }
    assert all(c["place"]["relation"] == "near" for c in listed)


def test_sessions_show_of_a_session_without_changes_says_none(server, capsys):
    sid = mapped_session(server)
    assert main(["sessions", "show", sid, "--server", server.url]) == 0
    assert re.search(r"^recent changes\s+none$", capsys.readouterr().out, re.M)


@pytest.mark.parametrize(
    ("change", "now_t", "words"),
    [
        (
            {"label": "mug", "kind": "moved", "t": 0.0, "place": ON_TABLE},
            600.0,
            "mug moved on the dining table, 10 min ago",
        ),
        (
            {"label": "laptop", "kind": "removed", "t": 10.0, "place": ON_DESK},
            190.0,
            "laptop removed from the desk, 3 min ago",
        ),
        (
            {"label": "cardboard box", "kind": "added", "t": 10.0, "place": NEAR_SOFA},
            12.0,
            "cardboard box added near the sofa, just now",
        ),
        (
            {"label": "book", "kind": "removed", "t": 0.0, "place": NEAR_SOFA},
            40.0,
            "book removed from near the sofa, 40 s ago",
        ),
        (
            {"label": "keys", "kind": "moved", "t": 0.0, "place": None},
            7200.0,
            "keys moved, 2 h ago",
        ),
        ({"label": "keys", "kind": "added", "t": 5.0}, None, "keys added"),  # an older server
        ({"label": "keys", "kind": "added", "t": 9.0, "place": None}, 5.0, "keys added, just now"),
    ],
)
def test_a_change_in_words(change, now_t, words):
    assert change_words(change, now_t) == words
