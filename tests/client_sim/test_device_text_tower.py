"""The device's text tower on a `--perception models` session (local queries need CLIP's text
tower on the device too: README.md, "Perception from pixels"): the `device` command's code
path against a real server on loopback, streaming frames WITHOUT detections (what a real
headset sends), with tiny random models (plumbing, not quality).

- with --models-dir it loads the session's CLIP text tower and answers locally (LQ forced
  by a threshold of 0 ms), with the server's ranking;
- without it, it says once that local queries are off, answers through the server, exits 0;
- a different encoder is refused for LQ with a clear error.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import shutil
from pathlib import Path

import httpx
import pytest
from analytic_world import Rect, RectSource

from app.perception.models.tiny import TINY_PREFIX
from app.perception.models.weights import CPU_PROFILE, MODEL_ID_FILE
from client_sim.local_map import LocalMap
from client_sim.querying import (
    EncoderMismatchError,
    LocalQueriesOff,
    QueryRouter,
    session_encoder_loader,
)
from client_sim.sources.base import FrameSource, SourceFrame

pytestmark = [pytest.mark.slow, pytest.mark.timeout(240)]

SCENE = (
    Rect(1, "chair", -0.6, -0.3, -0.1, 0.3, 2.0),
    Rect(2, "table", 0.1, -0.2, 0.7, 0.4, 2.6),
    Rect(3, "wall", -3.0, -3.0, 3.0, 3.0, 4.0),
)
TINY_CLIP = {"model": TINY_PREFIX + CPU_PROFILE.embedder.folder, "dim": 32}
NOTICE = "local queries are off for this session"


class WithoutDetections(FrameSource):
    """RGB, depth and pose only, as a real headset streams them."""

    def __init__(self, inner: FrameSource):
        self.inner = inner

    def __len__(self) -> int:
        return len(self.inner)

    def frame(self, index: int) -> SourceFrame:
        frame = self.inner.frame(index)
        frame.instance_ids, frame.instances = None, None
        return frame


def run_device(server_url: str, tmp_path: Path, monkeypatch, *flags: str) -> tuple[int, dict]:
    """The `device` command (its parser and run()) streaming the scene without detections."""
    from app.cli import device

    monkeypatch.setattr(
        device,
        "make_device_source",
        lambda spec, frames, max_side_px=None: WithoutDetections(RectSource(SCENE, 6)),
    )
    parser = argparse.ArgumentParser()
    device.add_parser(parser.add_subparsers(dest="command"))
    summary = tmp_path / "device.json"
    args = parser.parse_args(
        [
            "device",
            "--server",
            server_url,
            "--create",
            "--fps",
            "0",
            "--keyframe-interval",
            "1",
            "--min-observations",
            "1",
            "--min-mapping-bbox-area",
            "16",
            "--local-map-update-frequency",
            "1",
            "--net-latency-switch-threshold-ms",
            "0",  # any measured RTT is above it: LQ whenever the device can answer locally
            "--query",
            "a chair",
            "--json",
            str(summary),
            *flags,
        ]
    )
    return args.func(args), json.loads(summary.read_text())


def server_answer(server_url: str, sid: str, text: str, k: int = 3) -> list[dict]:
    reply = httpx.get(
        f"{server_url}/v1/sessions/{sid}/query", params={"text": text, "k": k}, timeout=30
    )
    reply.raise_for_status()
    return reply.json()["results"]


def test_with_models_dir_the_device_answers_locally_with_the_sessions_text_tower(
    live_server, tiny_models_dir, tmp_path, monkeypatch, capsys
):
    server = live_server(perception="models", models_dir=tiny_models_dir)
    status, summary = run_device(server.url, tmp_path, monkeypatch, "--models-dir", tiny_models_dir)
    assert status == 0
    assert summary["frames"]["sent"] == 6 and summary["frames"]["errors"] == 0
    assert summary["local_map"]["objects"] > 0
    assert summary["local_queries"] == {"on": True, "off_because": None}
    (answer,) = summary["queries"]
    assert answer["mode"] == "LQ" and answer["results"]
    assert NOTICE not in capsys.readouterr().err
    # The same space as the server's: each of the device's hits scores what the server gives
    # the same object, to within the int8 copy's rounding. (Random tiny towers rate many
    # objects within a thousandth of each other, so the order of near ties may differ.)
    served = {
        hit["id"]: hit["score"]
        for hit in server_answer(server.url, summary["session_id"], "a chair", k=100)
    }
    best = max(served.values())
    for hit in answer["results"]:
        assert hit["score"] == pytest.approx(served[hit["id"]], abs=0.01)
    assert served[answer["results"][0]["id"]] >= best - 0.01


def test_without_models_dir_the_device_says_so_once_and_asks_the_server(
    live_server, tiny_models_dir, tmp_path, monkeypatch, capsys
):
    server = live_server(perception="models", models_dir=tiny_models_dir)
    status, summary = run_device(server.url, tmp_path, monkeypatch)
    assert status == 0
    err = capsys.readouterr().err
    assert err.count(NOTICE) == 1 and "--models-dir" in err
    assert summary["local_queries"]["on"] is False
    (answer,) = summary["queries"]
    # RTT above the 0 ms threshold, yet SQ: the server is the only one who can answer.
    assert answer["mode"] == "SQ" and answer["results"]
    expected = server_answer(server.url, summary["session_id"], "a chair")
    assert [(r["id"], r["score"]) for r in answer["results"]] == [
        (r["id"], r["score"]) for r in expected
    ]


def test_a_models_dir_holding_another_clip_is_refused_for_local_queries(
    live_server, tiny_models_dir, tmp_path, monkeypatch, capsys
):
    other = tmp_path / "other-models"
    shutil.copytree(tiny_models_dir, other)
    (other / CPU_PROFILE.embedder.folder / MODEL_ID_FILE).write_text("someone/else-clip\n")
    server = live_server(perception="models", models_dir=tiny_models_dir)
    status, summary = run_device(server.url, tmp_path, monkeypatch, "--models-dir", str(other))
    err = capsys.readouterr().err
    assert "refusing local queries" in err and "someone/else-clip" in err
    assert TINY_CLIP["model"] in err
    (answer,) = summary["queries"]
    assert answer["mode"] == "SQ"  # never LQ with the wrong model
    assert status == 0 and summary["local_queries"]["on"] is False


def test_the_router_refuses_an_encoder_of_another_dimension(tiny_models_dir):
    encoder = session_encoder_loader(TINY_CLIP, tiny_models_dir)()
    assert (encoder.model_id, encoder.dim) == (TINY_CLIP["model"], TINY_CLIP["dim"])
    with pytest.raises(EncoderMismatchError, match="refusing local queries"):
        QueryRouter(
            "http://127.0.0.1:9",
            "sid",
            None,
            LocalMap(64),
            encoder,
            embedding=dict(TINY_CLIP, dim=64),
        )
    with pytest.raises(LocalQueriesOff, match="--models-dir"):
        session_encoder_loader(TINY_CLIP, None)


def test_with_local_queries_off_and_no_server_a_query_gets_no_answer():
    async def ask():
        async with QueryRouter(
            "http://127.0.0.1:9", "sid", None, LocalMap(32), None, server_timeout_s=0.5
        ) as router:
            return await router.query("a chair")

    answer = asyncio.run(ask())
    assert answer.mode == "none" and answer.results == []
    assert "local queries off" in answer.reason
