"""The device on a static-tower session: the `device` command's code path against a real
server on loopback (`--create --text-tower static`), which downloads the session's tower by
its hash, keeps it in `--tower-cache`, and answers locally (LQ forced by a threshold of
0 ms) with the scores the server's own answer (SQ) gives, to within the local map's
float16 copy; a tower of another hash, or bytes that are not the announced tower, are
refused for LQ with a clear error. A `models` session cannot have a static tower (422).

The tower is tiny and random (`StaticTower.build` over a small vocabulary): plumbing, not
quality; no distillation runs here.
"""

from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path

import httpx
import numpy as np
import pytest
from analytic_world import Rect, RectSource

from app.semantics import DEFAULT_MODEL_ID
from app.semantics.static import StaticTower, static_model_id
from app.server.towers import TOWERS_DIR
from client_sim.querying import EncoderMismatchError, LocalQueriesOff, session_encoder_loader

pytestmark = [pytest.mark.slow, pytest.mark.timeout(240)]

SCENE = (
    Rect(1, "chair", -0.6, -0.3, -0.1, 0.3, 2.0),
    Rect(2, "table", 0.1, -0.2, 0.7, 0.4, 2.6),
    Rect(3, "wall", -3.0, -3.0, 3.0, 3.0, 4.0),
)
DIM = 48
WORDS = [
    "[UNK]",
    "a",
    "an",
    "the",
    "is",
    "are",
    "where",
    "my",
    "what",
    "which",
    "on",
    "in",
    "under",
    "near",
    "next",
    "to",
    "of",
    "and",
    "chair",
    "table",
    "wall",
    "sofa",
    "mug",
    "lamp",
    "seat",
    "desk",
    "##s",
    "##es",
]
QUESTIONS = ("a chair", "where is the table", "the chair next to the table")


def tiny_tower(seed: int = 0) -> StaticTower:
    rows = np.random.default_rng(seed).normal(size=(len(WORDS), DIM))
    return StaticTower.build(WORDS, rows, teacher=DEFAULT_MODEL_ID)


@pytest.fixture
def tower_file(tmp_path) -> Path:
    path = tmp_path / "tiny.tower"
    path.write_bytes(tiny_tower().to_bytes())
    return path


def run_device(server_url: str, tmp_path: Path, monkeypatch, *flags: str) -> tuple[int, dict]:
    """The `device` command (its parser and run()) creating a static session and streaming
    the scene, then asking QUESTIONS (LQ whenever it can answer locally)."""
    from app.cli import device

    monkeypatch.setattr(
        device,
        "make_device_source",
        lambda spec, frames, max_side_px=None: RectSource(SCENE, 6),
    )
    parser = argparse.ArgumentParser()
    device.add_parser(parser.add_subparsers(dest="command"))
    summary = tmp_path / "device.json"
    questions = [arg for text in QUESTIONS for arg in ("--query", text)]
    args = parser.parse_args(
        [
            "device",
            "--server",
            server_url,
            "--create",
            "--text-tower",
            "static",
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
            "-k",
            "3",
            *questions,
            "--json",
            str(summary),
            *flags,
        ]
    )
    return args.func(args), json.loads(summary.read_text())


def server_answer(server_url: str, sid: str, text: str, k: int = 100) -> dict:
    reply = httpx.get(
        f"{server_url}/v1/sessions/{sid}/query", params={"text": text, "k": k}, timeout=30
    )
    reply.raise_for_status()
    return reply.json()


def test_the_device_downloads_the_tower_caches_it_and_answers_as_the_server(
    live_server, tower_file, tmp_path, monkeypatch, capsys
):
    server = live_server(static_tower=str(tower_file))
    cache = tmp_path / "towers"
    status, summary = run_device(server.url, tmp_path, monkeypatch, "--tower-cache", str(cache))
    assert status == 0, capsys.readouterr().err
    assert summary["frames"]["errors"] == 0 and summary["local_map"]["objects"] > 0
    assert summary["local_queries"] == {"on": True, "off_because": None}
    sid = summary["session_id"]
    data = tower_file.read_bytes()
    sha = hashlib.sha256(data).hexdigest()
    stats = httpx.get(f"{server.url}/v1/sessions/{sid}", timeout=30).json()
    assert stats["embedding"] == {"model": static_model_id(sha), "dim": DIM, "sha256": sha}
    assert [p.name for p in cache.iterdir()] == [f"{sha}.tower"]
    assert (cache / f"{sha}.tower").read_bytes() == data
    assert len(summary["queries"]) == len(QUESTIONS)
    for text, answer in zip(QUESTIONS, summary["queries"], strict=True):
        assert answer["mode"] == "LQ" and answer["results"], text
        assert answer["ranked_by"] == static_model_id(sha)
        # The same space as the server's: each of the device's hits scores what the server
        # gives the same object, to within the float16 copy's rounding, and the device's
        # best is the server's best or within that rounding of it (random towers may rate
        # objects nearly alike, so the order of near ties is not compared).
        served = {hit["id"]: hit for hit in server_answer(server.url, sid, text)["results"]}
        for hit in answer["results"]:
            assert hit["score"] == pytest.approx(served[hit["id"]]["score"], abs=0.01), text
            assert hit["relevance"] == pytest.approx(served[hit["id"]]["relevance"], abs=0.02)
            assert (hit["relation"] or {}).get("kind") == (served[hit["id"]]["relation"] or {}).get(
                "kind"
            ), text
        if "next to" in text:  # read as a relation on both ends
            assert answer["results"][0]["relation"]["kind"] == "next_to"
        best = max(hit["score"] for hit in served.values())
        assert served[answer["results"][0]["id"]]["score"] >= best - 0.01, text


def test_a_cached_tower_answers_without_the_server_and_a_damaged_one_is_fetched_again(
    live_server, tower_file, tmp_path
):
    server = live_server(static_tower=str(tower_file))
    tower = StaticTower.from_bytes(tower_file.read_bytes())
    embedding = {"model": tower.model_id, "dim": DIM, "sha256": tower.sha256}
    cache = tmp_path / "cache"
    with pytest.raises(LocalQueriesOff, match="no server"):
        session_encoder_loader(embedding, None, tower_cache=cache)
    load = session_encoder_loader(embedding, None, server_url=server.url, tower_cache=cache)
    encoder = load()
    assert (encoder.model_id, encoder.dim) == (tower.model_id, DIM)
    np.testing.assert_array_equal(encoder.encode_query("a chair"), tower.embed("a chair"))
    server.stop()  # from now on only the cache can answer
    offline = session_encoder_loader(embedding, None, tower_cache=cache)()
    np.testing.assert_array_equal(offline.encode_query("a chair"), tower.embed("a chair"))
    cached = cache / f"{tower.sha256}.tower"
    cached.write_bytes(cached.read_bytes()[:-1])  # damaged: removed, then downloaded again
    again = live_server(static_tower=str(tower_file))
    assert session_encoder_loader(embedding, None, server_url=again.url, tower_cache=cache)()
    assert cached.read_bytes() == tower_file.read_bytes()


def test_a_tower_that_is_not_the_announced_one_is_refused_for_local_queries(
    live_server, tower_file, tmp_path
):
    server = live_server(static_tower=str(tower_file))
    tower, other = tiny_tower(), tiny_tower(seed=1)
    # an announcement whose hash does not name its model: refused before any download
    crossed = {"model": other.model_id, "dim": DIM, "sha256": tower.sha256}
    with pytest.raises(EncoderMismatchError, match="does not name it"):
        session_encoder_loader(crossed, None, server_url=server.url, tower_cache=tmp_path)
    # a server whose store holds other bytes under the announced hash
    fake_sha = hashlib.sha256(b"the tower that is not there").hexdigest()
    (tmp_path / "data" / TOWERS_DIR / f"{fake_sha}.sxt").write_bytes(other.to_bytes())
    announced = {"model": static_model_id(fake_sha), "dim": DIM, "sha256": fake_sha}
    load = session_encoder_loader(announced, None, server_url=server.url, tower_cache=tmp_path)
    with pytest.raises(EncoderMismatchError, match=f"sha256 is {other.sha256}, not the {fake_sha}"):
        load()
    assert not (tmp_path / f"{fake_sha}.tower").exists()  # nothing wrong is cached
    # a tower the server does not hold: the download fails, naming the call
    missing = {"model": static_model_id("1" * 64), "dim": DIM, "sha256": "1" * 64}
    load = session_encoder_loader(missing, None, server_url=server.url, tower_cache=tmp_path)
    with pytest.raises(ConnectionError, match="404"):
        load()
    # the right tower of another dimension than announced
    wrong_dim = {"model": tower.model_id, "dim": DIM * 2, "sha256": tower.sha256}
    load = session_encoder_loader(wrong_dim, None, server_url=server.url, tower_cache=tmp_path)
    with pytest.raises(EncoderMismatchError, match="refusing local queries"):
        load()


def test_a_models_session_cannot_have_a_static_tower(live_server, tiny_models_dir, tower_file):
    server = live_server(
        perception="models,detections", models_dir=tiny_models_dir, static_tower=str(tower_file)
    )
    body = {"perception": "models", "text_tower": "static"}
    refused = httpx.post(f"{server.url}/v1/sessions", json=body, timeout=60)
    assert refused.status_code == 422
    detail = refused.json()["detail"]
    assert "text_tower" in detail and "only MiniLM sessions" in detail
    ok = httpx.post(f"{server.url}/v1/sessions", json={**body, "perception": "detections"})
    assert ok.status_code == 201 and ok.json()["embedding"]["dim"] == DIM


def test_with_rerank_a_connected_device_gets_minilms_ranking_and_says_so(
    live_server, tower_file, tmp_path, monkeypatch, capsys
):
    server = live_server(static_tower=str(tower_file))
    status, summary = run_device(
        server.url,
        tmp_path,
        monkeypatch,
        "--rerank",
        "--tower-cache",
        str(tmp_path / "towers"),
        "--net-latency-switch-threshold-ms",
        "10000",  # any measured RTT is below it: the server answers
    )
    assert status == 0, capsys.readouterr().err
    for text, answer in zip(QUESTIONS, summary["queries"], strict=True):
        assert answer["mode"] == "SQ" and answer["results"], text
        assert answer["ranked_by"] == DEFAULT_MODEL_ID, text
    assert f"ranked by {DEFAULT_MODEL_ID}" in capsys.readouterr().out
