"""Questions about relations, from outside: a client written only from README.md and
docs/protocol.md, with its own room (outside_room.py) and its own phrasing set
(outside_phrasings.py), asks a real server relational, negative and plain questions and
measures:

- top-1 on the relational questions (the first hit is one of the right objects),
- the share of negatives answered `match: false`,
- top-1 on the plain questions (and that they are answered plainly: `relation` null).

It prints a per-question table (`pytest -s` shows it) and holds the server to the relations
targets (docs/evaluation.md "Targets"): >= 90 % top-1, every negative no match, every plain
question right.
"""

import urllib.parse

import httpx
import pytest
from outside_phrasings import NEGATIVE, PLAIN, RELATIONAL
from outside_room import ROOM, build_export

pytestmark = [pytest.mark.timeout(90), pytest.mark.slow]

TARGET_TOP1 = 0.90
TARGET_NEGATIVES = 1.0
# Written at 6519aa1, where 35 of 40 held: an anchor named more loosely than its label ("the
# counter" for a kitchen counter, "the table" with a dining and a side table) did not ground,
# and the question fell back to a plain answer. Since anchors and targets ground by their head
# noun too (relational.HEAD_NOUN_RELEVANCE) 39 of 40 hold; the miss, "the chair closest to the
# table", is ambiguous here (two tables). The room's noise seed matters at the margin: with
# seeds 1-5 instead of 27 it was 34 of 40 before that change.
FLOOR_RELATIONAL_TOP1 = TARGET_TOP1
FLOOR_NEGATIVES_NO_MATCH = TARGET_NEGATIVES
FLOOR_PLAIN_TOP1 = 1.0


def _ask(client, sid, text, asker=None):
    params = {"text": text, "k": 5, "points": "false"}
    if asker is not None:
        params["from"] = ",".join(f"{v:g}" for v in asker)
    r = client.get(f"/v1/sessions/{sid}/query?{urllib.parse.urlencode(params)}")
    assert r.status_code == 200, (text, r.status_code, r.text)
    return r.json()


def _describe(answer, names):
    if not answer["results"]:
        return "-", "-", "-", answer["match"]
    top = answer["results"][0]
    rel = top.get("relation")
    kind = "-"
    if rel:
        anchors = "+".join(names.get(a["id"], str(a["id"])) for a in rel.get("anchors", []))
        kind = f"{rel['kind']}({anchors})" if anchors else rel["kind"]
    degree = f"{rel['degree']:.2f}" if rel else "-"
    return (
        f"{names.get(top['id'], top['id'])}#{top['id']} [{top['label']}]",
        kind,
        degree,
        answer["match"],
    )


@pytest.fixture(scope="module")
def room_session(outside_server):
    with httpx.Client(base_url=outside_server, timeout=30.0) as client:
        # the embedding the import must declare is the server's: ask a throwaway session
        probe = client.post("/v1/sessions", json={"name": "outside-probe"})
        assert probe.status_code == 201, probe.text
        embedding = probe.json()["embedding"]
        assert client.delete(f"/v1/sessions/{probe.json()['session_id']}").status_code == 204

        export, ids = build_export(embedding)
        r = client.post("/v1/sessions/import", json=export)
        assert r.status_code == 201, r.text
        sid = r.json()["session_id"]
        yield client, sid, ids


@pytest.fixture(scope="module")
def answers(room_session):
    client, sid, ids = room_session
    names = {i: key for key, i in ids.items()}
    rows = {"relational": [], "negative": [], "plain": []}
    for text, want, asker in RELATIONAL:
        a = _ask(client, sid, text, asker)
        ok = bool(a["results"]) and a["results"][0]["id"] in {ids[k] for k in want}
        rows["relational"].append((text, "/".join(sorted(want)), ok, *_describe(a, names)))
    for text in NEGATIVE:
        a = _ask(client, sid, text)
        # no match for the right reason: asked as a relation, nothing stands in it
        relational = bool(a["results"]) and a["results"][0].get("relation") is not None
        rows["negative"].append(
            (text, "no match", not a["match"] and relational, *_describe(a, names))
        )
    for text, want in PLAIN:
        a = _ask(client, sid, text)
        ok = bool(a["results"]) and a["results"][0]["id"] in {ids[k] for k in want}
        plain = all(h.get("relation") is None for h in a["results"])
        rows["plain"].append((text, "/".join(sorted(want)), ok and plain, *_describe(a, names)))

    lines = []
    for kind, table in rows.items():
        lines.append(f"\n== {kind} ({sum(r[2] for r in table)}/{len(table)}) ==")
        lines.append(
            f"{'':2} {'question':50} {'expected':24} {'top-1':34} {'relation':32} {'deg':5} match"
        )
        for text, want, ok, top, rel, deg, match in table:
            lines.append(
                f"{'ok' if ok else 'XX':2} {text:50} {want:24} {top:34} {rel:32} {deg:5} {match}"
            )
    share = {k: sum(r[2] for r in t) / len(t) for k, t in rows.items()}
    lines.append(
        f"\nrelational top-1 {share['relational']:.1%} (target {TARGET_TOP1:.0%}), "
        f"negatives no-match {share['negative']:.1%} (target {TARGET_NEGATIVES:.0%}), "
        f"plain top-1 {share['plain']:.1%}"
    )
    print("\n".join(lines))
    return rows, share


def test_the_room_is_the_map(room_session):
    client, sid, ids = room_session
    objects = client.get(f"/v1/sessions/{sid}/objects?points=false").json()
    assert sorted((o["id"], o["label"]) for o in objects) == sorted(
        (ids[t.key], t.label) for t in ROOM
    )


def test_phrasing_set_is_big_enough():
    assert len(RELATIONAL) >= 30 and len(NEGATIVE) >= 8 and len(PLAIN) >= 8


def test_relational_top1(answers):
    rows, share = answers
    assert share["relational"] >= FLOOR_RELATIONAL_TOP1


def test_negatives_no_match(answers):
    rows, share = answers
    assert share["negative"] >= FLOOR_NEGATIVES_NO_MATCH


def test_plain_questions_are_answered_plainly(answers):
    rows, share = answers
    assert share["plain"] >= FLOOR_PLAIN_TOP1
