"""Commit, then publish: a keyframe the store did not save is never shown, and faults are seen.

The session manager runs on a real SqliteStore; `FlakyStore` makes its commits (and probes)
fail on demand, as a full disk would. tests/app/server/test_faults.py does the same against
a real server process under a real file-size limit.
"""

from __future__ import annotations

import asyncio
import logging

import httpx
import msgpack
import pytest
from analytic_world import BATHROOM, KITCHEN, render_rects
from devices import frame_message, stream_in_step

from app.mapping.publish import update_message
from app.server.metrics import make_metrics
from app.server.sessions import Session, SessionManager
from app.server.sessions import storage as storage_module
from app.server.settings import ServerSettings
from app.store import StoreUnavailableError
from app.store.sqlite import SqliteStore

KNOBS = {
    "keyframe_interval": 1,
    "min_observations": 2,
    "min_mapping_bbox_area": 100,
    "local_map_update_frequency": 1,
    "cleanup_interval": 3,
}


class FlakyStore(SqliteStore):
    """A SqliteStore whose commits fail while `failing` is set: "before" refuses them (a
    full disk), "after" saves them and raises anyway (an error reported after the write
    landed). Its probe fails while `failing` is set."""

    failing: str | None = None

    def commit_keyframe(self, *args, **kwargs) -> None:
        if self.failing == "after":
            super().commit_keyframe(*args, **kwargs)
        if self.failing is not None:
            raise StoreUnavailableError("injected: the disk refused a write")
        super().commit_keyframe(*args, **kwargs)

    def probe(self) -> None:
        if self.failing is not None:
            raise StoreUnavailableError("injected: the disk refuses writes")
        super().probe()


@pytest.fixture
def manager(tmp_path, encoder, monkeypatch):
    monkeypatch.setattr(storage_module, "STORAGE_PROBE_INTERVAL_S", 0.0)  # probe every time
    store = FlakyStore(tmp_path / "db.sqlite3")
    manager = SessionManager(ServerSettings(data_dir=str(tmp_path)), store, encoder, make_metrics())
    yield manager
    manager.close()
    store.close()


def keyframe(manager: SessionManager, session: Session, index: int, rects=KITCHEN) -> dict:
    """Map keyframe `index` of the analytic scene (camera sliding along x) through the
    session's keyframe pipeline; its one reply."""
    frame = render_rects(list(rects), cam_xy=(0.02 * index, 0.0), seq=index)
    sent = session.engine.validate_frame(frame)

    async def run() -> dict:
        answered: asyncio.Future = asyncio.get_running_loop().create_future()

        async def reply(message: dict) -> None:
            answered.set_result(message)

        await manager.submit_keyframe(session, frame, reply, sent)
        return await asyncio.wait_for(answered, 30)

    return asyncio.run(run())


def shown(session: Session) -> dict:
    """Everything a reader can see: objects (all fields), the delta log, counters, queries."""
    engine = session.engine
    return {
        "objects": [
            (o.id, o.version, o.label, o.n_obs, o.points.tobytes(), o.embedding_sum.tobytes())
            for o in session.objects()
        ],
        "log": engine.log.state(),
        "keyframes": engine.keyframes,
        "next_object_id": engine.next_object_id,
        "record": (session.record.keyframes, session.record.next_object_id),
        "delta": msgpack.packb(session.build_delta(None)),
        "query": [(h.object.id, h.score) for h in session.query("a chair", 3)],
    }


def stored(manager: SessionManager, session: Session) -> tuple[list, int]:
    objects = manager.store.load_objects(session.id)
    return [(o.id, o.version, o.points.tobytes()) for o in objects], manager.store.load_delta_log(
        session.id
    ).seq


def counter(manager: SessionManager, name: str) -> float:
    return manager.metrics.registry.get_sample_value(name)


@pytest.mark.parametrize("how", ["before", "after"])
def test_a_failed_commit_leaves_every_reader_seeing_the_durable_map(manager, how):
    session, _ = manager.create("home", "semanticxr", KNOBS)
    for i in range(3):
        assert keyframe(manager, session, i)["type"] == "ack"
    before = shown(session)
    assert before["objects"] and before["log"]["seq"] >= 1

    manager.store.failing = how
    refused = keyframe(manager, session, 3, rects=KITCHEN + BATHROOM)  # would add objects
    assert refused["type"] == "error" and refused["code"] == "storage_unavailable"
    assert "retry later" in refused["message"]
    if how == "before":
        assert shown(session) == before  # the map, log and counters as before the keyframe
    # Whatever the store holds is what readers see: never more, never less.
    objects_stored, seq_stored = stored(manager, session)
    assert [(o.id, o.version, o.points.tobytes()) for o in session.objects()] == objects_stored
    assert session.engine.log.seq == seq_stored

    manager.store.failing = None
    ack = keyframe(manager, session, 4, rects=KITCHEN + BATHROOM)
    assert ack["type"] == "ack" and ack["update_seq"] == seq_stored + 1
    objects_stored, seq_stored = stored(manager, session)
    assert [(o.id, o.version, o.points.tobytes()) for o in session.objects()] == objects_stored
    assert session.engine.log.seq == seq_stored == ack["update_seq"]


def test_a_subscriber_never_sees_a_seq_reused_for_other_contents(manager):
    session, _ = manager.create("home", "semanticxr", KNOBS)
    for i in range(3):
        keyframe(manager, session, i)
    seen = session.build_delta(None)  # a subscriber holds the map at seen["seq"]

    manager.store.failing = "before"
    keyframe(manager, session, 3, rects=KITCHEN + BATHROOM)
    keyframe(manager, session, 4, rects=KITCHEN + BATHROOM)
    nothing = session.build_delta(seen["seq"])
    assert (nothing["seq"], nothing["upserts"], nothing["removed"]) == (seen["seq"], [], [])

    manager.store.failing = None
    keyframe(manager, session, 5, rects=KITCHEN + BATHROOM)
    delta = session.build_delta(seen["seq"])
    assert delta["seq"] == seen["seq"] + 1 and not delta["full"]
    # After a restart the store gives back exactly what subscribers were shown at that seq.
    restarted = SessionManager(manager.settings, manager.store, manager.encoder, make_metrics())
    restarted.restore()
    again = restarted.acquire(session.id)

    def the_map(message: dict) -> dict:
        message.pop("device_pose", None)  # where the device is: not part of the saved map
        return message

    assert the_map(update_message(again.engine, None)) == the_map(session.build_delta(None))
    assert the_map(update_message(again.engine, seen["seq"])) == the_map(delta)


def test_while_storage_fails_one_error_is_logged_keyframes_are_refused_and_health_returns(
    manager, caplog
):
    session, _ = manager.create("home", "semanticxr", KNOBS)
    keyframe(manager, session, 0)
    assert counter(manager, "semanticxr_persist_failures_total") == 0
    manager.store.failing = "before"
    caplog.set_level(logging.INFO, logger="semanticxr")
    replies = [keyframe(manager, session, i) for i in range(1, 5)]
    assert [r["code"] for r in replies] == ["storage_unavailable"] * 4
    assert manager.storage.reason is not None
    # One commit failed; later keyframes were refused by a failing probe, before mapping.
    assert counter(manager, "semanticxr_persist_failures_total") == 1
    assert session.engine.keyframes == 1
    errors = [r for r in caplog.records if r.levelno == logging.ERROR]
    assert len(errors) == 1 and "storage failing" in errors[0].getMessage()

    manager.store.failing = None
    assert keyframe(manager, session, 5)["type"] == "ack"
    assert manager.storage.reason is None
    infos = [r.getMessage() for r in caplog.records if r.levelno == logging.INFO]
    assert any("storage recovered" in m for m in infos)


def test_the_store_probe_clears_the_failure_without_a_keyframe(manager):
    session, _ = manager.create("home", "semanticxr", KNOBS)
    manager.store.failing = "before"
    keyframe(manager, session, 0)
    assert manager.storage.failing

    async def watch_until_recovered() -> None:
        watcher = asyncio.create_task(manager.watch_storage())
        try:
            await asyncio.sleep(0)
            assert manager.storage.failing  # the probe fails while the disk does
            manager.store.failing = None
            async with asyncio.timeout(10):
                while manager.storage.failing:
                    await asyncio.sleep(0.05)  # polling a flag another thread clears
        finally:
            watcher.cancel()

    asyncio.run(watch_until_recovered())
    assert manager.storage.reason is None


def test_a_mapping_error_is_undone_counted_and_logged(manager, monkeypatch, caplog):
    session, _ = manager.create("home", "semanticxr", KNOBS)
    for i in range(2):
        keyframe(manager, session, i)
    before = shown(session)
    engine = session.engine
    real_map = engine.map_keyframe

    def map_then_break(frame, detections):
        real_map(frame, detections)  # the map changed in memory...
        raise RuntimeError("a bug after the map changed")

    monkeypatch.setattr(engine, "map_keyframe", map_then_break)
    caplog.set_level(logging.ERROR, logger="semanticxr")
    reply = keyframe(manager, session, 2, rects=KITCHEN + BATHROOM)
    assert reply["code"] == "internal" and "a bug" in reply["message"]
    assert shown(session) == before  # ...and was put back
    assert counter(manager, "semanticxr_mapping_failures_total") == 1
    assert counter(manager, "semanticxr_persist_failures_total") == 0
    assert any("mapping keyframe 2 failed" in r.getMessage() for r in caplog.records)
    assert keyframe(manager, session, 3)["type"] == "ack"  # the next keyframe maps as usual


def test_fault_counters_are_present_at_zero_and_health_is_503_with_retry_after(live_server):
    server = live_server()
    with httpx.Client(base_url=server.url) as c:
        metrics = c.get("/metrics").text.splitlines()
        for name in (
            "semanticxr_dropped_frames_total",
            "semanticxr_persist_failures_total",
            "semanticxr_mapping_failures_total",
        ):
            assert f"{name} 0.0" in metrics
        health = server.app.state.manager.storage
        health.failed()
        r = c.get("/healthz")
        assert r.status_code == 503 and r.headers["retry-after"].isdigit()
        assert r.json()["status"] == "unavailable" and "storage" in r.json()["reason"]
        health.succeeded()
        assert c.get("/healthz").json()["status"] == "ok"


def test_a_graceful_restart_brings_back_the_exact_frame_count(live_server, tmp_path):
    server = live_server()
    with httpx.Client(base_url=server.url) as c:
        sid = c.post("/v1/sessions", json={"knobs": {"keyframe_interval": 5}}).json()["session_id"]
    frames = [frame_message(list(KITCHEN), i, cam_xy=(0.01 * i, 0.0)) for i in range(13)]
    replies = asyncio.run(stream_in_step(f"{server.ws_url}/v1/sessions/{sid}/stream", frames))
    assert [r["type"] for r in replies] == [
        "ack"
    ] * 13  # frames 10, 11, 12 follow the last keyframe

    # The stream ended: its counters reach the store without waiting for a shutdown.
    reader = SqliteStore(tmp_path / "data" / "semanticxr.sqlite3")
    try:
        for _ in range(100):
            if reader.load_session(sid).frames == 13:
                break
            asyncio.run(asyncio.sleep(0.05))  # another thread writes them
        assert reader.load_session(sid).frames == 13
    finally:
        reader.close()

    server.stop()
    server = live_server()
    with httpx.Client(base_url=server.url) as c:
        assert c.get(f"/v1/sessions/{sid}").json()["frames"] == 13
