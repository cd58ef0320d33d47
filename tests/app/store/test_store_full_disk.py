"""The SQLite store on a full disk, for real: a file-size limit (RLIMIT_FSIZE, in a child
process: writes past it fail with EFBIG, as a full disk fails them) refuses writes."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[3]

CHILD = r"""
import json, resource, sys
from collections import Counter
import numpy as np
from app.mapping.object import MapObject
from app.store import KeyframeCommit, SessionRecord, StoreUnavailableError
from app.store.sqlite import SqliteStore

store = SqliteStore(sys.argv[1])
store.create_session(SessionRecord("s", "n", "semanticxr", {}, "h", 0.0))
resource.setrlimit(resource.RLIMIT_FSIZE, (int(sys.argv[2]), resource.RLIM_INFINITY))

def objects(first_id):
    made = []
    for oid in range(first_id, first_id + 3):
        obj = MapObject(id=oid, embedding_sum=np.ones(16, np.float32),
                        label_counts=Counter(a=1), version=1, confirmed=True)
        obj.set_points(np.random.default_rng(oid).random((2000, 3), np.float32), 0.01)
        made.append(obj)
    return made

seq, refused = 0, None
for k in range(200):
    try:
        store.commit_keyframe(KeyframeCommit("s", seq + 1, objects(3 * seq + 1), [], {"frames": k}, 3 * seq + 4))
    except StoreUnavailableError as exc:
        refused = str(exc)
        break
    seq += 1
report = {"committed": seq, "refused": refused,
          "stored": [o.id for o in store.load_objects("s")],
          "stored_seq": store.load_delta_log("s").seq}
try:
    store.probe()
    report["probe_while_full"] = "ok"
except StoreUnavailableError:
    report["probe_while_full"] = "refused"
resource.setrlimit(resource.RLIMIT_FSIZE, (resource.RLIM_INFINITY, resource.RLIM_INFINITY))
store.probe()
store.commit_keyframe(KeyframeCommit("s", seq + 1, objects(3 * seq + 1), [], {"frames": 999}, 3 * seq + 4))
report["after"] = len(store.load_objects("s"))
print(json.dumps(report))
"""


def test_a_full_disk_refuses_a_commit_whole_the_probe_waits_for_room_and_writes_resume(tmp_path):
    limit = 1 << 20  # the WAL fills first (folded into the database, then retried), then the db
    out = subprocess.run(
        [sys.executable, "-c", CHILD, str(tmp_path / "db.sqlite3"), str(limit)],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    report = json.loads(out.stdout)
    # More was committed than a WAL of `limit` bytes holds: a full WAL was folded and retried.
    assert report["committed"] * 3 * 2000 * 12 > limit
    assert "disk refused a write" in report["refused"]
    # The refused commit changed nothing: the store holds exactly the commits before it.
    assert report["stored"] == list(range(1, 3 * report["committed"] + 1))
    assert report["stored_seq"] == report["committed"]
    assert report["probe_while_full"] == "refused"  # no recovery reported without room
    assert report["after"] == 3 * report["committed"] + 3  # room again: writes resume
