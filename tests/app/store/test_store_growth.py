"""The store stops growing when the map does: tombstones are trimmed by the server itself.

Run against each store (conftest.py `store_url`): an SQLite file reuses the pages it frees;
PostgreSQL keeps dead row versions until a vacuum (autovacuum's work) reclaims them, so its
size is measured after one.
"""

from __future__ import annotations

import asyncio
import sqlite3
from pathlib import Path

import httpx
import msgpack
import pytest
import websockets
from analytic_world import Rect
from devices import TIMEOUT_S, frame_message

pytestmark = pytest.mark.timeout(120)

MAX_TOMBSTONES = 50
# Twenty boxes in view. The labels cycle through three spellings and association needs a
# score of 2, reached only when a frame's spelling is the object's dominant label (its
# embedding is that label's: per-label evidence), the first spelling; the other two make a
# new object per box, confirmed at once; the clean-up every second keyframe merges each
# back into the box's first object (the spellings agree enough to merge), which tombstones
# the ones already published. The map stays twenty objects while twenty confirmed objects
# are removed, and tombstoned, about every three keyframes.
KNOBS = {
    "keyframe_interval": 1,
    "min_observations": 1,
    "cleanup_interval": 2,
    "association_threshold": 2.0,
    "min_mapping_bbox_area": 100,
    "local_map_update_frequency": 1,
}
LABELS = ("chair", "chair.", "chair!")
BOXES = [(x, y) for x in (-0.8, -0.4, 0.0, 0.4, 0.8) for y in (-0.6, -0.2, 0.2, 0.6)]


def _frame(seq: int) -> dict:
    label = LABELS[seq % len(LABELS)]
    rects = [
        Rect(i + 1, label, x - 0.1, y - 0.1, x + 0.1, y + 0.1, 2.0)
        for i, (x, y) in enumerate(BOXES)
    ]
    return frame_message(rects, seq)


async def _stream(url: str, seqs: range) -> None:
    async with websockets.connect(url, max_size=None) as ws:
        for seq in seqs:
            await ws.send(msgpack.packb(_frame(seq)))
            reply = msgpack.unpackb(await asyncio.wait_for(ws.recv(), TIMEOUT_S))
            assert reply["type"] == "ack" and reply["keyframe"], reply


def _contents(db) -> dict:
    """What the store holds (`db`: an sqlite3 or a psycopg connection)."""
    return {
        "tombstones": db.execute("SELECT count(*) FROM tombstones").fetchone()[0],
        "objects": db.execute("SELECT count(*) FROM objects").fetchone()[0],
        "seq_floor_next_id": tuple(
            db.execute("SELECT seq, delta_floor, next_object_id FROM sessions").fetchone()
        ),
    }


def _measure(store_url: str) -> dict:
    """The database as a reader sees it: its size (an SQLite file after moving the WAL into
    it; PostgreSQL's tables and indexes after a vacuum) and what it holds."""
    if store_url.startswith("sqlite:///"):
        db_path = Path(store_url.removeprefix("sqlite:///"))
        with sqlite3.connect(db_path) as db:
            db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
            page_size = db.execute("PRAGMA page_size").fetchone()[0]
            return {
                "bytes": db.execute("PRAGMA page_count").fetchone()[0] * page_size,
                "file_bytes": db_path.stat().st_size,
                **_contents(db),
            }
    import psycopg

    with psycopg.connect(store_url, autocommit=True) as db:
        db.execute("VACUUM FULL")  # drops dead row versions, as (auto)vacuum lets them be reused
        size = db.execute(
            "SELECT sum(pg_total_relation_size(c.oid))::bigint FROM pg_class AS c"
            " WHERE c.relname IN ('sessions', 'objects', 'tombstones', 'changes')"
        ).fetchone()[0]
        return {"bytes": size, "file_bytes": size, **_contents(db)}


def test_the_database_stops_growing_when_the_map_does(store_url, live_server):
    server = live_server(store=store_url, max_tombstones=MAX_TOMBSTONES)
    created = httpx.post(f"{server.url}/v1/sessions", json={"knobs": KNOBS}, timeout=10).json()
    url = f"{server.ws_url}/v1/sessions/{created['session_id']}/stream"

    n = 40
    asyncio.run(_stream(url, range(0, n)))
    after_n = _measure(store_url)
    asyncio.run(_stream(url, range(n, 2 * n)))
    after_2n = _measure(store_url)

    # The workload removed far more objects than the store keeps tombstones for...
    seq, floor, next_id = after_2n["seq_floor_next_id"]
    assert next_id > len(BOXES) * n and seq == 2 * n
    assert floor > after_n["seq_floor_next_id"][1] > 0
    # ...while the map stayed twenty objects, and the store stayed the same size.
    assert after_n["objects"] <= 2 * len(BOXES) and after_2n["objects"] <= 2 * len(BOXES)
    assert after_2n["tombstones"] <= MAX_TOMBSTONES
    assert after_2n["bytes"] <= after_n["bytes"]
    assert after_2n["file_bytes"] <= after_n["file_bytes"]

    stats = httpx.get(f"{server.url}/v1/sessions/{created['session_id']}", timeout=10).json()
    assert stats["objects"] == len(BOXES)

    # A subscriber resuming from before the kept history gets the whole map.
    async def resume(since: int) -> dict:
        updates = f"{server.ws_url}/v1/sessions/{created['session_id']}/updates?since={since}"
        async with websockets.connect(updates, max_size=None) as ws:
            return msgpack.unpackb(await asyncio.wait_for(ws.recv(), TIMEOUT_S))

    old = asyncio.run(resume(floor - 1))
    assert old["full"] and len(old["upserts"]) == len(BOXES)
    recent = asyncio.run(resume(floor))
    assert not recent["full"]


def test_a_restart_trims_a_store_that_kept_more_tombstones_than_the_setting(store_url, live_server):
    """Databases written before trimming (or with a larger setting) shrink as each session
    loads (on its first use: start-up loads no map)."""
    first = live_server(store=store_url)
    created = httpx.post(f"{first.url}/v1/sessions", json={"knobs": KNOBS}, timeout=10).json()
    asyncio.run(_stream(f"{first.ws_url}/v1/sessions/{created['session_id']}/stream", range(12)))
    first.stop()
    before = _measure(store_url)
    assert before["tombstones"] > MAX_TOMBSTONES and before["seq_floor_next_id"][1] == 0

    again = live_server(store=store_url, max_tombstones=MAX_TOMBSTONES)
    assert _measure(store_url)["tombstones"] == before["tombstones"]  # nothing loaded yet
    stats = httpx.get(f"{again.url}/v1/sessions/{created['session_id']}", timeout=10).json()
    assert (stats["objects"], stats["update_seq"]) == (len(BOXES), 12)
    after = _measure(store_url)
    assert after["tombstones"] <= MAX_TOMBSTONES // 2
    assert after["seq_floor_next_id"][1] > 0
