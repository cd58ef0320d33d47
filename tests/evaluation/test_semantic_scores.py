"""Semantic quality (docs/evaluation.md "Evaluation definitions") on point sets scored by hand."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from evaluation.semantic_scores import (
    SemanticScores,
    assign_classes_by_text,
    majority_gt_class,
    semantic_scores,
)

CLASSES = ["chair", "table", "floor"]
CHAIR, TABLE, FLOOR = 0, 1, 2


def on_x_axis(*xs: float) -> np.ndarray:
    """Points [N, 3] at the given x (metres), y = z = 0."""
    return np.array([[x, 0.0, 0.0] for x in xs], dtype=np.float64)


def hand_scored_scene() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """GT: 4 chair points, 2 table points, 2 floor points; a map that gets some right.

    chair GT at x=0,1,2,3: map says chair, chair, table, (nothing within 5 cm) -> TP 2/4.
    table GT at x=10,11:   map says table, chair (3 cm away)              -> TP 1/2.
    floor GT at x=20,21:   map says table, nothing                         -> ignored.
    Pred over evaluated points: chair 3 (x=0,1,11), table 2 (x=2,10).
    """
    gt_points = on_x_axis(0, 1, 2, 3, 10, 11, 20, 21)
    gt_class = np.array([CHAIR] * 4 + [TABLE] * 2 + [FLOOR] * 2)
    map_points = on_x_axis(0, 1, 2, 3.5, 10, 11.03, 20)
    map_class = np.array([CHAIR, CHAIR, TABLE, CHAIR, TABLE, CHAIR, TABLE])
    return map_points, map_class, gt_points, gt_class


def test_hand_scored_scene_gives_the_hand_computed_scores() -> None:
    scores = semantic_scores(*hand_scored_scene(), CLASSES)
    # recall: chair 2/4, table 1/2; IoU: chair 2/(4+3-2), table 1/(2+2-1)
    assert scores.per_class["chair"] == {"recall": 50.0, "iou": 40.0, "gt_points": 4}
    assert scores.per_class["table"]["recall"] == pytest.approx(50.0)
    assert scores.per_class["table"]["iou"] == pytest.approx(100 / 3)
    assert scores.mAcc == pytest.approx(50.0)
    assert scores.F_mIoU == pytest.approx((40.0 * 4 + 100 / 3 * 2) / 6)


def test_ignored_classes_get_no_score_and_do_not_count() -> None:
    scores = semantic_scores(*hand_scored_scene(), CLASSES)
    assert "floor" not in scores.per_class
    assert sum(entry["gt_points"] for entry in scores.per_class.values()) == 6


def test_ignored_classes_are_matched_case_insensitively() -> None:
    scores = semantic_scores(*hand_scored_scene(), ["chair", "table", "Floor"])
    assert "Floor" not in scores.per_class


def test_not_ignoring_a_class_scores_it() -> None:
    scores = semantic_scores(*hand_scored_scene(), CLASSES, ignore_classes=())
    assert scores.per_class["floor"] == {"recall": 0.0, "iou": 0.0, "gt_points": 2}
    assert scores.mAcc == pytest.approx((50 + 50 + 0) / 3)


def test_predicting_an_ignored_class_counts_as_wrong() -> None:
    gt_points = on_x_axis(0, 1)
    scores = semantic_scores(
        on_x_axis(0, 1), np.array([FLOOR, CHAIR]), gt_points, np.array([CHAIR, CHAIR]), CLASSES
    )
    assert scores.per_class["chair"]["recall"] == 50.0
    assert scores.mAcc == 50.0


def test_map_point_exactly_at_the_radius_labels_the_gt_point() -> None:
    radius_m = 0.0625  # a power of two: the distance is exact in floating point
    scores = semantic_scores(
        on_x_axis(radius_m),
        np.array([CHAIR]),
        on_x_axis(0),
        np.array([CHAIR]),
        CLASSES,
        radius_m=radius_m,
    )
    assert scores.mAcc == 100.0


def test_map_point_just_beyond_the_radius_leaves_the_gt_point_unlabelled() -> None:
    scores = semantic_scores(
        on_x_axis(0.0501), np.array([CHAIR]), on_x_axis(0), np.array([CHAIR]), CLASSES
    )
    assert scores.per_class["chair"] == {"recall": 0.0, "iou": 0.0, "gt_points": 1}


def test_a_larger_radius_reaches_farther_map_points() -> None:
    args = (on_x_axis(0.2), np.array([CHAIR]), on_x_axis(0), np.array([CHAIR]), CLASSES)
    assert semantic_scores(*args, radius_m=0.05).mAcc == 0.0
    assert semantic_scores(*args, radius_m=0.25).mAcc == 100.0


def test_gt_point_nearest_to_an_unlabelled_map_point_is_unlabelled() -> None:
    # The nearer map point is unlabelled; the farther (still in radius) chair point is not used.
    scores = semantic_scores(
        on_x_axis(0.01, 0.04), np.array([-1, CHAIR]), on_x_axis(0), np.array([CHAIR]), CLASSES
    )
    assert scores.mAcc == 0.0


def test_empty_map_scores_zero_without_crashing() -> None:
    _, _, gt_points, gt_class = hand_scored_scene()
    scores = semantic_scores(np.zeros((0, 3)), np.zeros(0, int), gt_points, gt_class, CLASSES)
    assert (scores.mAcc, scores.F_mIoU) == (0.0, 0.0)
    assert scores.per_class["chair"] == {"recall": 0.0, "iou": 0.0, "gt_points": 4}


def test_ground_truth_of_only_ignored_classes_scores_zero() -> None:
    scores = semantic_scores(
        on_x_axis(0), np.array([FLOOR]), on_x_axis(0), np.array([FLOOR]), CLASSES
    )
    assert scores == SemanticScores(mAcc=0.0, F_mIoU=0.0, per_class={})


def test_scores_serialise_to_plain_json_types() -> None:
    as_dict = semantic_scores(*hand_scored_scene(), CLASSES).to_dict()
    assert set(as_dict) == {"mAcc", "F_mIoU", "per_class"}
    assert type(as_dict["mAcc"]) is float
    assert type(as_dict["per_class"]["chair"]["gt_points"]) is int


def test_class_index_out_of_range_is_a_value_error() -> None:
    with pytest.raises(ValueError, match="map_point_class"):
        semantic_scores(on_x_axis(0), np.array([3]), on_x_axis(0), np.array([0]), CLASSES)


@settings(max_examples=30, deadline=None)
@given(
    cells=st.sets(st.tuples(*[st.integers(0, 20)] * 3), min_size=1, max_size=80),
    data=st.data(),
)
def test_a_perfect_map_scores_100_on_both_metrics(cells: set, data: st.DataObject) -> None:
    class_names = ["chair", "table", "lamp", "wall"]
    points_m = np.array(sorted(cells), dtype=np.float64) * 0.1  # distinct, 10 cm apart
    point_class = np.array(
        data.draw(st.lists(st.integers(0, 3), min_size=len(points_m), max_size=len(points_m)))
    )
    assume(np.any(point_class != 3))  # at least one class that is not ignored
    scores = semantic_scores(points_m, point_class, points_m, point_class, class_names)
    assert scores.mAcc == pytest.approx(100.0)
    assert scores.F_mIoU == pytest.approx(100.0)


# --- assign_classes_by_text -----------------------------------------------------------------


def test_each_object_gets_the_class_of_highest_cosine() -> None:
    class_text = np.eye(3)
    objects = np.array([[0.1, 0.9, 0.0], [0.0, 0.2, -0.5], [5.0, 1.0, 0.0]])
    # the last object is not unit length: cosine, not dot product, decides
    np.testing.assert_array_equal(assign_classes_by_text(objects, class_text), [1, 1, 0])


def test_cosine_not_dot_product_decides_between_classes_of_different_norms() -> None:
    class_text = np.array([[10.0, 0.0], [0.6, 0.8]])
    np.testing.assert_array_equal(assign_classes_by_text(np.array([[0.5, 0.8]]), class_text), [1])


def test_no_objects_gives_no_classes() -> None:
    assigned = assign_classes_by_text(np.zeros((0, 4)), np.eye(4))
    assert assigned.shape == (0,) and assigned.dtype == np.int64


def test_mismatched_embedding_dimensions_are_a_value_error() -> None:
    with pytest.raises(ValueError, match="dimension"):
        assign_classes_by_text(np.ones((2, 3)), np.eye(4))


# --- majority_gt_class ----------------------------------------------------------------------


def test_each_object_gets_its_majority_gt_class() -> None:
    gt_points = on_x_axis(0, 0.1, 0.2, 5, 5.1)
    gt_class = np.array([CHAIR, CHAIR, TABLE, TABLE, TABLE])
    objects = [on_x_axis(0, 0.1, 0.2), on_x_axis(5.01, 5.1), on_x_axis(9)]
    np.testing.assert_array_equal(majority_gt_class(objects, gt_points, gt_class), [0, 1, -1])


def test_majority_ties_go_to_the_lower_class_index() -> None:
    gt_points = on_x_axis(0, 1)
    objects = [on_x_axis(1, 0)]
    np.testing.assert_array_equal(
        majority_gt_class(objects, gt_points, np.array([TABLE, CHAIR])), [CHAIR]
    )


def test_objects_without_points_or_without_ground_truth_get_minus_one() -> None:
    assert majority_gt_class([np.zeros((0, 3))], on_x_axis(0), np.array([0])).tolist() == [-1]
    assert majority_gt_class([on_x_axis(0)], np.zeros((0, 3)), np.zeros(0, int)).tolist() == [-1]
