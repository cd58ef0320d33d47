"""`semanticxr eval --scenario relations`: questions about how things stand, asked of a map of a
relation room, scored against the room's geometry."""

from __future__ import annotations

import json

import pytest

from app import semantics
from app.cli import main
from evaluation.relations import _ask, _perfect_view
from world.gt import gt_point_cloud
from world.relation_scenes import make_relation_scene, relation_walk


def test_a_perfect_map_of_a_relation_room_tells_the_duplicates_apart(encoder):
    scene = make_relation_scene(0)
    viewer = relation_walk(scene, 60, 0)[-1][:3, 3]
    view = _perfect_view(scene, gt_point_cloud(scene), encoder, viewer, 200)
    things = {o.instance_id: o for o in scene.objects}

    def support_of(text: str) -> str:
        got = _ask(text, view, encoder)
        assert got.relational and got.match, text
        return things[things[got.top_id].support_id].category

    assert support_of("the mug on the desk") == "desk"
    assert support_of("the mug on the dining table") == "dining table"
    assert support_of("the backpack on the chair") == "chair"


@pytest.mark.slow
def test_the_relations_scenario_writes_the_documented_json(tmp_path, encoder, monkeypatch, capsys):
    monkeypatch.setattr(semantics, "get_text_encoder", lambda: encoder)  # loaded once per session
    out = tmp_path / "relations.json"
    code = main(
        [
            "eval", "--scenario", "relations", "--seeds", "1", "--frames", "40",
            "--width", "160", "--height", "120", "--min-mapping-bbox-area", "125",
            "--noise", "none", "--json", str(out),
        ]
    )  # fmt: skip
    assert code == 0
    printed = capsys.readouterr()
    assert "relational top-1" in printed.out and "[relations]" in printed.err
    result = json.loads(out.read_text())
    assert (result["scenario"], result["seeds"], result["noise"]) == ("relations", [0], "none")
    relations = result["relations"]
    for key in ("top1", "negatives_no_match", "right_answers_match", "plain_top1"):
        assert relations[key] is None or 0 <= relations[key] <= 100, key
    assert 0 <= relations["lq_equals_sq"] <= 100 and relations["lq_asked"] > 0
    assert 0 <= relations["plain_path_top1"] <= 100
    assert set(relations["index_update_ms"]) >= {"p50", "p95"}
    asked = relations["asked"]
    assert relations["questions"] == sum(asked.values()) and asked["relational"] > 0
    assert sum(slot["asked"] for slot in relations["by_kind"].values()) == (
        asked["relational"] + asked["any"] + asked["negative"]
    )
    for failure in relations["failures"]:
        assert {"question", "expected", "got", "reason"} <= set(failure)
