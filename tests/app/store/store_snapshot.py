"""What a store reads back, as plain JSON values: the check that a store written by earlier
code opens, migrates and reads the same.

`snapshot` uses the public `Store` reads only, so the code that wrote a fixture
(tests/data/store/write_fixtures.py) and today's store are read through the same questions.
Arrays are compared bit for bit (their dtype, shape and bytes as hex).
"""

from __future__ import annotations

import dataclasses
import json
from collections import Counter

import numpy as np

from app.mapping.object import Change, MapObject, Stay

DONE_KEYS = (("left", 1), ("left", 2), ("right", 7), ("left", 99))
"""The (stream_id, seq) keys whose remembered acks a snapshot reads (the last one never
remembered)."""
SHARDS_NOW = 1_800_000_000.0
"""The time at which a snapshot lists the shard registry (every heartbeat before it)."""


def _array(values: np.ndarray | None) -> list | None:
    if values is None:
        return None
    return [values.dtype.str, list(values.shape), values.tobytes().hex()]


def _stay(stay: Stay) -> list:
    return [stay.t_from, stay.t_to, list(stay.centroid), list(stay.bbox)]


def object_fields(obj: MapObject) -> dict:
    """Everything a store keeps of one object."""
    return {
        "id": obj.id,
        "version": obj.version,
        "n_obs": obj.n_obs,
        "frames_seen": obj.frames_seen,
        "first_seen": obj.first_seen,
        "last_seen": obj.last_seen,
        "confirmed": obj.confirmed,
        "resolution_m": obj.resolution_m,
        "label_counts": [[label, count] for label, count in Counter(obj.label_counts).items()],
        "points": _array(obj.points),
        "embedding_sum": _array(obj.embedding_sum),
        "label_embeddings": [[label, _array(v)] for label, v in obj.label_embeddings.items()],
        "first_seen_t": obj.first_seen_t,
        "last_seen_t": obj.last_seen_t,
        "state": obj.state,
        "stays": [_stay(stay) for stay in obj.stays],
    }


def _change(change: Change) -> list:
    return [
        change.id,
        change.kind,
        change.t,
        change.label,
        None if change.from_xyz is None else list(change.from_xyz),
        None if change.to_xyz is None else list(change.to_xyz),
        change.seq,
    ]


def snapshot(store) -> dict:
    """Every session (record, present and removed objects, changes, delta log, counted map,
    remembered acks) and the shard registry, as JSON values."""
    stored = {entry.record.session_id: entry for entry in store.list_stored()}
    sessions = []
    for rec in store.list_sessions():
        sid = rec.session_id
        done = {}
        for stream_id, seq in DONE_KEYS:
            ack = store.done_ack(sid, stream_id, seq)
            done[f"{stream_id}:{seq}"] = None if ack is None else ack.hex()
        sessions.append(
            {
                "record": dataclasses.asdict(rec),
                "loaded_record": dataclasses.asdict(store.load_session(sid)),
                "objects": [object_fields(obj) for obj in store.load_objects(sid)],
                "removed": [object_fields(obj) for obj in store.load_removed_objects(sid)],
                "one_object": [
                    None if obj is None else object_fields(obj)
                    for obj in (store.load_object(sid, i) for i in range(1, 8))
                ],
                "changes": [_change(c) for c in store.load_changes(sid)],
                "newest_two_changes": [_change(c) for c in store.load_changes(sid, limit=2)],
                "delta_log": store.load_delta_log(sid).state(),
                "stored": [stored[sid].objects, stored[sid].seq],
                "done": done,
            }
        )
    shards = [dataclasses.asdict(s) for s in store.live_shards(1e12, now=SHARDS_NOW)]
    return json.loads(json.dumps({"sessions": sessions, "shards": shards}))
