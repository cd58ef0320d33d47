"""Export and import of a map through a real server: JSON round trip, PLY, validation."""

from __future__ import annotations

import asyncio
import copy

import httpx
import numpy as np
import pytest
from analytic_world import KITCHEN
from devices import frame_message, stream_in_step

from app.protocol.rest import MapExport

KNOBS = {"keyframe_interval": 1, "min_observations": 2, "local_map_update_frequency": 1}
API_KEY = "export-test-key"


def mapped_session(server, frames: int = 6) -> str:
    """A session of the server with the analytic kitchen mapped (confirmed objects)."""
    headers = {"Authorization": f"Bearer {API_KEY}"}
    sid = httpx.post(
        f"{server.url}/v1/sessions", json={"name": "kitchen", "knobs": KNOBS}, headers=headers
    ).json()["session_id"]
    messages = [frame_message(list(KITCHEN), i, cam_xy=(0.02 * i, 0.0)) for i in range(frames)]
    replies = asyncio.run(
        stream_in_step(f"{server.ws_url}/v1/sessions/{sid}/stream", messages, headers)
    )
    assert [r["type"] for r in replies] == ["ack"] * frames
    return sid


@pytest.fixture
def server(live_server):
    return live_server(api_key=API_KEY)


@pytest.fixture
def http(server):
    with httpx.Client(
        base_url=server.url, headers={"Authorization": f"Bearer {API_KEY}"}, timeout=30
    ) as client:
        yield client


@pytest.mark.parametrize("embeddings", [False, True])
def test_export_import_export_gives_the_same_map(server, http, encoder, embeddings):
    sid = mapped_session(server)
    params = {"format": "json", "embeddings": str(embeddings).lower()}
    first = http.get(f"/v1/sessions/{sid}/export", params=params)
    assert first.status_code == 200, first.text
    export = first.json()
    MapExport.model_validate(export, strict=True)  # the body is what the protocol defines
    assert export["format"] == "semanticxr-map" and export["version"] == 1
    assert export["session"]["name"] == "kitchen"
    objects = export["objects"]
    assert objects and [o["id"] for o in objects] == sorted(o["id"] for o in objects)
    assert all(("embedding" in o) == embeddings for o in objects)
    # Full server resolution: more points than the client cap the objects list sends.
    listed = http.get(f"/v1/sessions/{sid}/objects", params={"points": "true"}).json()
    assert sum(len(o["points"]) for o in objects) > sum(len(o["points"]) for o in listed)
    assert [o["label"] for o in objects] == [o["label"] for o in listed]

    created = http.post("/v1/sessions/import", json=export)
    assert created.status_code == 201, created.text
    new_sid = created.json()["session_id"]
    assert new_sid != sid
    again = http.get(f"/v1/sessions/{new_sid}/export", params=params)
    assert again.content == first.content

    # The imported map is a map: listed, queried, and kept across a restart.
    stats = http.get(f"/v1/sessions/{new_sid}").json()
    assert stats["objects"] == len(objects) and stats["update_seq"] == 1
    hits = http.get(f"/v1/sessions/{new_sid}/query", params={"text": objects[0]["label"]})
    assert hits.json()["results"][0]["label"] == objects[0]["label"]
    server.stop()
    restarted = server.__class__(server.settings.data_dir, encoder, api_key=API_KEY)
    try:
        after = httpx.get(
            f"{restarted.url}/v1/sessions/{new_sid}/export",
            params=params,
            headers={"Authorization": f"Bearer {API_KEY}"},
            timeout=30,
        )
        assert after.content == first.content
    finally:
        restarted.stop()


def test_the_ply_holds_every_exported_point_with_its_object_id(server, http, tmp_path):
    import open3d as o3d

    sid = mapped_session(server)
    objects = http.get(f"/v1/sessions/{sid}/export").json()["objects"]
    answer = http.get(f"/v1/sessions/{sid}/export", params={"format": "ply"})
    assert answer.status_code == 200
    assert answer.content.startswith(b"ply\nformat binary_little_endian 1.0\n")
    path = tmp_path / "map.ply"
    path.write_bytes(answer.content)

    cloud = o3d.t.io.read_point_cloud(str(path))
    expected_ids = np.concatenate([np.full(len(o["points"]), o["id"]) for o in objects])
    expected_points = np.concatenate([o["points"] for o in objects])
    assert len(cloud.point.positions) == len(expected_ids)
    np.testing.assert_array_equal(cloud.point["object_id"].numpy().ravel(), expected_ids)
    np.testing.assert_allclose(cloud.point.positions.numpy(), expected_points, atol=1e-5)
    colours = cloud.point.colors.numpy()
    by_label: dict[str, set] = {}
    for o, start in zip(
        objects, np.cumsum([0, *(len(o["points"]) for o in objects)]), strict=False
    ):
        by_label.setdefault(o["label"], set()).add(tuple(colours[start]))
    assert all(len(c) == 1 for c in by_label.values())  # one colour per label
    assert len(o3d.io.read_point_cloud(str(path)).points) == len(expected_ids)


def a_valid_export(http, server) -> dict:
    sid = mapped_session(server, frames=4)
    return http.get(f"/v1/sessions/{sid}/export").json()


@pytest.mark.parametrize(
    ("spoil", "field"),
    [
        (lambda e: e.update(format="other"), "format"),
        (lambda e: e.update(version=2), "version"),
        (lambda e: e["session"]["embedding"].update(dim=512), "session.embedding.dim"),
        (lambda e: e["objects"][0]["points"][0].__setitem__(0, "NaN"), "objects.0.points"),
        (lambda e: e["objects"].insert(1, copy.deepcopy(e["objects"][0])), "objects[1].id"),
        (lambda e: e["objects"][0].update(embedding=[0.1] * 5), "objects[0].embedding"),
        (lambda e: e["objects"][0].update(embedding=[]), "objects.0.embedding"),  # was a 500
    ],
    ids=["format", "version", "dim", "nan", "duplicate-id", "embedding-length", "embedding-empty"],
)
def test_a_bad_import_is_refused_naming_the_field(server, http, spoil, field):
    export = a_valid_export(http, server)
    before = len(http.get("/v1/sessions").json())
    spoil(export)
    answer = http.post(
        "/v1/sessions/import",
        content=httpx.Request("POST", "/", json=export).content.replace(b'"NaN"', b"NaN"),
        headers={"Content-Type": "application/json"},
    )
    assert answer.status_code == 422, answer.text
    assert field in answer.json()["detail"]
    assert len(http.get("/v1/sessions").json()) == before  # nothing left behind


def test_import_needs_the_api_key(server):
    answer = httpx.post(f"{server.url}/v1/sessions/import", json={})
    assert answer.status_code == 401
