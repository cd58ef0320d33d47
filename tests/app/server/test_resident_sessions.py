"""Stored versus resident sessions, through a real server on loopback with a real SQLite store.

Sessions live in the store; only the maps in use are in memory. Start-up loads none; a
session loads on first use; it is unloaded when idle or when the resident budget needs room
(least recently used first, never one with an open socket), and comes back whole, its
subscribers resuming by seq, as after a restart. Past --max-sessions stored, creation is
refused naming the flag; retention deletes sessions unused for too long.
"""

from __future__ import annotations

import asyncio
import logging
import time
from concurrent.futures import ThreadPoolExecutor

import httpx
import msgpack
import pytest
import websockets
from analytic_world import KITCHEN, Rect
from devices import TIMEOUT_S, frame_message, stream_in_step, wait_settled
from helpers_device import FAST_KNOBS, wait_until
from prometheus_client.parser import text_string_to_metric_families

from app.store.sqlite import SqliteStore

pytestmark = pytest.mark.timeout(120)

LAMP = Rect(3, "lamp", -0.9, 0.35, -0.7, 0.8, 1.8)
"""In view beside the kitchen: what a device sees after its subscriber went away."""


# ---------------------------------------------------------------------- helpers
def create(c: httpx.Client, name: str = "s") -> str:
    r = c.post("/v1/sessions", json={"name": name, "knobs": FAST_KNOBS})
    assert r.status_code == 201, r.text
    return r.json()["session_id"]


def listed(c: httpx.Client) -> dict[str, dict]:
    """GET /v1/sessions by id (reads the store: loads nothing)."""
    r = c.get("/v1/sessions")
    assert r.status_code == 200, r.text
    return {s["session_id"]: s for s in r.json()}


def resident(c: httpx.Client) -> set[str]:
    return {sid for sid, s in listed(c).items() if s["resident"]}


def metric(c: httpx.Client, name: str, **labels: str) -> float:
    """One sample of /metrics, parsed by prometheus_client's parser."""
    for family in text_string_to_metric_families(c.get("/metrics").text):
        for sample in family.samples:
            if sample.name == name and sample.labels == labels:
                return sample.value
    raise AssertionError(f"no sample {name} {labels}")


def the_map(c: httpx.Client, sid: str) -> tuple[int, int, list[dict]]:
    """(update seq, frames, confirmed objects with their points) as the server shows them."""
    stats = c.get(f"/v1/sessions/{sid}")
    assert stats.status_code == 200, stats.text
    objects = c.get(f"/v1/sessions/{sid}/objects", params={"points": True}).json()
    return stats.json()["update_seq"], stats.json()["frames"], objects


def stream_frames(server, sid: str, scene, indices: range) -> None:
    """Stream the frames one at a time, then wait for the closed stream's settle."""
    frames = [frame_message(list(scene), i, cam_xy=(0.02 * i, 0.0)) for i in indices]
    replies = asyncio.run(stream_in_step(f"{server.ws_url}/v1/sessions/{sid}/stream", frames))
    assert all(r["type"] == "ack" for r in replies), replies
    wait_settled(server.url, sid)


def first_update(ws_url: str, sid: str, since: int | None) -> dict:
    """The first message an updates subscriber gets (since=None: a full snapshot)."""

    async def run() -> dict:
        query = "" if since is None else f"?since={since}"
        url = f"{ws_url}/v1/sessions/{sid}/updates{query}"
        async with websockets.connect(url, max_size=None) as sub:
            return msgpack.unpackb(await asyncio.wait_for(sub.recv(), TIMEOUT_S))

    return asyncio.run(run())


def held(delta: dict, before: dict[int, int] | None = None) -> dict[int, int]:
    """A subscriber's map (id -> version) after applying `delta` to `before`."""
    out = {} if delta["full"] or before is None else dict(before)
    for up in delta["upserts"]:
        out[up["id"]] = up["version"]
    for oid in delta["removed"]:
        out.pop(oid, None)
    return out


def assert_resumes_with_only_what_it_missed(
    ws_url: str, sid: str, seen: dict[int, int], seen_seq: int, objects: list[dict], seq: int
) -> None:
    """A subscriber that applied the map up to `seen_seq` resumes with ?since=: it gets a
    delta (not a snapshot) holding exactly the objects changed since, and ends equal."""
    delta = first_update(ws_url, sid, seen_seq)
    now = {o["id"]: o["version"] for o in objects}
    assert not delta["full"] and delta["seq"] == seq
    assert {up["id"] for up in delta["upserts"]} == {i for i in now if seen.get(i) != now[i]}
    assert set(delta["removed"]) <= set(seen) - set(now)
    assert held(delta, seen) == now


# ---------------------------------------------------------------------- tests
@pytest.mark.slow
def test_a_session_unloaded_for_room_comes_back_whole_and_its_subscriber_resumes_by_seq(
    live_server,
):
    server = live_server(max_resident_sessions=2)
    with httpx.Client(base_url=server.url, timeout=30) as c:
        home = create(c, "home")
        stream_frames(server, home, KITCHEN, range(3))
        # A subscriber applies the map so far, then goes away while more is mapped.
        snapshot = first_update(server.ws_url, home, None)
        seen, seen_seq = held(snapshot), snapshot["seq"]
        stream_frames(server, home, (*KITCHEN, LAMP), range(3, 7))
        seq, frames, objects = the_map(c, home)
        assert seq > seen_seq and len(objects) > len(seen) and frames == 7

        others = [create(c, f"other-{i}") for i in range(2)]  # 3 sessions, room for 2
        assert resident(c) == set(others)
        assert metric(c, "semanticxr_session_unloads_total", reason="budget") == 1
        entry = listed(c)[home]
        assert (entry["objects"], entry["update_seq"], entry["frames"]) == (
            len(objects),
            seq,
            frames,
        )

        assert the_map(c, home) == (seq, frames, objects)  # loaded again, whole
        assert home in resident(c)
        assert_resumes_with_only_what_it_missed(server.ws_url, home, seen, seen_seq, objects, seq)

    server.stop()  # and the same after a restart
    server = live_server(max_resident_sessions=2)
    with httpx.Client(base_url=server.url, timeout=30) as c:
        assert the_map(c, home) == (seq, frames, objects)
        assert_resumes_with_only_what_it_missed(server.ws_url, home, seen, seen_seq, objects, seq)
        # and it maps on from where it was: the seq goes on, no object id is reused
        stream_frames(server, home, (*KITCHEN, LAMP), range(7, 9))
        seq_after, _, objects_after = the_map(c, home)
        assert seq_after >= seq and {o["id"] for o in objects} <= {o["id"] for o in objects_after}


def test_start_up_loads_no_map_and_concurrent_first_uses_load_a_session_once(live_server):
    server = live_server()
    with httpx.Client(base_url=server.url, timeout=30) as c:
        sids = [create(c, f"s{i}") for i in range(3)]
        stream_frames(server, sids[0], KITCHEN, range(3))
        objects = c.get(f"/v1/sessions/{sids[0]}/objects", params={"points": True}).json()
    server.stop()

    server = live_server()
    with httpx.Client(base_url=server.url, timeout=30) as c:
        assert metric(c, "semanticxr_session_loads_total") == 0
        assert metric(c, "semanticxr_sessions") == 0  # resident
        assert metric(c, "semanticxr_sessions_stored") == 3
        entries = listed(c)  # listing reads the store, loads nothing
        assert set(entries) == set(sids) and not any(e["resident"] for e in entries.values())
        assert entries[sids[0]]["objects"] == len(objects) > 0
        assert metric(c, "semanticxr_session_loads_total") == 0

    def get_objects(_: int) -> list[dict]:
        with httpx.Client(base_url=server.url, timeout=30) as c:
            r = c.get(f"/v1/sessions/{sids[0]}/objects", params={"points": True})
            assert r.status_code == 200, r.text
            return r.json()

    with ThreadPoolExecutor(8) as pool:
        answers = list(pool.map(get_objects, range(8)))
    assert all(a == objects for a in answers)
    with httpx.Client(base_url=server.url, timeout=30) as c:
        assert metric(c, "semanticxr_session_loads_total") == 1
        assert resident(c) == {sids[0]}


def test_an_idle_session_is_unloaded_but_never_one_with_an_open_socket(live_server):
    server = live_server(idle_unload_s=0.3)
    with httpx.Client(base_url=server.url, timeout=30) as c:
        watched, quiet = create(c, "watched"), create(c, "quiet")

        async def run() -> None:
            url = f"{server.ws_url}/v1/sessions/{watched}/updates"
            async with websockets.connect(url, max_size=None) as sub:
                await asyncio.wait_for(sub.recv(), TIMEOUT_S)
                assert c.get(f"/v1/sessions/{quiet}").status_code == 200  # used after
                await wait_until(lambda: quiet not in resident(c), what="the idle unload")
                # quiet was used last, so watched was idle at least as long: kept for its socket
                assert watched in resident(c)
            await wait_until(lambda: watched not in resident(c), what="unload once closed")

        asyncio.run(run())
        assert metric(c, "semanticxr_session_unloads_total", reason="idle") >= 2
        assert c.get(f"/v1/sessions/{quiet}").json()["session_id"] == quiet  # loads again


def test_when_every_resident_session_has_a_socket_open_others_get_503_with_retry_after(
    live_server,
):
    server = live_server(max_resident_sessions=2)
    with httpx.Client(base_url=server.url, timeout=30) as c:
        stored, a, b = create(c, "stored"), create(c, "a"), create(c, "b")
        assert resident(c) == {a, b}

        async def run() -> None:
            async with (
                websockets.connect(f"{server.ws_url}/v1/sessions/{a}/updates") as sub_a,
                websockets.connect(f"{server.ws_url}/v1/sessions/{b}/stream"),
            ):
                await asyncio.wait_for(sub_a.recv(), TIMEOUT_S)
                for refused in (
                    c.post("/v1/sessions", json={}),
                    c.get(f"/v1/sessions/{stored}"),
                ):
                    assert refused.status_code == 503, refused.text
                    assert int(refused.headers["retry-after"]) >= 1
                    assert "--max-resident-sessions" in refused.json()["detail"]
                with pytest.raises(websockets.InvalidStatus) as socket_refused:
                    await websockets.connect(f"{server.ws_url}/v1/sessions/{stored}/updates")
                answer = socket_refused.value.response
                assert answer.status_code == 503 and int(answer.headers["retry-after"]) >= 1
                assert b"--max-resident-sessions" in answer.body
                assert resident(c) == {a, b}  # neither was unloaded

            # a's socket closed: a makes room for the stored one, b (its socket open) stays
            async with websockets.connect(f"{server.ws_url}/v1/sessions/{b}/stream"):
                await wait_until(  # once the server has seen a's socket close
                    lambda: c.get(f"/v1/sessions/{stored}").status_code == 200,
                    what="room for the stored session",
                )
                assert resident(c) == {stored, b}

        asyncio.run(run())


def test_past_max_sessions_creation_and_import_are_refused_naming_the_flag(live_server):
    server = live_server(max_sessions=2, max_resident_sessions=1)
    with httpx.Client(base_url=server.url, timeout=30) as c:
        first, _ = create(c, "one"), create(c, "two")  # stored: 2, resident: 1
        export = c.get(f"/v1/sessions/{first}/export").json()
        for refused in (
            c.post("/v1/sessions", json={}),
            c.post("/v1/sessions/import", json=export),
        ):
            assert refused.status_code == 409, refused.text
            assert "--max-sessions" in refused.json()["detail"]
            assert "retry-after" not in refused.headers  # deleting sessions is the way out
        assert len(listed(c)) == 2
        assert c.delete(f"/v1/sessions/{first}").status_code == 204
        create(c, "three")


def test_retention_deletes_sessions_unused_for_longer_at_start_logs_and_counts_them(
    live_server, tmp_path, caplog
):
    server = live_server()
    with httpx.Client(base_url=server.url, timeout=30) as c:
        old, recent = create(c, "old"), create(c, "recent")
    server.stop()
    with SqliteStore(tmp_path / "data" / "semanticxr.sqlite3") as store:
        store.update_session(old, last_used_at=time.time() - 3 * 86_400)  # 3 days ago

    caplog.set_level(logging.INFO, logger="semanticxr")
    server = live_server(session_retention_days=2)
    with httpx.Client(base_url=server.url, timeout=30) as c:
        assert set(listed(c)) == {recent}
        assert c.get(f"/v1/sessions/{old}").status_code == 404
        assert metric(c, "semanticxr_sessions_expired_total") == 1
    deleted = [
        r.getMessage() for r in caplog.records if "--session-retention-days" in r.getMessage()
    ]
    assert len(deleted) == 1 and old in deleted[0]


def test_retention_is_checked_while_the_server_runs_and_spares_a_session_in_use(live_server):
    retention_days = 1.0 / 86_400  # one second
    server = live_server(session_retention_days=retention_days)
    with httpx.Client(base_url=server.url, timeout=30) as c:
        unused, in_use = create(c, "unused"), create(c, "in use")

        async def run() -> None:
            url = f"{server.ws_url}/v1/sessions/{in_use}/updates"
            async with websockets.connect(url, max_size=None) as sub:
                await asyncio.wait_for(sub.recv(), TIMEOUT_S)
                await wait_until(lambda: unused not in listed(c), what="retention")
                assert in_use in listed(c)

        asyncio.run(run())
        assert metric(c, "semanticxr_sessions_expired_total") >= 1
        assert c.get(f"/v1/sessions/{unused}").status_code == 404
