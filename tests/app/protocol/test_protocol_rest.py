"""REST bodies: the records the server answers with, and what a client parses back."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.config import Knobs, knobs_to_dict
from app.errors import InputError
from app.protocol import (
    PROTOCOL_VERSION,
    EmbeddingInfo,
    ObjectRecord,
    QueryHit,
    QueryResult,
    SessionCreated,
    SessionStats,
    SessionSummary,
    parse_query_result,
    parse_record,
)

FEW = settings(max_examples=40, deadline=None)
coordinate = st.floats(-100, 100, allow_nan=False).map(lambda v: round(v, 4))
hits = st.builds(
    QueryHit,
    id=st.integers(0, 10**9),
    label=st.text(max_size=30),
    score=st.floats(-1, 1).map(lambda v: round(v, 5)),
    relevance=st.floats(0, 1).map(lambda v: round(v, 5)),
    bbox=st.lists(coordinate, min_size=6, max_size=6),
    centroid=st.lists(coordinate, min_size=3, max_size=3),
    points=st.none()
    | st.lists(st.lists(coordinate, min_size=3, max_size=3), max_size=5).map(
        lambda rows: np.asarray(rows, np.float32).reshape(-1, 3)
    ),
)
results = st.builds(
    QueryResult,
    text=st.text(min_size=1, max_size=50),
    match=st.booleans(),
    results=st.lists(hits, max_size=4),
    latency_ms=st.floats(0, 1e4),
)


@FEW
@given(result=results)
def test_a_query_result_survives_to_json_json_parse(result):
    parsed = parse_query_result(json.loads(json.dumps(result.to_json())))
    assert parsed.text == result.text and parsed.latency_ms == result.latency_ms
    assert parsed.match == result.match
    assert len(parsed.results) == len(result.results)
    for got, sent in zip(parsed.results, result.results, strict=True):
        assert (got.id, got.label, got.score) == (sent.id, sent.label, sent.score)
        assert got.relevance == sent.relevance
        assert got.bbox == list(sent.bbox) and got.centroid == list(sent.centroid)
        if sent.points is None:
            assert got.points is None
        else:
            np.testing.assert_allclose(got.points, sent.points, atol=1e-6)


def _answer() -> dict:
    hit = QueryHit(
        id=3, label="mug", score=0.5, relevance=0.9, bbox=[0, 0, 0, 1, 1, 1], centroid=[0.5] * 3
    )
    return QueryResult(text="a mug", match=True, results=[hit], latency_ms=1.0).to_json()


def _hit(**changes) -> dict:
    answer = _answer()
    answer["results"][0].update(changes)
    return answer


MALFORMED = [
    ("body", []),
    ("text", {**_answer(), "text": 3}),
    ("results", {**_answer(), "results": None}),
    ("latency_ms", {k: v for k, v in _answer().items() if k != "latency_ms"}),
    ("results[0]", {**_answer(), "results": [3]}),
    ("results[0].id", _hit(id="3")),
    ("results[0].score", _hit(score=True)),
    ("match", {**_answer(), "match": "yes"}),
    ("results[0].relevance", _hit(relevance=1.5)),
    ("results[0].bbox", _hit(bbox=[0, 0, 0])),
    ("results[0].centroid", _hit(centroid=[0, "x", 0])),
    ("results[0].points", _hit(points=[[0, 1]])),
]


@pytest.mark.parametrize(("field", "body"), MALFORMED, ids=[f for f, _ in MALFORMED])
def test_a_malformed_query_answer_raises_one_error_naming_the_field(field, body):
    with pytest.raises(InputError) as err:
        parse_query_result(body)
    assert err.value.field == field, str(err.value)


def test_session_records_answer_v1_bodies_with_the_protocol_version():
    knobs = knobs_to_dict(Knobs())
    created = SessionCreated(
        session_id="s1", token="tok", embedding=EmbeddingInfo(model="minilm", dim=384), knobs=knobs
    ).to_json()
    assert created == {
        "session_id": "s1",
        "token": "tok",
        "embedding": {"model": "minilm", "dim": 384},
        "knobs": knobs,
        "protocol": PROTOCOL_VERSION,
    }
    stats = {
        "session_id": "s1",
        "name": "n",
        "mode": "semanticxr",
        "perception": "detections",
        "created_at": 1.0,
        "frames": 10,
        "frames_whole": 4,
        "sightings": 6,
        "keyframes": 2,
        "dropped_frames": 0,
        "objects": 3,
        "fps": 5.0,
        "bytes_in": {"total": 9},
        "bytes_out": {"total": 4},
        "mapping_latency_ms": {"p50": None, "p95": None},
        "update_seq": 7,
        "subscribers": 0,
        "embedding": {"model": "minilm", "dim": 384},
        "knobs": knobs,
        "warnings": ["frames arrive without detections"],
        "something_newer": 1,  # a stats key beyond the record is left out
    }
    assert SessionStats.model_validate(stats).to_json() == {
        k: v for k, v in stats.items() if k != "something_newer"
    }
    assert SessionSummary.model_validate(stats).to_json() == {
        "session_id": "s1",
        "name": "n",
        "mode": "semanticxr",
        "objects": 3,
        "frames": 10,
        "frames_whole": 4,
        "sightings": 6,
        "keyframes": 2,
        "fps": 5.0,
        "update_seq": 7,
        "resident": True,  # a server before stored sessions listed only the ones in memory
        "last_used_at": None,
    }


def test_stats_of_a_server_that_does_not_count_sightings_apart_parse_without_them():
    older = {
        "session_id": "s1",
        "name": "n",
        "mode": "semanticxr",
        "objects": 3,
        "frames": 10,
        "keyframes": 2,
        "fps": 5.0,
        "update_seq": 7,
    }
    summary = parse_record(SessionSummary, older)
    assert (summary.frames, summary.frames_whole, summary.sightings) == (10, None, None)


def test_a_malformed_stats_answer_raises_one_error_naming_the_field():
    with pytest.raises(InputError) as err:
        parse_record(SessionSummary, {"session_id": "s1", "name": "n", "mode": "semanticxr"})
    assert err.value.field == "objects", str(err.value)
    with pytest.raises(InputError) as err:
        parse_record(SessionStats, [1, 2])
    assert err.value.field == "body", str(err.value)


def test_an_object_record_rounds_geometry_and_leaves_out_points_not_asked_for():
    geometry = dict(bbox=[0.123456, 0, 0, 1, 1, 1], centroid=[0.5, 0.5, 0.55557])
    record = ObjectRecord(id=1, version=2, label="cup", n_obs=4, **geometry)
    assert record.to_json() == {
        "id": 1,
        "version": 2,
        "label": "cup",
        "bbox": [0.1235, 0.0, 0.0, 1.0, 1.0, 1.0],
        "centroid": [0.5, 0.5, 0.5556],
        "n_obs": 4,
        "state": "present",  # the living map: its times are null while unknown
        "first_seen_t": None,
        "last_seen_t": None,
    }
    points = np.array([[0.123456, 1, 2]], np.float32)
    with_points = ObjectRecord(id=1, version=2, label="cup", n_obs=4, points=points, **geometry)
    assert with_points.to_json()["points"] == [[0.1235, 1.0, 2.0]]
