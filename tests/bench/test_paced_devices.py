"""The paced-devices section of bench.server, run small: its document's shape, not its times."""

import pytest

from bench.server import PACED_FPS, encode_frames, paced_devices


@pytest.mark.slow
def test_paced_devices_report_every_frame_answered_once_with_ack_percentiles(live_server):
    server = live_server()
    frames, _ = encode_frames(10, "apartment")

    section = paced_devices(server, frames, [2], seconds=2.0)

    assert section["fps_per_device"] == PACED_FPS
    (run,) = section["runs"]
    assert run["devices"] == 2 and len(run["per_device"]) == 2
    assert run["frames_sent"] + run["stalls"] == 2 * 10
    assert run["errors"] == 0 and run["unanswered"] == 0
    answered = run["keyframe_ack_ms"]["count"] + run["frame_ack_ms"]["count"]
    assert answered + run["dropped_keyframes"] == run["frames_sent"]
    for summary in (run["keyframe_ack_ms"], run["frame_ack_ms"]):
        assert set(summary) == {"p50", "p95", "mean", "max", "count"}
    assert run["keyframe_ack_ms"]["count"] > 0 and run["frame_ack_ms"]["count"] > 0
    assert run["keyframe_ack_ms"]["p50"] <= run["keyframe_ack_ms"]["p95"]
