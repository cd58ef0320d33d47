"""Relational questions through a real server on loopback: a known map imported, the right
copy at top-1 with its relation, plain questions answered exactly as before."""

from __future__ import annotations

import httpx
import pytest
from relation_scene import SCENE, map_export

from app.protocol.rest import QueryResult

API_KEY = "relations-test-key"


@pytest.fixture
def http(live_server):
    server = live_server(api_key=API_KEY)
    with httpx.Client(
        base_url=server.url, headers={"Authorization": f"Bearer {API_KEY}"}, timeout=60
    ) as client:
        yield client


@pytest.fixture
def sid(http):
    """A session holding SCENE (Z-up, no device pose: up is Z, no asker's position)."""
    export = map_export(SCENE, "relations")
    created = http.post("/v1/sessions/import", json=export)
    assert created.status_code == 201, created.text
    return created.json()["session_id"]


def ask(http, sid, text, **params) -> QueryResult:
    reply = http.get(
        f"/v1/sessions/{sid}/query", params={"text": text, "points": "false", **params}
    )
    assert reply.status_code == 200, reply.text
    return QueryResult.model_validate(reply.json(), strict=True)


def test_relational_questions_answer_the_right_copy_with_their_relation(http, sid):
    for text, expected, kind, anchor in [
        ("the mug on the desk", 10, "on", 1),
        ("which chair is next to the sofa", 21, "next_to", 4),
        ("what is under the table", 30, "under", 3),
    ]:
        result = ask(http, sid, text)
        best = result.results[0]
        assert best.id == expected, (text, [(h.id, h.label) for h in result.results])
        assert best.relation is not None and best.relation.kind == kind
        assert [(a.id, a.label) for a in best.relation.anchors] == [(anchor, SCENE[anchor][0])]
        assert result.match
    nothing = ask(http, sid, "the mug under the sofa")
    assert nothing.results[0].label == "mug" and nothing.results[0].relation.degree == 0.0
    assert not nothing.match


@pytest.mark.parametrize("text", ["where is the sofa", "where are my keys", "keys on a ring"])
def test_plain_questions_are_answered_as_before(http, sid, text):
    result = ask(http, sid, text)
    # include=removed takes today's path whatever the question; with nothing removed it
    # ranks the same objects
    before = ask(http, sid, text, include="removed")
    assert all(h.relation is None for h in result.results)
    assert result.model_dump(exclude={"latency_ms"}) == before.model_dump(exclude={"latency_ms"})


def test_the_asker_may_say_where_they_stand(http, sid):
    """`from=x,y,z` places the asker ("closest to me"); without it (this imported map has no
    pose) the question is answered as a plain one."""
    for where, expected in [("3.3,0.1,1.5", 11), ("1.0,3.4,1.5", 12), ("0.5,0.2,1.5", 10)]:
        result = ask(http, sid, "the mug closest to me", **{"from": where})
        assert result.results[0].id == expected, (where, [h.id for h in result.results])
        assert result.results[0].relation is not None
    assert all(h.relation is None for h in ask(http, sid, "the mug closest to me").results)


@pytest.mark.parametrize("where", ["1,2", "a,b,c", "nan,0,0", "1,2,3,4", "1e9,0,0", "", "9" * 101])
def test_a_bad_from_gets_422_naming_it(http, sid, where):
    reply = http.get(
        f"/v1/sessions/{sid}/query", params={"text": "the mug closest to me", "from": where}
    )
    assert reply.status_code == 422, reply.text
    assert "from" in reply.json()["detail"]
