"""A session fed frames its backend cannot map says so once: log, stats and the device."""

from __future__ import annotations

import argparse
import asyncio
import logging

import httpx
import numpy as np
from analytic_world import KITCHEN
from devices import frame_message, stream_in_step
from PIL import Image

from app.cli.device import add_parser
from app.server.sessions import NO_DETECTIONS_WARNING


def stream(server, frames: list[dict]) -> str:
    """A new session fed `frames`; its id."""
    sid = httpx.post(f"{server.url}/v1/sessions", json={}).json()["session_id"]
    asyncio.run(stream_in_step(f"{server.ws_url}/v1/sessions/{sid}/stream", frames))
    return sid


def test_frames_without_detections_warn_once_in_the_log_and_the_stats(live_server, caplog):
    caplog.set_level(logging.WARNING, logger="semanticxr")
    server = live_server()
    bare = [frame_message(KITCHEN, i, cam_xy=(0.03 * i, 0.0)) for i in range(6)]
    for frame in bare:
        del frame["detections"]  # a recording without labels
    sid = stream(server, bare)
    stats = httpx.get(f"{server.url}/v1/sessions/{sid}").json()
    assert stats["frames"] == 6 and stats["objects"] == 0
    assert stats["warnings"] == [NO_DETECTIONS_WARNING]
    assert "--perception models" in NO_DETECTIONS_WARNING
    said = [r.getMessage() for r in caplog.records if NO_DETECTIONS_WARNING in r.getMessage()]
    assert said == [f"session {sid}: {NO_DETECTIONS_WARNING}"]  # once, for 6 frames

    with_detections = [frame_message(KITCHEN, i, cam_xy=(0.03 * i, 0.0)) for i in range(3)]
    sid = stream(server, with_detections)
    assert httpx.get(f"{server.url}/v1/sessions/{sid}").json()["warnings"] == []


def write_seven_scenes_wall(folder, n_frames: int = 4) -> None:
    """A 7-Scenes recording (no labels: the format has none) of a wall 2.5 m ahead."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    for number in range(n_frames):
        stem = folder / f"frame-{number:06d}"
        Image.fromarray(rng.integers(0, 256, (60, 80, 3), np.uint8)).save(f"{stem}.color.png")
        Image.fromarray(np.full((60, 80), 2500, np.uint16)).save(f"{stem}.depth.png")
        pose = np.eye(4)
        pose[0, 3] = 0.05 * number
        np.savetxt(f"{stem}.pose.txt", pose)
    np.savetxt(folder / "camera-intrinsics.txt", [[70.0, 0, 39.5], [0, 70.0, 29.5], [0, 0, 1]])


def test_the_device_streaming_a_recording_without_detections_prints_the_warning_once(
    live_server, tmp_path, capsys
):
    server = live_server()
    write_seven_scenes_wall(tmp_path / "wall")
    parser = argparse.ArgumentParser()
    add_parser(parser.add_subparsers(dest="command"))
    args = parser.parse_args(
        ["device", "--server", server.url, "--create", "--source", f"7scenes:{tmp_path / 'wall'}"]
        + ["--fps", "0"]
    )
    assert args.func(args) == 0
    err = capsys.readouterr().err
    assert err.count("[device] server warns: ") == 1, err
    assert f"server warns: {NO_DETECTIONS_WARNING}" in err
