"""Sessions with a static text tower, through a real server on loopback: created with
`text_tower: "static"` (the session record names the tower by hash), the tower served by
that hash (`GET /v1/text-towers/{sha256}`: the file's bytes, cacheable for good, no
credentials), plain and relational questions answered with it, export and import keeping
it, and a restart loading the session with the same tower (refused, clearly, when the
server no longer holds it).

The tower is tiny and random (`StaticTower.build` over a small vocabulary): plumbing, not
quality; no distillation runs here.
"""

from __future__ import annotations

import asyncio
import gzip
import hashlib
import json
import shutil
from pathlib import Path

import httpx
import numpy as np
import pytest
import websockets
from relation_scene import SCENE, map_export

from app.semantics import DEFAULT_MODEL_ID
from app.semantics.static import StaticTower
from app.server.towers import TOWERS_DIR

pytestmark = pytest.mark.timeout(180)

API_KEY = "tower-test-key"
DIM = 32
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
    "desk",
    "shelf",
    "table",
    "sofa",
    "mug",
    "chair",
    "bag",
    "lamp",
    "cup",
    "seat",
    "##s",
    "##es",
]


def tiny_tower(seed: int = 0, teacher: str = DEFAULT_MODEL_ID) -> StaticTower:
    rows = np.random.default_rng(seed).normal(size=(len(WORDS), DIM))
    return StaticTower.build(WORDS, rows, teacher=teacher)


@pytest.fixture
def tower_file(tmp_path) -> Path:
    path = tmp_path / "tiny.tower"
    path.write_bytes(tiny_tower().to_bytes())
    return path


@pytest.fixture
def server(live_server, tower_file):
    return live_server(api_key=API_KEY, static_tower=str(tower_file))


def client(server) -> httpx.Client:
    return httpx.Client(
        base_url=server.url, headers={"Authorization": f"Bearer {API_KEY}"}, timeout=60
    )


def create(http: httpx.Client, **body) -> httpx.Response:
    return http.post("/v1/sessions", json={"knobs": {}, **body})


def test_a_static_session_names_its_tower_by_hash_and_the_server_serves_it(server, tower_file):
    data = tower_file.read_bytes()
    sha = hashlib.sha256(data).hexdigest()
    tower = StaticTower.from_bytes(data)
    with client(server) as http:
        created = create(http, text_tower="static")
        assert created.status_code == 201, created.text
        embedding = created.json()["embedding"]
        assert embedding == {"model": f"static-{sha[:16]}", "dim": DIM, "sha256": sha}
        assert embedding["model"] == tower.model_id
        sid = created.json()["session_id"]
        assert http.get(f"/v1/sessions/{sid}").json()["embedding"] == embedding
        # a MiniLM session, as before: no sha256 in its embedding
        plain = create(http).json()["embedding"]
        assert plain == {"model": DEFAULT_MODEL_ID, "dim": 384}
    # the tower by its hash: public (no credentials), the file's bytes, cacheable for good
    url = f"{server.url}/v1/text-towers/{sha}"
    got = httpx.get(url, headers={"Accept-Encoding": "identity"}, timeout=30)
    assert got.status_code == 200
    assert got.content == data and hashlib.sha256(got.content).hexdigest() == sha
    assert got.headers["content-type"] == "application/octet-stream"
    assert "content-encoding" not in got.headers
    assert got.headers["etag"] == f'"{sha}"'
    assert got.headers["cache-control"] == "public, max-age=31536000, immutable"
    # gzipped for a client that takes it (httpx, browsers), its own ETag; the same file
    with httpx.stream("GET", url, headers={"Accept-Encoding": "br, gzip;q=0.8"}) as packed:
        assert packed.headers["content-encoding"] == "gzip"
        assert packed.headers["etag"] == f'"{sha}.gz"'
        assert gzip.decompress(b"".join(packed.iter_raw())) == data
    refused = httpx.get(url, headers={"Accept-Encoding": "gzip;q=0, br"}, timeout=30)
    assert "content-encoding" not in refused.headers and refused.content == data
    for held in (f'"{sha}"', f'W/"{sha}.gz"', f'"other", "{sha}.gz"'):
        again = httpx.get(url, headers={"If-None-Match": held}, timeout=30)
        assert again.status_code == 304 and again.content == b"", held
    unknown = "0" * 64
    missing = httpx.get(f"{server.url}/v1/text-towers/{unknown}", timeout=30)
    assert missing.status_code == 404 and unknown in missing.json()["detail"]
    for bad in ("abc", sha.upper(), sha + "0", "g" * 64):
        answer = httpx.get(f"{server.url}/v1/text-towers/{bad}", timeout=30)
        assert answer.status_code == 422, bad
        assert "sha256" in answer.json()["detail"]


def test_a_text_tower_other_than_minilm_or_static_is_refused_naming_the_choices(server):
    with client(server) as http:
        for bad in ("clip", "", "STATIC", 3):
            answer = create(http, text_tower=bad)
            assert answer.status_code == 422, bad
            detail = answer.json()["detail"]
            assert "text_tower" in detail and "minilm" in detail and "static" in detail
        assert http.get("/v1/sessions").json() == []


def test_the_openapi_document_lists_the_tower_route_as_public(server):
    schema = httpx.get(f"{server.url}/openapi.json", timeout=30).json()
    operation = schema["paths"]["/v1/text-towers/{sha256}"]["get"]
    assert operation["security"] == []
    assert {"200", "304", "404", "422"} <= set(operation["responses"])
    create_body = schema["components"]["schemas"]["CreateSession"]["properties"]
    assert set(create_body["text_tower"]["enum"]) == {"minilm", "static"}


def static_export(name: str) -> dict:
    tower = tiny_tower()
    return map_export(
        SCENE,
        name,
        text_tower="static",
        embedding={"model": tower.model_id, "dim": DIM, "sha256": tower.sha256},
    )


def test_plain_and_relational_questions_export_and_import_work_with_the_static_tower(
    server, tower_file
):
    tower = StaticEncoderOf(tower_file)
    with client(server) as http:
        imported = http.post("/v1/sessions/import", json=static_export("room"))
        assert imported.status_code == 201, imported.text
        assert imported.json()["embedding"]["model"] == tower.model_id
        sid = imported.json()["session_id"]
        plain = http.get(f"/v1/sessions/{sid}/query", params={"text": "the sofa", "k": 20})
        assert plain.status_code == 200, plain.text
        hits = plain.json()["results"]
        assert len(hits) == len(SCENE)
        # scored with the tower's own embeddings: the label's cosine to the question
        question = tower.encode_query("the sofa")
        for hit in hits:
            label = tower.encode_labels([hit["label"]])[0]
            assert hit["score"] == pytest.approx(float(question @ label), abs=1e-4)
        related = http.get(
            f"/v1/sessions/{sid}/query", params={"text": "the mug on the shelf", "k": 3}
        )
        assert related.status_code == 200, related.text
        best = related.json()["results"][0]
        assert best["id"] == 11 and best["relation"]["kind"] == "on"
        assert [a["id"] for a in best["relation"]["anchors"]] == [2]
        # the export keeps the tower, embeddings and all; its import reads the same
        export = http.get(f"/v1/sessions/{sid}/export", params={"embeddings": "true"}).json()
        assert export["session"]["text_tower"] == "static"
        assert export["session"]["embedding"] == {
            "model": tower.model_id,
            "dim": DIM,
            "sha256": tower.tower.sha256,
        }
        again = http.post("/v1/sessions/import", json=export)
        assert again.status_code == 201, again.text
        assert again.json()["embedding"] == export["session"]["embedding"]
        # embeddings of another tower cannot come in under this server's
        other = dict(export, session=dict(export["session"]))
        other["session"]["embedding"] = dict(export["session"]["embedding"], sha256="1" * 64)
        refused = http.post("/v1/sessions/import", json=other)
        assert refused.status_code == 422 and "session.embedding.sha256" in refused.json()["detail"]
        # a MiniLM export stays MiniLM, and says nothing of towers
        minilm = http.post("/v1/sessions/import", json=map_export(SCENE, "plain"))
        plain_export = http.get(f"/v1/sessions/{minilm.json()['session_id']}/export").json()
        assert "text_tower" not in plain_export["session"]
        assert plain_export["session"]["embedding"] == {"model": DEFAULT_MODEL_ID, "dim": 384}


def StaticEncoderOf(path: Path):  # noqa: N802 (reads as the encoder it returns)
    """The tower in `path` as the server embeds a map with it (labels with their texts)."""
    from app.answering.towers import map_static_encoder

    return map_static_encoder(StaticTower.from_bytes(path.read_bytes()))


def test_a_restart_loads_a_static_session_with_the_tower_it_was_created_with(
    live_server, tower_file, tmp_path
):
    first = live_server(api_key=API_KEY, static_tower=str(tower_file))
    with client(first) as http:
        sid = http.post("/v1/sessions/import", json=static_export("kept")).json()["session_id"]
        embedding = http.get(f"/v1/sessions/{sid}").json()["embedding"]
        before = http.get(f"/v1/sessions/{sid}/query", params={"text": "a mug", "k": 5}).json()
    first.stop()
    # without --static-tower: the server kept the tower it was given in its data dir
    second = live_server(api_key=API_KEY)
    with client(second) as http:
        assert http.get(f"/v1/sessions/{sid}").json()["embedding"] == embedding
        after = http.get(f"/v1/sessions/{sid}/query", params={"text": "a mug", "k": 5}).json()
        assert [(h["id"], h["score"]) for h in after["results"]] == [
            (h["id"], h["score"]) for h in before["results"]
        ]
        served = httpx.get(f"{second.url}/v1/text-towers/{embedding['sha256']}", timeout=30)
        assert served.content == tower_file.read_bytes()
    second.stop()
    shutil.rmtree(tmp_path / "data" / TOWERS_DIR)
    other = tmp_path / "other.tower"
    other.write_bytes(tiny_tower(seed=1).to_bytes())
    third = live_server(api_key=API_KEY, static_tower=str(other))
    with client(third) as http:
        refused = http.get(f"/v1/sessions/{sid}")
        assert refused.status_code == 409
        detail = refused.json()["detail"]
        assert embedding["sha256"] in detail and "--static-tower" in detail
        for socket in ("stream", "updates"):  # the sockets say it as REST does
            url = f"{third.ws_url}/v1/sessions/{sid}/{socket}?token={API_KEY}"
            assert _handshake(url) == (409, detail)
        # new static sessions get the tower this server was started with
        new = create(http, text_tower="static").json()["embedding"]
        assert new["sha256"] == hashlib.sha256(other.read_bytes()).hexdigest()
        assert http.get("/v1/sessions").status_code == 200  # listing needs no map


def _handshake(url: str) -> tuple[int, str] | str:
    """A socket's handshake: "open", or the HTTP status and detail it was refused with."""

    async def go():
        try:
            async with websockets.connect(url, open_timeout=10):
                return "open"
        except websockets.InvalidStatus as exc:
            return exc.response.status_code, json.loads(exc.response.body)["detail"]

    return asyncio.run(go())


def test_a_tower_file_from_another_teacher_stops_the_server_from_starting(tmp_path):
    from app.server.towers import TowerFileError, read_tower_file

    path = tmp_path / "clip.tower"
    path.write_bytes(tiny_tower(teacher="someone/clip").to_bytes())
    with pytest.raises(TowerFileError, match="someone/clip"):
        read_tower_file(path, DEFAULT_MODEL_ID)
    path.write_bytes(b"not a tower")
    with pytest.raises(TowerFileError, match="not a static text tower"):
        read_tower_file(path, DEFAULT_MODEL_ID)


def test_rerank_answers_a_static_session_with_its_teacher_and_says_so(server, tower_file, encoder):
    tower = StaticEncoderOf(tower_file)
    with client(server) as http:
        sid = http.post("/v1/sessions/import", json=static_export("room")).json()["session_id"]
        own = http.get(f"/v1/sessions/{sid}/query", params={"text": "somewhere to sit"}).json()
        assert own["ranked_by"] == tower.model_id
        again = http.get(
            f"/v1/sessions/{sid}/query", params={"text": "somewhere to sit", "rerank": "true"}
        ).json()
        assert again["ranked_by"] == DEFAULT_MODEL_ID
        # the teacher's ranking: its cosine of the question with each hit's label, best first
        question = encoder.encode_query("somewhere to sit")
        scores = [hit["score"] for hit in again["results"]]
        assert scores == sorted(scores, reverse=True)
        for hit in again["results"]:
            expected = float(encoder.encode([hit["label"]])[0] @ question)
            assert hit["score"] == pytest.approx(expected, abs=1e-5)
        assert again["results"][0]["label"] in ("sofa", "chair")  # the tiny tower knows no seat
        related = http.get(
            f"/v1/sessions/{sid}/query",
            params={"text": "the mug on the shelf", "k": 3, "rerank": "true"},
        ).json()
        assert related["ranked_by"] == DEFAULT_MODEL_ID
        assert (
            related["results"][0]["id"] == 11 and related["results"][0]["relation"]["kind"] == "on"
        )
        # a MiniLM session is its own teacher: nothing to re-rank
        minilm = http.post("/v1/sessions/import", json=map_export(SCENE, "plain")).json()
        plain = http.get(
            f"/v1/sessions/{minilm['session_id']}/query",
            params={"text": "the sofa", "rerank": "true"},
        ).json()
        assert plain["ranked_by"] == DEFAULT_MODEL_ID


@pytest.mark.slow
def test_a_spoken_question_is_reranked_as_the_typed_one(live_server, tower_file, tmp_path):
    """`rerank=true` on `POST .../query/speech` re-ranks as on the typed query: the page asks
    both ways with it."""
    from spoken import ASR_TIMEOUT_S, speak

    wav = speak("where is the sofa", tmp_path / "q.wav").read_bytes()
    server = live_server(api_key=API_KEY, static_tower=str(tower_file), asr_timeout_s=ASR_TIMEOUT_S)
    with httpx.Client(
        base_url=server.url, headers={"Authorization": f"Bearer {API_KEY}"}, timeout=120
    ) as http:
        sid = http.post("/v1/sessions/import", json=static_export("room")).json()["session_id"]
        path = f"/v1/sessions/{sid}/query/speech"
        heard = {}
        for rerank in ("false", "true"):
            reply = http.post(
                path,
                params={"rerank": rerank, "points": "false"},
                content=wav,
                headers={"Content-Type": "audio/wav"},
            )
            assert reply.status_code == 200, reply.text
            heard[rerank] = reply.json()
        typed = http.get(
            f"/v1/sessions/{sid}/query",
            params={"text": heard["true"]["transcript"], "rerank": "true", "points": "false"},
        ).json()
    assert heard["false"]["ranked_by"] == StaticEncoderOf(tower_file).model_id
    assert heard["true"]["ranked_by"] == DEFAULT_MODEL_ID
    assert [h["id"] for h in heard["true"]["results"]] == [h["id"] for h in typed["results"]]
