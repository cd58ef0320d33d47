"""The emulated device end to end: the real server on loopback (a NetemProxy in between
where the network matters) and, for a misbehaving server, a tiny fake one.

What crosses the wire is checked against the server's own view (GET /objects), never
against the client's idea of it. Waits are on conditions with deadlines.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

import msgpack
import numpy as np
import pytest
import websockets
from analytic_world import BATHROOM, KITCHEN, Rect, RectSource
from helpers_device import FAST_KNOBS, assert_local_map_equals, synced_state, wait_until

from app.config import Knobs, updated_knobs
from app.protocol import UpsertEntry, pack_delta
from app.semantics import TextEncoder
from app.store import StoreUnavailableError
from client_sim.local_map import LocalMap
from client_sim.netem import NetemProxy
from client_sim.querying import QueryRouter
from client_sim.sources.base import FrameSource, SourceFrame
from client_sim.streaming import DeviceClient

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]

MILK = "where do I keep the milk cold"
EMBEDDING_DIM = 384  # all-MiniLM-L6-v2, the sessions' encoder
N_LIVE = 60  # frames of the stream that runs through the outage (6 s at 10 fps)


async def new_session(
    server_url: str, api_key: str | None = None, **knob_overrides
) -> tuple[str, str, Knobs]:
    sid, token, answer = await DeviceClient.create_session(
        server_url, knobs=dict(FAST_KNOBS, **knob_overrides), api_key=api_key
    )
    return sid, token, updated_knobs(Knobs(), answer["knobs"])


@asynccontextmanager
async def following(device: DeviceClient) -> AsyncIterator[asyncio.Task]:
    """The device follows updates for the duration of the block; it must never crash."""
    task = asyncio.create_task(device.follow_updates())
    try:
        yield task
    finally:
        await device.stop()
        await asyncio.wait_for(task, 15)  # re-raises anything follow_updates raised


async def assert_synced_with_server(
    device: DeviceClient, server_url: str, sid: str, token: str
) -> tuple[int, list[dict]]:
    """Wait until the device holds the server's current map, then compare them."""
    seq, objects = await synced_state(device, server_url, sid, token)
    assert_local_map_equals(device.local_map, objects, device.knobs.max_object_points_client)
    return seq, objects


def test_after_streaming_the_local_map_equals_the_servers_confirmed_map(live_server):
    server = live_server(api_key="secret")  # as deployed: the session token on every call

    async def scenario():
        sid, token, knobs = await new_session(server.url, api_key="secret")
        device = DeviceClient(server.url, sid, token, knobs=knobs)
        async with following(device):
            stats = await device.stream(RectSource(KITCHEN, 12), fps=None, max_in_flight=1)
            _, objects = await assert_synced_with_server(device, server.url, sid, token)
        return stats, objects, device

    stats, objects, device = asyncio.run(scenario())
    assert (stats.frames_sent, stats.acks, stats.errors, stats.dropped) == (12, 12, 0, 0)
    assert stats.keyframes_acked == 12 and stats.rtt_ms_smoothed is not None
    assert stats.bytes_up_by_kind["total"] > stats.bytes_up_by_kind["rgb"] > 0
    assert sorted(o["label"] for o in objects) == ["chair", "refrigerator"]
    assert list(device.subscriptions) == [None]  # a new device starts from a full snapshot
    assert device.stats.full_snapshots == 1 and device.stats.deltas_applied > 1


class UnlabelledEveryThird(RectSource):
    """Every third frame has an instance image but no labels: the server refuses it."""

    def frame(self, index: int) -> SourceFrame:
        frame = super().frame(index)
        if index % 3 == 2:
            frame.instances = []
        return frame


def test_frames_the_server_refuses_are_logged_and_counted_and_streaming_goes_on(live_server):
    server = live_server()

    async def scenario():
        sid, token, knobs = await new_session(server.url)
        logs: list[str] = []
        device = DeviceClient(server.url, sid, token, knobs=knobs, on_log=logs.append)
        async with following(device):
            stats = await device.stream(UnlabelledEveryThird(KITCHEN, 9), fps=None)
            _, objects = await assert_synced_with_server(device, server.url, sid, token)
        return stats, objects, logs

    stats, objects, logs = asyncio.run(scenario())
    assert (stats.frames_sent, stats.acks, stats.errors) == (9, 6, 3)
    assert "detections.instances" in stats.last_error
    assert sum("server error" in line for line in logs) == 3
    assert len(objects) == 2  # the good frames were mapped


def test_an_outage_switches_queries_to_local_and_the_device_catches_up_without_losing_updates(
    live_server, encoder
):
    server = live_server()
    port = int(server.url.rsplit(":", 1)[1])

    async def scenario(proxy: NetemProxy):
        sid, token, knobs = await new_session(server.url)
        logs: list[str] = []
        device = DeviceClient(proxy.url(), sid, token, knobs=knobs, on_log=logs.append)
        router = QueryRouter(
            proxy.url(),
            sid,
            token,
            device.local_map,
            encoder,
            rtt_ms=lambda: device.rtt_ms,
            server_timeout_s=5.0,  # a loaded CI machine must not turn the last SQ into LQ
        )
        async with following(device), router:
            await device.stream(RectSource(KITCHEN, 8), fps=None, max_in_flight=1)
            await assert_synced_with_server(device, server.url, sid, token)
            seq_before = device.local_map.seq

            # The device keeps capturing at 10 fps through the outage.
            before = device.stats.copy()
            live = asyncio.create_task(
                device.stream(RectSource(KITCHEN, N_LIVE, start_x_m=0.08), fps=10)
            )
            await wait_until(lambda: device.stats.frames_sent > before.frames_sent, what="stream")
            await asyncio.to_thread(proxy.cut)
            await wait_until(lambda: not device.connected, what="the device to notice the cut")

            offline = await router.query(MILK, k=1)
            offline_nothing = [await router.query(t, k=2) for t in ("xyzzy plugh", "keys")]

            # Meanwhile the map changes: another device maps the bathroom, straight to the server.
            writer = DeviceClient(server.url, sid, token, knobs=knobs)
            await writer.stream(RectSource(BATHROOM, 6, start_x_m=4.0), fps=None, max_in_flight=1)
            await writer.stop()
            await wait_until(lambda: device.stats.dropped > before.dropped, what="a frame skipped")
            sent_at_restore = device.stats.frames_sent
            await asyncio.to_thread(proxy.restore)

            stats = await live
            _, objects = await assert_synced_with_server(device, server.url, sid, token)
            await wait_until(lambda: device.rtt_ms is not None, what="an RTT after the outage")
            online = await router.query(MILK, k=1)
            online_nothing = [await router.query(t, k=2) for t in ("xyzzy plugh", "keys")]
        return {
            "offline_nothing": offline_nothing,
            "online_nothing": online_nothing,
            "stats": stats,
            "before": before,
            "seq_before": seq_before,
            "sent_at_restore": sent_at_restore,
            "subscriptions": list(device.subscriptions),
            "objects": objects,
            "offline": offline,
            "online": online,
            "logs": logs,
        }

    with NetemProxy("127.0.0.1", port) as proxy:
        r = asyncio.run(scenario(proxy))
    stats, before = r["stats"], r["before"]
    assert r["offline"].mode == "LQ", r["offline"].reason
    assert r["offline"].results[0]["label"] == "refrigerator"
    assert r["offline"].match and r["offline"].results[0]["relevance"] >= 0.5
    # Nonsense, and keys the kitchen does not hold: hits listed, none a confident match,
    # rated the same by the device (LQ) as by the server (SQ).
    for offline, online in zip(r["offline_nothing"], r["online_nothing"], strict=True):
        assert (offline.mode, online.mode) == ("LQ", "SQ")
        assert not offline.match and not online.match, (offline.results, online.results)
        assert offline.results and all(h["relevance"] < 0.5 for h in offline.results)
    assert {"bathtub", "toilet"} <= {o["label"] for o in r["objects"]}  # made during the outage
    # Resumed from its last seq, not resynced: no full snapshot after the first one.
    subscriptions = r["subscriptions"]
    assert subscriptions[0] is None and len(subscriptions) >= 2
    assert all(since is not None and since >= r["seq_before"] > 0 for since in subscriptions[1:])
    assert stats.full_snapshots == 1 and stats.resyncs == 0
    # Frames are samples: each of the live stream's frames was sent once or skipped.
    sent, dropped = stats.frames_sent - before.frames_sent, stats.dropped - before.dropped
    assert sent + dropped == N_LIVE and dropped > 0
    assert stats.frames_sent > r["sent_at_restore"], "streaming did not resume after the outage"
    assert stats.reconnects >= 2  # both sockets
    assert any("lost" in line for line in r["logs"])
    assert r["online"].mode == "SQ" and r["online"].results[0]["label"] == "refrigerator"
    assert r["online"].match


def test_latency_above_the_threshold_switches_to_local_queries_and_back(live_server, encoder):
    server = live_server()
    port = int(server.url.rsplit(":", 1)[1])

    async def scenario(proxy: NetemProxy):
        sid, token, knobs = await new_session(server.url)
        device = DeviceClient(proxy.url(), sid, token, knobs=knobs)
        router = QueryRouter(
            proxy.url(),
            sid,
            token,
            device.local_map,
            encoder,
            threshold_ms=100,
            rtt_ms=lambda: device.rtt_ms,
            server_timeout_s=5.0,  # SQ through 150 ms each way must not time out
        )
        async with following(device), router:
            await device.stream(RectSource(KITCHEN, 6), fps=None, max_in_flight=1)
            await assert_synced_with_server(device, server.url, sid, token)
            live = asyncio.create_task(device.stream(RectSource(KITCHEN, 300), fps=10))
            await wait_until(lambda: (device.rtt_ms or math.inf) < 100, what="a fast RTT")
            fast = await router.query(MILK, k=1)

            proxy.set_latency(150)  # each way: RTT ~300 ms
            await wait_until(lambda: (device.rtt_ms or 0) > 100, what="the RTT to rise")
            slow = await router.query(MILK, k=1)

            proxy.set_latency(0)
            await wait_until(lambda: (device.rtt_ms or math.inf) < 100, what="the RTT to fall")
            fast_again = await router.query(MILK, k=1)
            await device.stop()
            await live
        return fast, slow, fast_again

    with NetemProxy("127.0.0.1", port) as proxy:
        fast, slow, fast_again = asyncio.run(scenario(proxy))
    assert fast.mode == "SQ" and fast_again.mode == "SQ", (fast.reason, fast_again.reason)
    assert slow.mode == "LQ" and "> 100 ms" in slow.reason, slow.reason
    for answer in (fast, slow, fast_again):
        assert answer.results[0]["label"] == "refrigerator", answer
        assert answer.latency_ms > 0


# --- a misbehaving server ----------------------------------------------------------------


def _upsert(encoder: TextEncoder, oid: int, label: str, version: int = 1) -> dict:
    """One wire upsert: 30 points around (oid, 0, 2), the label's real embedding."""
    points = np.random.default_rng(oid).uniform(-0.2, 0.2, (30, 3)) + [oid, 0.0, 2.0]
    return UpsertEntry(
        id=oid,
        version=version,
        label=label,
        embedding=encoder.encode([label])[0],
        points=points,
        bbox=(*points.min(axis=0).tolist(), *points.max(axis=0).tolist()),
        n_obs=3,
    ).pack()


def _delta(seq: int, upserts: list[dict], full: bool, removed: tuple[int, ...] = ()) -> bytes:
    """A packed v1 delta (upserts as packed entries, so a test can break one on purpose)."""
    message = pack_delta(seq, removed=removed, full=full)
    return msgpack.packb(dict(message, upserts=upserts))


def test_garbage_on_the_updates_socket_is_logged_and_resynced_with_a_full_snapshot(encoder):
    """A fake server: snapshot then garbage; snapshot then a malformed delta; snapshot then
    text. Each time the device logs it, reconnects without `since` and gets a snapshot; in
    between it answers from its last good map, never from a half-applied one."""
    snapshot_a = [_upsert(encoder, 1, "chair"), _upsert(encoder, 2, "refrigerator")]
    snapshot_b = [
        *snapshot_a[:1],
        _upsert(encoder, 2, "refrigerator", 2),
        _upsert(encoder, 3, "sofa"),
    ]
    snapshot_c = [*snapshot_b, _upsert(encoder, 4, "bed")]
    bad_embedding = dict(_upsert(encoder, 5, "toilet"), embedding=b"\x00" * 10)
    script = [
        (_delta(5, snapshot_a, True), b"\xc1\xc1 not msgpack"),
        (_delta(8, snapshot_b, True), _delta(9, [bad_embedding], False, removed=(1,))),
        (_delta(10, snapshot_c, True), "a text frame"),
        (_delta(10, snapshot_c, True),),
    ]

    async def scenario():
        paths: list[str] = []
        authorizations: list[str | None] = []
        # Connection n speaks once released[n] is set: the test looks at the map in between.
        released = [asyncio.Event() for _ in script]
        released[0].set()

        async def handler(ws):
            n = min(len(paths), len(script) - 1)
            paths.append(ws.request.path)
            authorizations.append(ws.request.headers.get("Authorization"))
            await released[n].wait()
            for message in script[n]:
                await ws.send(message)
            await ws.wait_closed()

        async with websockets.serve(handler, "127.0.0.1", 0) as fake:
            port = fake.sockets[0].getsockname()[1]
            logs: list[str] = []
            device = DeviceClient(f"http://127.0.0.1:{port}", "s1", "t", on_log=logs.append)
            router = QueryRouter(
                f"http://127.0.0.1:{port}",
                "s1",
                "t",
                device.local_map,
                encoder,
                rtt_ms=lambda: math.inf,  # the fake has no REST: answer locally
            )
            async with following(device) as follow, router:
                await wait_until(lambda: device.stats.resyncs == 1, what="the first resync")
                held_after_garbage = device.local_map.snapshot()
                answer = await router.query(MILK, k=1)
                released[1].set()
                await wait_until(lambda: device.stats.resyncs == 2, what="the second resync")
                held_after_bad_delta = device.local_map.snapshot()
                released[2].set()
                await wait_until(lambda: device.stats.resyncs == 3, what="the third resync")
                released[3].set()
                await wait_until(lambda: len(paths) == 4, what="the last connection")
                await wait_until(lambda: device.stats.full_snapshots == 4, what="the last snapshot")
                assert not follow.done()
        return {
            "device": device,
            "logs": logs,
            "paths": paths,
            "authorizations": authorizations,
            "held_after_garbage": held_after_garbage,
            "held_after_bad_delta": held_after_bad_delta,
            "answer": answer,
        }

    r = asyncio.run(scenario())
    device = r["device"]
    assert r["held_after_garbage"] == {1: (1, "chair"), 2: (1, "refrigerator")}
    assert r["answer"].mode == "LQ" and r["answer"].results[0]["label"] == "refrigerator"
    # The malformed delta changed nothing: no toilet, and the chair it "removed" is still there.
    assert r["held_after_bad_delta"] == {1: (1, "chair"), 2: (2, "refrigerator"), 3: (1, "sofa")}
    assert device.local_map.snapshot() == {
        1: (1, "chair"),
        2: (2, "refrigerator"),
        3: (1, "sofa"),
        4: (1, "bed"),
    }
    assert r["paths"] == ["/v1/sessions/s1/updates"] * 4  # every reconnect asked for a snapshot
    assert r["authorizations"] == ["Bearer t"] * 4
    assert device.stats.resyncs == 3 and device.stats.full_snapshots == 4
    bad = [line for line in r["logs"] if "resyncing" in line]
    assert len(bad) == 3
    assert "msgpack" in bad[0] and "embedding" in bad[1] and "text" in bad[2]


# --- memory ------------------------------------------------------------------------------


class RecordingLocalMap(LocalMap):
    """A LocalMap that remembers the most memory it held after any update."""

    peak_bytes = 0

    def apply_delta(self, message: dict) -> None:
        super().apply_delta(message)
        self.peak_bytes = max(self.peak_bytes, self.memory_bytes())


SHOWROOM = (
    *KITCHEN,
    Rect(5, "television", -1.0, -0.5, -0.7, -0.2, 2.6),
    Rect(6, "lamp", -0.95, 0.1, -0.75, 0.6, 2.4),
)


def test_the_local_map_never_exceeds_a_tiny_memory_budget(live_server):
    server = live_server()
    budget_mb = 0.0025  # room for about two objects of 200 points

    async def scenario():
        sid, token, knobs = await new_session(server.url, local_map_budget_mb=budget_mb)
        local_map = RecordingLocalMap(
            dim=EMBEDDING_DIM,
            max_points_per_object=knobs.max_object_points_client,
            budget_mb=knobs.local_map_budget_mb,
        )
        device = DeviceClient(server.url, sid, token, knobs=knobs, local_map=local_map)
        async with following(device):
            await device.stream(RectSource(SHOWROOM, 10), fps=None, max_in_flight=1)
            seq, objects = await synced_state(device, server.url, sid, token)
        return local_map, objects

    local_map, objects = asyncio.run(scenario())
    assert len(objects) == 4
    assert 0 < len(local_map) < len(objects) and local_map.evicted > 0
    assert local_map.peak_bytes <= budget_mb * 1e6
    server_versions = {o["id"]: (o["version"], o["label"]) for o in objects}
    for oid, held in local_map.snapshot().items():  # what it keeps is current
        assert server_versions[oid] == held


# --- the synthetic world -----------------------------------------------------------------


def test_a_device_walking_the_synthetic_living_room_mirrors_the_server(live_server, encoder):
    synthetic = pytest.importorskip("client_sim.sources.synthetic")
    from world.render import default_camera

    source = synthetic.SyntheticSource("living_room", n_frames=60, camera=default_camera(320, 240))
    if not isinstance(source, FrameSource):
        pytest.skip("SyntheticSource is not a FrameSource yet")
    server = live_server()

    async def scenario():
        sid, token, knobs = await new_session(
            server.url, keyframe_interval=5, min_observations=3, min_mapping_bbox_area=500
        )
        device = DeviceClient(server.url, sid, token, knobs=knobs)
        router = QueryRouter(
            server.url, sid, token, device.local_map, encoder, rtt_ms=lambda: math.inf
        )
        async with following(device), router:
            stats = await device.stream(source, fps=None, max_in_flight=1)
            _, objects = await assert_synced_with_server(device, server.url, sid, token)
            label = max({o["label"] for o in objects}, key=[o["label"] for o in objects].count)
            answer = await router.query(label, k=3)
        return stats, objects, label, answer

    stats, objects, label, answer = asyncio.run(scenario())
    assert stats.frames_sent == 60 and stats.errors == 0 and stats.keyframes_acked == 12
    assert len(objects) >= 3
    assert answer.mode == "LQ" and label in [hit["label"] for hit in answer.results]


def test_the_device_command_streams_queries_and_writes_a_summary(live_server, tmp_path):
    pytest.importorskip("client_sim.sources.synthetic")
    import argparse
    import json

    from app.cli.device import add_parser

    server = live_server()
    parser = argparse.ArgumentParser()
    add_parser(parser.add_subparsers(dest="command"))
    summary = tmp_path / "device.json"
    args = parser.parse_args(
        [
            "device",
            "--server",
            server.url,
            "--create",
            "--source",
            "synthetic:living_room",
            "--frames",
            "20",
            "--fps",
            "0",
            "--keyframe-interval",
            "2",
            "--min-observations",
            "2",
            "--local-map-update-frequency",
            "1",
            "--query",
            "sofa",
            "--json",
            str(summary),
        ]
    )
    assert args.func(args) == 0
    result = json.loads(summary.read_text())
    assert result["frames"]["sent"] == 20 and result["frames"]["errors"] == 0
    # the device follows the server up to its seq once the stream closed; the settle of the
    # closed stream may publish once more after the device read that seq, never before
    assert result["local_map"]["seq"] >= result["local_map"]["server_seq"] > 0
    (query,) = result["queries"]
    assert query["mode"] == "SQ" and query["results"]


def test_a_server_that_cannot_save_makes_the_device_back_off_saying_so_once(
    live_server, monkeypatch
):
    server = live_server()
    store = server.app.state.manager.store
    disk_full = True
    real_commit, real_probe = store.commit_keyframe, store.probe

    def commit_keyframe(*args, **kwargs):
        if disk_full:
            raise StoreUnavailableError("injected: the disk is full")
        return real_commit(*args, **kwargs)

    def probe():
        if disk_full:
            raise StoreUnavailableError("injected: the disk is full")
        return real_probe()

    monkeypatch.setattr(store, "commit_keyframe", commit_keyframe)
    monkeypatch.setattr(store, "probe", probe)

    async def scenario():
        nonlocal disk_full
        sid, token, knobs = await new_session(server.url)
        logs: list[str] = []
        device = DeviceClient(server.url, sid, token, knobs=knobs, on_log=logs.append)
        streaming = asyncio.create_task(device.stream(RectSource(KITCHEN, 60), fps=10))
        await asyncio.sleep(2.5)  # the disk stays full for 2.5 s of the 6 s walk
        disk_full = False
        return await streaming, logs

    stats, logs = asyncio.run(scenario())
    assert stats.storage_backoff_skipped > 0  # frames due during the back-off were not sent
    assert stats.dropped >= stats.storage_backoff_skipped
    assert stats.frames_sent + stats.dropped == 60
    assert sum("cannot save" in line for line in logs) == 1  # once per streak
    assert sum("saves the map again" in line for line in logs) == 1
    assert stats.keyframes_acked > 0  # after the disk had room again
