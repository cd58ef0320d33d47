"""The server through the real stack: uvicorn on loopback, HTTP and WebSockets."""

from __future__ import annotations

import asyncio
import contextlib

import httpx
import msgpack
import pytest
import websockets
from analytic_world import Rect
from devices import TIMEOUT_S, frame_message, send_and_collect, stream, stream_in_step

from app.codecs import float16_points_from_bytes
from app.protocol import PROTOCOL_VERSION

pytestmark = pytest.mark.timeout(120)

CHAIR = Rect(1, "chair", -0.6, -0.3, -0.1, 0.3, 2.0)
FRIDGE = Rect(2, "refrigerator", 0.1, -0.8, 0.9, 0.8, 2.5)
SCENE = [CHAIR, FRIDGE]
FAST = {
    "keyframe_interval": 1,
    "min_observations": 2,
    "min_mapping_bbox_area": 100,
    "local_map_update_frequency": 1,
}


def create(client: httpx.Client, headers=None, **body) -> dict:
    body.setdefault("knobs", FAST)
    r = client.post("/v1/sessions", json=body, headers=headers)
    assert r.status_code == 201, r.text
    return r.json()


def test_health_metrics_and_openapi_describe_the_service(live_server):
    server = live_server()
    with httpx.Client(base_url=server.url) as c:
        assert c.get("/healthz").json()["status"] == "ok"
        assert "semanticxr_sessions" in c.get("/metrics").text
        spec = c.get("/openapi.json").json()
        paths = spec["paths"]
    for path in (
        "/v1/sessions",
        "/v1/sessions/{sid}",
        "/v1/sessions/{sid}/knobs",
        "/v1/sessions/{sid}/objects",
        "/v1/sessions/{sid}/query",
    ):
        assert path in paths
    for path, methods in paths.items():  # every route documents its answer with a schema
        for method, op in methods.items():
            ok = next(v for k, v in op["responses"].items() if k.startswith("2"))
            if method != "delete" and path != "/metrics":
                content = ok.get("content", {})
                body = content.get("application/json", content.get("application/octet-stream"))
                assert "schema" in (body or {}), (method, path)
    assert "min_observations" in spec["components"]["schemas"]["Knobs"]["properties"]
    # the Authorize button of /docs: the API key, or a session's token under a session
    assert set(spec["components"]["securitySchemes"]) == {"apiKey", "sessionToken"}
    assert paths["/v1/sessions"]["post"]["security"] == [{"apiKey": []}]
    query_security = paths["/v1/sessions/{sid}/query"]["get"]["security"]
    assert query_security == [{"sessionToken": []}, {"apiKey": []}]
    assert "security" not in paths["/healthz"]["get"]


def test_session_lifecycle_and_knobs(live_server):
    server = live_server()
    with httpx.Client(base_url=server.url) as c:
        created = create(c, name="kitchen", mode="baseline")
        sid = created["session_id"]
        assert created["embedding"] == {"model": "all-MiniLM-L6-v2", "dim": 384}
        assert [s["session_id"] for s in c.get("/v1/sessions").json()] == [sid]
        assert c.get(f"/v1/sessions/{sid}").json()["mode"] == "baseline"
        r = c.patch(f"/v1/sessions/{sid}/knobs", json={"max_object_points_client": 50})
        assert r.status_code == 200 and r.json()["max_object_points_client"] == 50
        for body, named in (
            ({"warp_speed": 9}, "unknown knob 'warp_speed'; known knobs: "),
            ({"min_observations": -1}, "'min_observations' must be within"),
            ({"min_observations": "three"}, "'min_observations' must be a number"),
            ({"priority_class": 7}, "'priority_class' must be a list of strings"),
        ):
            r = c.patch(f"/v1/sessions/{sid}/knobs", json=body)
            assert r.status_code == 422 and named in str(r.json()["detail"]), (body, r.text)
        r = c.post("/v1/sessions", json={"knobs": {"nope": 1}})
        assert r.status_code == 422 and "unknown knob 'nope'" in str(r.json()["detail"])
        assert c.get(f"/v1/sessions/{sid}/knobs").json()["min_observations"] == 2  # unchanged
        r = c.patch(
            f"/v1/sessions/{sid}/knobs",
            json={"min_observations": "4", "skip_mapping_set": "cup,mug"},
        )
        assert r.json()["min_observations"] == 4 and r.json()["skip_mapping_set"] == ["cup", "mug"]
        assert c.delete(f"/v1/sessions/{sid}").status_code == 204
        assert c.get(f"/v1/sessions/{sid}").status_code == 404


def test_a_device_streams_and_a_query_finds_the_fridge(live_server):
    server = live_server()
    with httpx.Client(base_url=server.url) as c:
        sid = create(c)["session_id"]
        frames = [frame_message(SCENE, i, cam_xy=(0.03 * i, 0.0)) for i in range(3)]
        replies = asyncio.run(stream_in_step(f"{server.ws_url}/v1/sessions/{sid}/stream", frames))
        assert [r["type"] for r in replies] == ["ack"] * 3
        assert sorted(r["seq"] for r in replies) == [0, 1, 2]
        objects = c.get(f"/v1/sessions/{sid}/objects").json()
        assert sorted(o["label"] for o in objects) == ["chair", "refrigerator"]
        answer = c.get(
            f"/v1/sessions/{sid}/query", params={"text": "where do I keep the milk cold", "k": 1}
        ).json()
        assert answer["results"][0]["label"] == "refrigerator" and answer["results"][0]["points"]
        assert answer["latency_ms"] >= 0
        assert answer["match"] is True and answer["results"][0]["relevance"] >= 0.5


def test_a_nonsense_query_or_an_absent_object_answers_no_confident_match(live_server):
    server = live_server()
    with httpx.Client(base_url=server.url) as c:
        sid = create(c)["session_id"]
        frames = [frame_message(SCENE, i, cam_xy=(0.03 * i, 0.0)) for i in range(3)]
        asyncio.run(stream_in_step(f"{server.ws_url}/v1/sessions/{sid}/stream", frames))
        query = f"/v1/sessions/{sid}/query"
        for text in ("xyzzy plugh", "keys"):  # the map holds a chair and a refrigerator
            answer = c.get(query, params={"text": text, "k": 2, "points": False}).json()
            assert answer["match"] is False, answer
            hits = answer["results"]  # still listed, best first, each rated low
            assert sorted(h["label"] for h in hits) == ["chair", "refrigerator"], answer
            assert all(0.0 <= h["relevance"] < 0.5 for h in hits), answer
        answer = c.get(query, params={"text": "a chair", "k": 2, "points": False}).json()
        assert answer["match"] is True
        assert answer["results"][0]["label"] == "chair"
        assert answer["results"][0]["relevance"] > answer["results"][1]["relevance"]


def test_session_creation_announces_the_protocol_and_queries_respect_max_query_k(live_server):
    server = live_server(max_query_k=3)
    with httpx.Client(base_url=server.url) as c:
        created = create(c)
        assert created["protocol"] == PROTOCOL_VERSION
        query = f"/v1/sessions/{created['session_id']}/query"
        assert c.get(query, params={"text": "fridge", "k": 3}).status_code == 200
        too_many = c.get(query, params={"text": "fridge", "k": 4})
        assert too_many.status_code == 422
        assert too_many.json()["detail"] == "k: 4 is over this server's limit of 3"


def test_a_subscriber_ends_up_holding_the_servers_confirmed_map(live_server):
    server = live_server()
    with httpx.Client(base_url=server.url) as c:
        sid = create(c)["session_id"]

        async def run():
            async with websockets.connect(
                f"{server.ws_url}/v1/sessions/{sid}/updates?since=0"
            ) as sub:
                first = msgpack.unpackb(await asyncio.wait_for(sub.recv(), TIMEOUT_S))
                held = {}
                frames = [frame_message(SCENE, i, cam_xy=(0.02 * i, 0.0)) for i in range(4)]
                await stream(f"{server.ws_url}/v1/sessions/{sid}/stream", frames)
                target = c.get(f"/v1/sessions/{sid}").json()["update_seq"]
                seq = first["seq"]
                while seq < target:
                    delta = msgpack.unpackb(await asyncio.wait_for(sub.recv(), TIMEOUT_S))
                    for up in delta["upserts"]:
                        held[up["id"]] = up
                    for oid in delta["removed"]:
                        held.pop(oid, None)
                    seq = delta["seq"]
                return held

        held = asyncio.run(run())
        objects = {
            o["id"]: o for o in c.get(f"/v1/sessions/{sid}/objects", params={"points": True}).json()
        }
        assert held.keys() == objects.keys()
        for oid, up in held.items():
            assert up["version"] == objects[oid]["version"] and up["label"] == objects[oid]["label"]
            pts = float16_points_from_bytes(up["points"], "points")
            assert (
                len(pts) == len(objects[oid]["points"]) <= FAST.get("max_object_points_client", 200)
            )


def _bad_messages() -> dict:
    good = frame_message(SCENE, 5)

    def variant(path, value):
        msg = msgpack.unpackb(msgpack.packb(good))
        node = msg
        *parents, leaf = path.split(".")
        for p in parents:
            node = node[p]
        if value is KeyError:
            del node[leaf]
        else:
            node[leaf] = value
        return msgpack.packb(msg)

    return {
        "not msgpack": b"\xc1\xc1 not msgpack",
        "wrong shape": msgpack.packb([1, 2, 3]),
        "missing pose": variant("pose", KeyError),
        "unknown codec": variant("depth.codec", "lz77"),
        "corrupt jpeg": variant("rgb.data", b"\xff\xd8\xff\xe0 nope"),
        "corrupt zstd": variant("depth.data", b"\x28\xb5\x2f\xfd\x00\x00 broken"),
        "corrupt png": variant("depth.codec", "png"),
        "depth size mismatch": variant("depth.w", 7),
        "mask size mismatch": variant("detections.w", 10),
        "nan pose": variant("pose", b"\x00\x00\xc0\x7f" * 16),
        "non-rigid pose": variant("pose", (b"\x00\x00\x00\x40" + b"\x00" * 60)),
        "unlabelled ids": variant("detections.instances", []),
    }


def test_every_bad_frame_gets_a_clear_error_and_changes_nothing(live_server):
    server = live_server()
    with httpx.Client(base_url=server.url) as c:
        sid = create(c)["session_id"]
        bad = _bad_messages()

        async def run():
            async with websockets.connect(f"{server.ws_url}/v1/sessions/{sid}/stream") as ws:
                replies = await send_and_collect(ws, list(bad.values()))
                # the connection is still open and serving
                (after,) = await send_and_collect(ws, [frame_message(SCENE, 99)])
                return replies, after

        replies, after = asyncio.run(run())
        for name, reply in zip(bad, replies, strict=True):
            assert reply["type"] == "error", name
            assert reply["message"], name
        assert after["type"] == "ack"
        fields = {name: r["message"].split(":")[0] for name, r in zip(bad, replies, strict=True)}
        assert fields["missing pose"] == "pose" and fields["corrupt jpeg"] == "rgb"
        assert (
            fields["unlabelled ids"] == "detections.instances"
            and fields["depth size mismatch"] == "depth"
        )


def test_the_map_is_unchanged_by_bad_frames(live_server):
    server = live_server()
    with httpx.Client(base_url=server.url) as c:
        sid = create(c)["session_id"]
        url = f"{server.ws_url}/v1/sessions/{sid}/stream"
        asyncio.run(stream_in_step(url, [frame_message(SCENE, i) for i in range(2)]))
        before = c.get(f"/v1/sessions/{sid}/objects", params={"points": True}).json()
        assert len(before) == 2
        asyncio.run(stream(url, list(_bad_messages().values())))
        assert c.get(f"/v1/sessions/{sid}/objects", params={"points": True}).json() == before


def test_oversized_messages_close_the_socket_with_1009(live_server):
    server = live_server(max_message_bytes=64 * 1024)
    with httpx.Client(base_url=server.url) as c:
        sid = create(c)["session_id"]

        async def run():
            async with websockets.connect(f"{server.ws_url}/v1/sessions/{sid}/stream") as ws:
                await ws.send(b"\x00" * (200 * 1024))
                with pytest.raises(websockets.ConnectionClosed) as closed:
                    while True:
                        await asyncio.wait_for(ws.recv(), TIMEOUT_S)
                return closed.value.rcvd.code if closed.value.rcvd else None

        assert asyncio.run(run()) == 1009
        assert c.get("/healthz").status_code == 200


def test_unknown_session_is_404_over_rest_and_refused_over_websockets(live_server):
    server = live_server()
    with httpx.Client(base_url=server.url) as c:
        assert c.get("/v1/sessions/nope/objects").status_code == 404

    async def run():
        with pytest.raises(websockets.InvalidStatus):
            async with websockets.connect(f"{server.ws_url}/v1/sessions/nope/stream"):
                pass

    asyncio.run(run())


def _raw_request(url: str, head: bytes, chunks, chunk_size: int) -> tuple[bytes, int]:
    """Send a request over a bare socket, streaming the body; returns (status line, bytes
    of body sent before the server answered)."""
    import socket
    from urllib.parse import urlsplit

    parts = urlsplit(url)
    with socket.create_connection((parts.hostname, parts.port), timeout=TIMEOUT_S) as sock:
        sock.sendall(head)
        sent = 0
        for chunk in chunks:
            try:
                sock.sendall(chunk)
            except OSError:  # the server answered and closed mid-body
                break
            sent += chunk_size
        answer = sock.recv(4096)
    return answer.split(b"\r\n", 1)[0], sent


def test_request_bodies_over_the_limit_get_413_even_when_chunked(live_server):
    server = live_server(max_body_bytes=64 * 1024)
    with httpx.Client(base_url=server.url) as c:
        too_big = b'{"name": "' + b"x" * (100 * 1024) + b'"}'
        r = c.post("/v1/sessions", content=too_big, headers={"content-type": "application/json"})
        assert r.status_code == 413 and "65536 bytes" in r.json()["detail"]

    # Chunked: no Content-Length to check up front; 16 MiB offered in 256 kiB chunks.
    size = 256 * 1024
    chunk = b"%x\r\n" % size + b"x" * size + b"\r\n"
    head = (
        b"POST /v1/sessions HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\n"
        b"Transfer-Encoding: chunked\r\n\r\n"
    )
    status, sent = _raw_request(server.url, head, [chunk] * 64 + [b"0\r\n\r\n"], size)
    assert status == b"HTTP/1.1 413 Request Entity Too Large", status

    with httpx.Client(base_url=server.url) as c:  # still serving, and nothing was created
        assert c.get("/healthz").status_code == 200
        assert c.get("/v1/sessions").json() == []
        assert create(c, name="small")["session_id"]


def test_405_names_every_method_of_the_path_and_errors_are_documented(live_server):
    server = live_server()
    with httpx.Client(base_url=server.url) as c:
        sid = create(c)["session_id"]
        r = c.request("OPTIONS", f"/v1/sessions/{sid}")
        spec = c.get("/openapi.json").json()
    assert r.status_code == 405
    assert {m.strip() for m in r.headers["allow"].split(",")} >= {"GET", "DELETE"}
    assert "GET" in r.json()["detail"] and "DELETE" in r.json()["detail"]
    ops = spec["paths"]["/v1/sessions/{sid}/query"]["get"]["responses"]
    assert {"401", "403", "404", "413", "422"} <= ops.keys()
    assert ops["404"]["content"]["application/json"]["schema"]["$ref"].endswith("/ErrorBody")
    assert {"400", "503"} <= spec["paths"]["/v1/sessions"]["post"]["responses"].keys()


def test_connections_beyond_max_connections_get_503_until_one_closes(live_server):
    server = live_server(max_connections=3)
    with httpx.Client(base_url=server.url) as c:
        sid = create(c)["session_id"]

    async def run():
        url = f"{server.ws_url}/v1/sessions/{sid}/updates?since=0"
        async with contextlib.AsyncExitStack() as stack:
            for _ in range(3):
                await stack.enter_async_context(websockets.connect(url))
            async with httpx.AsyncClient(base_url=server.url) as c:
                assert (await c.get("/healthz")).status_code == 503
            with pytest.raises(websockets.InvalidStatus) as refused:
                await stack.enter_async_context(websockets.connect(url))
            assert refused.value.response.status_code == 503
            assert refused.value.response.headers["Retry-After"] == "1"
        async with httpx.AsyncClient(base_url=server.url) as c:  # all closed: served again
            for _ in range(50):
                if (await c.get("/healthz")).status_code == 200:
                    break
                await asyncio.sleep(0.1)
            assert (await c.get("/healthz")).status_code == 200

    asyncio.run(run())


def test_a_flood_of_frames_gets_one_answer_each_and_keeps_the_newest(live_server):
    server = live_server()
    with httpx.Client(base_url=server.url) as c:
        sid = create(c)["session_id"]
        frames = [frame_message(SCENE, i, cam_xy=(0.005 * i, 0.0)) for i in range(40)]
        replies = asyncio.run(stream(f"{server.ws_url}/v1/sessions/{sid}/stream", frames))
        assert sorted(r["seq"] for r in replies) == list(range(40))
        assert all(r["type"] == "ack" for r in replies)
        mapped = [r for r in replies if r["keyframe"]]
        dropped = [r for r in replies if r.get("dropped")]
        assert len(mapped) + len(dropped) == 40 and mapped
        assert max(r["seq"] for r in mapped) == 39  # the newest frame is always mapped
        stats = c.get(f"/v1/sessions/{sid}").json()
        assert stats["dropped_frames"] == len(dropped) and stats["keyframes"] == len(mapped)


API_KEY = "test-key"


def test_auth_refuses_wrong_tokens_on_every_route_and_socket(live_server):
    server = live_server(api_key=API_KEY)
    admin = {"Authorization": f"Bearer {API_KEY}"}
    with httpx.Client(base_url=server.url) as c:
        assert c.post("/v1/sessions", json={}).status_code == 401
        assert c.get("/v1/sessions", headers={"Authorization": "Bearer wrong"}).status_code == 403
        created = create(c, headers=admin)
        sid, token = created["session_id"], created["token"]
        other = create(c, headers=admin)
        good = {"Authorization": f"Bearer {token}"}
        wrong = {"Authorization": f"Bearer {other['token']}"}
        routes = [
            ("GET", f"/v1/sessions/{sid}"),
            ("GET", f"/v1/sessions/{sid}/objects"),
            ("GET", f"/v1/sessions/{sid}/query?text=chair"),
            ("PATCH", f"/v1/sessions/{sid}/knobs"),
            ("DELETE", f"/v1/sessions/{sid}"),
        ]
        for method, path in routes:
            kwargs = {"json": {}} if method == "PATCH" else {}
            assert c.request(method, path, **kwargs).status_code == 401, path
            assert c.request(method, path, headers=wrong, **kwargs).status_code == 403, path
        # an unknown session looks exactly like a wrong token
        assert c.get("/v1/sessions/doesnotexist", headers=wrong).status_code == 403
        assert c.get(f"/v1/sessions/{sid}", headers=good).status_code == 200

    async def sockets():
        for path in ("stream", "updates"):
            for suffix in ("", f"?token={other['token']}"):
                with pytest.raises(websockets.InvalidStatus):
                    async with websockets.connect(
                        f"{server.ws_url}/v1/sessions/{sid}/{path}{suffix}"
                    ):
                        pass
        replies = await stream(
            f"{server.ws_url}/v1/sessions/{sid}/stream?token={token}", [frame_message(SCENE, 0)]
        )
        assert replies[0]["type"] == "ack"

    asyncio.run(sockets())


def test_a_subscriber_catches_up_when_the_stream_stops_between_publications(live_server):
    server = live_server()
    knobs = {**FAST, "local_map_update_frequency": 2}
    with httpx.Client(base_url=server.url) as c:
        sid = create(c, knobs=knobs)["session_id"]

        async def run():
            url = f"{server.ws_url}/v1/sessions/{sid}/updates?since=0"
            async with websockets.connect(url) as sub:
                await asyncio.wait_for(sub.recv(), TIMEOUT_S)
                frames = [frame_message(SCENE, i, cam_xy=(0.02 * i, 0.0)) for i in range(3)]
                await stream_in_step(f"{server.ws_url}/v1/sessions/{sid}/stream", frames)
                target = c.get(f"/v1/sessions/{sid}").json()["update_seq"]
                seq = 0
                while seq < target:  # odd keyframe count: the last change still arrives
                    seq = msgpack.unpackb(await asyncio.wait_for(sub.recv(), TIMEOUT_S))["seq"]
                return seq, target

        seq, target = asyncio.run(run())
        assert seq == target


def test_every_422_answers_one_format_naming_the_field(live_server):
    server = live_server()
    with httpx.Client(base_url=server.url) as c:
        sid = create(c)["session_id"]
        answers = {
            "mode": c.post("/v1/sessions", json={"mode": "nope"}),
            "query.text": c.get(f"/v1/sessions/{sid}/query"),
            "unknown knob 'nope'": c.patch(f"/v1/sessions/{sid}/knobs", json={"nope": 1}),
        }
    for named, answer in answers.items():
        assert answer.status_code == 422
        assert set(answer.json()) == {"detail"} and isinstance(answer.json()["detail"], str)
        assert named in answer.json()["detail"], answer.text
