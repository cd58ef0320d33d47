"""bench.load, run small through a real server in a child process: its document's shape and
its counts, never its times."""

import json
import os

import msgpack
import pytest

from bench.load import REPO_ROOT, Walk, cpu_s, main

RUN_FIELDS = {
    "server",
    "devices",
    "frames_due",
    "frames_sent",
    "frames_acked",
    "acked_percent",
    "acked_not_superseded_percent",
    "acked_per_s",
    "keyframe_ack_ms",
    "frame_ack_ms",
    "superseded_keyframes",
    "errors",
    "unanswered",
    "stalled_sockets",
    "server_cpu_ms_per_acked_frame",
    "rss_mb",
    "per_device",
}


def small_run(tmp_path, *flags: str) -> dict:
    out = tmp_path / "out"
    args = ["--devices", "2", "--seconds", "3", "--size", "160x120", "--out", str(out), *flags]
    assert main(args) == 0
    assert (out / "load.png").stat().st_size > 0
    return json.loads((out / "load.json").read_text())


def assert_counts_consistent(run: dict) -> None:
    assert run["devices"] == 2 and len(run["per_device"]) == 2
    assert run["errors"] == 0 and run["unanswered"] == 0
    assert run["frames_acked"] <= run["frames_sent"] <= run["frames_due"]
    assert run["frames_sent"] > 0 and run["frames_acked"] == run["frames_sent"]
    answered = run["keyframe_ack_ms"]["count"] + run["frame_ack_ms"]["count"]
    assert answered + run["superseded_keyframes"] == run["frames_acked"]
    assert run["keyframe_ack_ms"]["count"] > 0 and run["frame_ack_ms"]["count"] > 0
    for summary in (run["keyframe_ack_ms"], run["frame_ack_ms"]):
        assert 0 <= summary["p50"] <= summary["p95"] <= summary["p99"] <= summary["max"]
    assert run["acked_per_s"] >= 0 and run["server_cpu_ms_per_acked_frame"] >= 0
    assert run["rss_mb"] > 0


@pytest.mark.slow
def test_paced_devices_against_this_checkouts_server_report_every_frame_acked_once(tmp_path):
    document = small_run(tmp_path)

    assert document["bench"] == "load" and not document["saturate"]
    (run,) = document["runs"]
    assert set(run) >= RUN_FIELDS
    assert_counts_consistent(run)
    assert run["frames_due"] == 2 * 15  # 3 s at 5 fps, each device
    assert run["sightings_sent"] == 0
    assert document["targets"] == []  # they are at 8 and 32 devices


@pytest.mark.slow
def test_semanticxr_path_runs_that_checkouts_server_saturated_with_sightings(tmp_path):
    document = small_run(tmp_path, "--semanticxr", str(REPO_ROOT), "--saturate", "--sightings")

    (server,) = document["servers"]
    assert server["checkout"] == str(REPO_ROOT)
    (run,) = document["runs"]
    assert run["server"] == server["label"]
    assert run["server_cwd"] == str(REPO_ROOT)
    assert_counts_consistent(run)
    assert run["sightings_sockets"] == 2 and run["sightings_sent"] > 0
    assert run["superseded_keyframes"] == 0  # one frame in flight: nothing to supersede


def test_a_replayed_walk_goes_on_with_growing_seq_and_t():
    frames = [msgpack.packb({"type": "frame", "seq": i, "t": i * 0.2}) for i in range(3)]
    walk = Walk(frames, [None, frames[1], None], 0.2, (160, 120))

    assert walk.message(1, as_sighting=False) is frames[1]
    assert msgpack.unpackb(walk.message(7, as_sighting=False)) == {
        "type": "frame",
        "seq": 7,
        "t": pytest.approx(1.4),
    }
    assert walk.message(6, as_sighting=True) is None


def test_cpu_seconds_of_a_process_grow_with_its_work():
    before = cpu_s(os.getpid())
    sum(i * i for i in range(2_000_000))
    assert cpu_s(os.getpid()) > before
