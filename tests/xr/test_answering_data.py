"""`GET /v1/answering/{model_id}` (app/server/routes/answering_data.py) on a real server: what
the page rates offline answers by, exactly what the server's rater reads."""

from __future__ import annotations

import base64
import io
from importlib import resources

import httpx
import numpy as np
import pytest

from app.answering.relevance import (
    background_text_list,
    background_texts,
    background_vocabulary,
    rule_for,
    texts_of,
)
from app.relations.grammar import question_phrases
from app.semantics import DEFAULT_MODEL_ID

pytestmark = pytest.mark.timeout(120)


def test_the_answering_data_is_the_servers_rule_background_and_reader(live_server):
    server = live_server(api_key="sesame")  # public: no credential needed
    got = httpx.get(f"{server.url}/v1/answering/{DEFAULT_MODEL_ID}", timeout=30)
    assert got.status_code == 200, got.text
    assert got.headers["cache-control"] == "no-cache"
    data = got.json()
    rule = rule_for(DEFAULT_MODEL_ID)
    assert data["model"] == DEFAULT_MODEL_ID
    assert data["rule"] == {
        "w_z": rule.w_z,
        "w_gap": rule.w_gap,
        "w_name": rule.w_name,
        "bias": rule.bias,
        "alike_cosine": rule.alike_cosine,
    }
    shipped = background_texts()
    assert data["background"] == [[lb, texts_of(lb, shipped)] for lb in background_vocabulary()]
    phrases = question_phrases()
    relational = data["relational"]
    assert set(relational["anchored"]) | set(relational["from_asker"]) == set(phrases["relations"])
    assert {"on", "next to", "in front of"} <= set(relational["anchored"])
    assert {"on my left", "nearby", "in front"} <= set(relational["from_asker"])
    assert relational["superlatives"] == phrases["superlatives"]
    # MiniLM's shipped background embeddings, as the rater reads them (float16 -> float32)
    rows = data["background_embeddings"]
    assert rows["texts"] == background_text_list() and rows["dtype"] == "float16"
    served = np.frombuffer(base64.b64decode(rows["rows"]), "<f2").reshape(-1, rows["dim"])
    npz = resources.files("app.answering").joinpath(
        "background_embeddings", f"{DEFAULT_MODEL_ID}.npz"
    )
    with np.load(io.BytesIO(npz.read_bytes())) as stored:
        assert np.array_equal(served, stored["embeddings"])


def test_a_tower_without_shipped_embeddings_gets_none_and_a_bad_id_a_422(live_server):
    server = live_server()
    other = httpx.get(f"{server.url}/v1/answering/static-0123456789abcdef", timeout=30).json()
    assert other["background_embeddings"] is None  # the page embeds the texts with its tower
    assert other["rule"]["w_z"] == rule_for("static-0123456789abcdef").w_z
    slash = httpx.get(f"{server.url}/v1/answering/openai/clip-vit-b-16", timeout=30)
    assert slash.status_code == 200 and slash.json()["model"] == "openai/clip-vit-b-16"
    long = httpx.get(f"{server.url}/v1/answering/{'m' * 129}", timeout=30)
    assert long.status_code == 422 and "model_id" in long.json()["detail"]
