"""Export and import of a map through a real server: JSON round trip, PLY, validation."""

from __future__ import annotations

import asyncio
import copy

import httpx
import numpy as np
import pytest
from analytic_world import KITCHEN
from devices import frame_message, stream_in_step

from app.mapping.object import MAX_STAYS
from app.protocol.rest import MAX_EXPORTED_STAYS, MapExport

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
    # The living map's history: a first look removes nothing and concludes no change.
    assert export["removed_objects"] == [] and export["changes"] == []
    assert all(o["first_seen_t"] <= o["last_seen_t"] and o["stays"] for o in objects)
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


def with_history(export: dict) -> dict:
    """`export` with a living map's history: its last object removed (kept as history), times
    and stays on the others, and changes over three update seqs (t going back once)."""
    export = copy.deepcopy(export)
    *objects, gone = export["objects"]
    for i, o in enumerate(objects):
        o.update(first_seen_t=10.0 + i / 3, last_seen_t=610.25 + i)
        o["stays"] = [
            {"t_from": 10.0, "t_to": 11.5, "centroid": [0.1, 0.2, 0.3], "bbox": [0, 0, 0, 1, 1, 1]},
            {"t_from": 600.0, "t_to": 610.25 + i, "centroid": o["centroid"], "bbox": o["bbox"]},
        ]
    gone.update(first_seen_t=10.0, last_seen_t=11.5)
    gone["stays"] = [
        {"t_from": 10.0, "t_to": 11.5, "centroid": gone["centroid"], "bbox": gone["bbox"]}
    ]
    first = objects[0]
    export["objects"], export["removed_objects"] = objects, [gone]
    export["changes"] = [
        {"id": first["id"], "kind": "moved", "t": 605.0, "label": first["label"],
         "from": [0.1, 0.2, 0.3], "to": first["centroid"], "seq": 3},
        {"id": gone["id"], "kind": "removed", "t": 604.5, "label": gone["label"],
         "from": gone["centroid"], "seq": 3},
        {"id": 999, "kind": "added", "t": 700.125, "label": "box", "to": [1.0, 2.0, 3.0],
         "seq": 8},
    ]  # fmt: skip
    return export


def test_the_history_of_a_living_map_survives_export_import_export_and_a_restart(
    server, http, encoder
):
    crafted = with_history(a_valid_export(http, server))
    MapExport.model_validate(crafted, strict=True)
    created = http.post("/v1/sessions/import", json=crafted)
    assert created.status_code == 201, created.text
    sid = created.json()["session_id"]
    first = http.get(f"/v1/sessions/{sid}/export")
    assert first.json() == crafted  # every field as imported (places already at 0.1 mm)

    again = http.post("/v1/sessions/import", json=first.json()).json()["session_id"]
    assert http.get(f"/v1/sessions/{again}/export").content == first.content

    # The removed object is history: out of the map, its id never reused.
    listed = http.get(f"/v1/sessions/{sid}/objects").json()
    assert [o["id"] for o in listed] == [o["id"] for o in crafted["objects"]]
    stats = http.get(f"/v1/sessions/{sid}").json()
    assert stats["objects"] == len(crafted["objects"]) and stats["update_seq"] == 8
    server.stop()
    restarted = server.__class__(server.settings.data_dir, encoder, api_key=API_KEY)
    try:
        after = httpx.get(
            f"{restarted.url}/v1/sessions/{sid}/export",
            headers={"Authorization": f"Bearer {API_KEY}"},
            timeout=30,
        )
        assert after.content == first.content
    finally:
        restarted.stop()


def test_an_export_holds_the_stays_the_map_keeps():
    assert MAX_EXPORTED_STAYS == MAX_STAYS


def test_an_export_from_before_the_living_map_imports(server, http):
    export = a_valid_export(http, server)
    for key in ("removed_objects", "changes"):
        del export[key]
    for o in export["objects"]:
        for key in ("first_seen_t", "last_seen_t", "stays"):
            o.pop(key, None)
    created = http.post("/v1/sessions/import", json=export)
    assert created.status_code == 201, created.text
    again = http.get(f"/v1/sessions/{created.json()['session_id']}/export").json()
    assert again == {**export, "removed_objects": [], "changes": []}


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


def a_valid_export(http, server, history: bool = False) -> dict:
    sid = mapped_session(server, frames=4)
    export = http.get(f"/v1/sessions/{sid}/export").json()
    return with_history(export) if history else export


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
        (lambda e: e["objects"][0].update(stays=e["objects"][0]["stays"] * 33), "objects.0.stays"),
        (lambda e: e["objects"][0]["stays"][0].update(t_to="NaN"), "objects.0.stays.0.t_to"),
        (
            lambda e: e["objects"][0]["stays"][0].update(centroid=[1e5, 0, 0]),
            "objects[0].stays[0]",
        ),
        (lambda e: e["objects"][0].update(last_seen_t="NaN"), "objects.0.last_seen_t"),
        (
            lambda e: e["removed_objects"][0].update(id=e["objects"][0]["id"]),
            "removed_objects[0].id",
        ),
        (
            lambda e: e["removed_objects"][0]["points"][0].__setitem__(0, 2e4),
            "removed_objects[0].points",
        ),
        (lambda e: e["changes"][2].update(seq=2), "changes[2].seq"),
        (lambda e: e["changes"][0].update(kind="teleported"), "changes.0.kind"),
        (lambda e: e["changes"][0].update(to=[0, 1]), "changes.0.to"),
        (lambda e: e["changes"][0].update(t="NaN"), "changes.0.t"),
    ],
    ids=[
        "format",
        "version",
        "dim",
        "nan",
        "duplicate-id",
        "embedding-length",
        "embedding-empty",
        "stays-over-32",
        "stay-nan",
        "stay-far",
        "last-seen-nan",
        "removed-id-twice",
        "removed-points-far",
        "changes-seq-back",
        "change-kind",
        "change-place",
        "change-t-nan",
    ],
)
def test_a_bad_import_is_refused_naming_the_field(server, http, spoil, field):
    export = a_valid_export(http, server, history=True)
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
