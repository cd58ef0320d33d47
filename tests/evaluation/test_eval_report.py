"""What `semanticxr eval` reports: query top-1 over the categories in view, the
categories never in view, the failing queries, latency percentiles, and `--queries FILE`."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from app.config import Knobs
from evaluation.walk import (
    IN_VIEW_MIN_FRAMES,
    EvalConfig,
    format_eval_table,
    label_ceiling,
    load_queries,
    run_eval,
)
from world.rooms import make_scene

FRAMES = 60


@pytest.fixture(scope="module")
def kitchen_queries():
    categories = make_scene("kitchen", 0).categories_present
    return {name: [f"where is the {name}", f"show me a {name}"] for name in categories}


@pytest.fixture(scope="module")
def report(encoder, kitchen_queries):
    cfg = EvalConfig(
        scene="kitchen",
        frames=FRAMES,
        width=160,
        height=120,
        modes=("semanticxr",),
        knobs=Knobs(min_mapping_bbox_area=150),
        queries=kitchen_queries,
    )
    return run_eval(cfg, encoder, progress=lambda _: None)


def test_categories_in_view_for_too_few_frames_are_listed_as_unobserved(report):
    in_view = report["frames_in_view"]
    assert set(in_view) == set(make_scene("kitchen", 0).categories_present)
    expected = sorted(name for name, n in in_view.items() if n < IN_VIEW_MIN_FRAMES)
    assert report["unobserved_categories"] == expected
    assert expected and len(expected) < len(in_view)  # the short walk misses some, not all
    # every frame of the walk counts, not only the keyframes (one in five)
    assert max(in_view.values()) == FRAMES
    assert str(IN_VIEW_MIN_FRAMES) in report["in_view_definition"]


def test_query_top1_observed_is_over_the_queries_of_observed_categories(report, kitchen_queries):
    m = report["modes"]["semanticxr"]
    unobserved = set(report["unobserved_categories"])
    phrases = {p: name for name, ps in kitchen_queries.items() for p in ps}
    # the file replaced the built-in paraphrases: only its phrases were asked
    assert m["queries_asked"] == len(phrases)
    assert all(
        f["query"] in phrases and f["expected"] == phrases[f["query"]] for f in m["query_failures"]
    )
    assert all(set(f) == {"query", "expected", "got"} for f in m["query_failures"])
    asked = sum(1 for name in phrases.values() if name not in unobserved)
    failed = sum(1 for f in m["query_failures"] if f["expected"] not in unobserved)
    assert m["queries_asked_observed"] == asked
    assert m["query_top1_observed"] == pytest.approx(100.0 * (asked - failed) / asked)
    assert m["query_top1"] == pytest.approx(
        100.0 * (len(phrases) - len(m["query_failures"])) / len(phrases)
    )


def test_latency_is_reported_as_p50_p95_and_mean(report):
    lat = report["modes"]["semanticxr"]["latency_ms"]
    assert {"p50", "p95", "mean"} <= lat.keys()
    assert 0 < lat["p50"] <= lat["p95"]
    assert report["modes"]["semanticxr"]["mapping_total_ms"] >= lat["mean"]


def test_the_label_ceiling_ranks_the_queries_against_the_observed_names_only(encoder):
    queries = {
        "armchair": ["armchair", "a chair"],  # the second is lost to "chair" between labels
        "chair": ["chair"],
        "sofa": ["sofa"],  # not among the names: not asked
    }
    ceiling = label_ceiling(encoder, ["chair", "armchair"], queries)
    assert ceiling["queries_asked"] == 3
    assert ceiling["query_failures"] == [
        {"query": "a chair", "expected": "armchair", "got": "chair"}
    ]
    assert ceiling["query_top1_observed"] == pytest.approx(200 / 3)
    assert label_ceiling(encoder, [], queries)["queries_asked"] == 0


def test_the_report_carries_the_label_ceiling_over_the_observed_categories(report, kitchen_queries):
    ceiling = report["label_ceiling"]
    observed = set(kitchen_queries) - set(report["unobserved_categories"])
    assert ceiling["queries_asked"] == sum(len(kitchen_queries[name]) for name in observed)
    assert all(
        f["expected"] in observed and f["got"] in observed for f in ceiling["query_failures"]
    )
    failed = len(ceiling["query_failures"])
    assert ceiling["query_top1_observed"] == pytest.approx(
        100.0 * (ceiling["queries_asked"] - failed) / ceiling["queries_asked"]
    )
    table = format_eval_table(report)
    assert f"label-text ceiling: {ceiling['query_top1_observed']:.1f}%" in table
    for f in ceiling["query_failures"]:
        assert f"{f['expected']} -> {f['got']}" in table


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("{not json", "not valid JSON"),
        ("[]", "JSON object"),
        ('{"unicorn": ["a horse with a horn"]}', "unknown categories ['unicorn']"),
        ('{"sofa": []}', "'sofa' must map to a non-empty list"),
        ('{"sofa": ["a couch", 3]}', "'sofa' must map to a non-empty list"),
    ],
)
def test_a_bad_query_file_is_refused_with_a_clear_message(tmp_path, content, message):
    path = tmp_path / "queries.json"
    path.write_text(content)
    with pytest.raises(ValueError, match=message.replace("[", r"\[").replace("]", r"\]")):
        load_queries(str(path))


def test_a_good_query_file_loads(tmp_path):
    path = tmp_path / "queries.json"
    path.write_text(json.dumps({"sofa": [" a couch "], "mug": ["a cup for coffee"]}))
    assert load_queries(str(path)) == {"sofa": ["a couch"], "mug": ["a cup for coffee"]}


def test_eval_exits_2_naming_the_query_file_before_any_work(tmp_path):
    path = tmp_path / "queries.json"
    path.write_text('{"unicorn": ["x"]}')
    proc = subprocess.run(
        [sys.executable, "-m", "app.cli", "eval", "--queries", str(path)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2
    assert "--queries" in proc.stderr and "unicorn" in proc.stderr
    assert "keyframes" not in proc.stderr  # refused before rendering anything


def test_sightings_hand_the_non_keyframes_to_the_engines_unless_turned_off(encoder, report):
    assert report["sightings"] is True
    assert {"p50", "p95", "mean"} <= report["modes"]["semanticxr"]["sightings_ms"].keys()
    cfg = EvalConfig(
        scene="kitchen",
        frames=30,
        width=160,
        height=120,
        modes=("semanticxr",),
        knobs=Knobs(min_mapping_bbox_area=150),
        sightings=False,
    )
    result = run_eval(cfg, encoder, progress=lambda _: None)
    assert result["sightings"] is False
    assert result["modes"]["semanticxr"]["sightings_ms"] is None


def test_the_sightings_extension_path_hands_the_engines_parsed_sighting_messages(encoder):
    cfg = EvalConfig(
        scene="kitchen",
        frames=30,
        width=160,
        height=120,
        modes=("semanticxr",),
        knobs=Knobs(min_mapping_bbox_area=150),
        upstream="sightings",
    )
    result = run_eval(cfg, encoder, progress=lambda _: None)
    assert result["upstream"] == "sightings"
    assert {"p50", "p95", "mean"} <= result["modes"]["semanticxr"]["sightings_ms"].keys()
    with pytest.raises(ValueError, match="upstream must be one of frames, sightings"):
        run_eval(EvalConfig(upstream="carrier pigeon"), encoder, progress=lambda _: None)
