"""Semantic quality of a map (docs/evaluation.md "Evaluation definitions"); pure numpy/scipy.

The ConceptFusion/ConceptGraphs protocol: each map object takes the class whose text query
scores highest (`assign_classes_by_text`), every map point takes its object's class, and
every ground-truth point takes the class of its nearest map point, or none if no map point
lies within `radius_m` (`semantic_scores`). Scores are percentages from 0 to 100.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

UNLABELLED = -1
"""Class index of a point without a class."""


@dataclass
class SemanticScores:
    """Semantic quality of one map against one ground truth."""

    # Mixed-case names: the metrics' names in the papers and in `semanticxr eval --json`.
    mAcc: float
    """Mean over evaluated classes of per-class recall, percent 0..100."""

    F_mIoU: float
    """Per-class IoU weighted by each class's share of evaluated GT points, percent 0..100."""

    per_class: dict[str, dict] = field(default_factory=dict)
    """Class name -> {"recall": %, "iou": %, "gt_points": int}, for classes with GT points."""

    def to_dict(self) -> dict:
        """Plain JSON-ready dict with the keys of `semanticxr eval --json`."""
        return {
            "mAcc": float(self.mAcc),
            "F_mIoU": float(self.F_mIoU),
            "per_class": {
                name: {
                    "recall": float(scores["recall"]),
                    "iou": float(scores["iou"]),
                    "gt_points": int(scores["gt_points"]),
                }
                for name, scores in self.per_class.items()
            },
        }


def _points(points: np.ndarray, name: str) -> np.ndarray:
    """`points` as float64 [N, 3]; an empty input of any shape becomes [0, 3]."""
    points = np.asarray(points, dtype=np.float64)
    if points.size == 0:
        return points.reshape(0, 3)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{name} must be [N, 3], got shape {list(points.shape)}")
    return points


def _classes(point_class: np.ndarray, n_points: int, n_classes: int, name: str) -> np.ndarray:
    """`point_class` as int64 [n_points] with values in -1..n_classes-1."""
    point_class = np.asarray(point_class).reshape(-1).astype(np.int64)
    if point_class.shape[0] != n_points:
        raise ValueError(f"{name} has {point_class.shape[0]} entries for {n_points} points")
    if point_class.size and (point_class.min() < UNLABELLED or point_class.max() >= n_classes):
        raise ValueError(f"{name} values must lie in -1..{n_classes - 1}")
    return point_class


def _nearest_within(
    tree_points: np.ndarray, query_points: np.ndarray, radius_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """(index [Q] of each query point's nearest tree point, found [Q] bool: within radius_m).

    Inclusive at radius_m (cKDTree's upper bound alone is strict).
    """
    if len(tree_points) == 0 or len(query_points) == 0:
        return np.zeros(len(query_points), dtype=np.int64), np.zeros(len(query_points), bool)
    upper_bound = np.nextafter(radius_m, np.inf)
    distance, index = cKDTree(tree_points).query(
        query_points, k=1, distance_upper_bound=upper_bound, workers=-1
    )
    found = distance <= radius_m
    return np.where(found, index, 0).astype(np.int64), found


def semantic_scores(
    map_points: np.ndarray,
    map_point_class: np.ndarray,
    gt_points: np.ndarray,
    gt_point_class: np.ndarray,
    class_names: list[str],
    ignore_classes: tuple[str, ...] = ("floor", "wall", "ceiling"),
    radius_m: float = 0.05,
) -> SemanticScores:
    """mAcc and F-mIoU of a labelled map point cloud against labelled GT points.

    map_points: float [M, 3] metres; map_point_class: int [M], index into `class_names`,
    -1 = unlabelled. gt_points: float [N, 3] metres; gt_point_class: int [N] likewise.

    Each GT point is predicted as the class of its nearest map point (which may itself be
    unlabelled), or unlabelled if no map point lies within `radius_m`. GT points of
    `ignore_classes` (matched case-insensitively) and unlabelled GT points are not
    evaluated; predicting an ignored class for an evaluated point counts as wrong.
    recall_c = TP_c / GT_c; IoU_c = TP_c / (GT_c + Pred_c - TP_c), with Pred_c counted over
    evaluated GT points. mAcc averages recall over classes with GT points; F-mIoU weights
    IoU_c by GT_c / sum(GT).
    """
    n_classes = len(class_names)
    map_points = _points(map_points, "map_points")
    gt_points = _points(gt_points, "gt_points")
    map_point_class = _classes(map_point_class, len(map_points), n_classes, "map_point_class")
    gt_point_class = _classes(gt_point_class, len(gt_points), n_classes, "gt_point_class")

    ignored = {name.lower() for name in ignore_classes}
    is_ignored_class = np.array([name.lower() in ignored for name in class_names], dtype=bool)
    evaluated = gt_point_class != UNLABELLED
    evaluated[evaluated] = ~is_ignored_class[gt_point_class[evaluated]]
    eval_points = gt_points[evaluated]
    eval_truth = gt_point_class[evaluated]
    if len(eval_truth) == 0:
        return SemanticScores(mAcc=0.0, F_mIoU=0.0, per_class={})

    nearest, found = _nearest_within(map_points, eval_points, radius_m)
    predicted = np.full(len(eval_truth), UNLABELLED, dtype=np.int64)
    predicted[found] = map_point_class[nearest[found]]

    # bincount over class + 1 so that unlabelled (-1) lands in slot 0 and is dropped.
    gt_count = np.bincount(eval_truth, minlength=n_classes)
    pred_count = np.bincount(predicted + 1, minlength=n_classes + 1)[1:]
    true_positive = np.bincount(eval_truth[predicted == eval_truth], minlength=n_classes)

    scored_classes = np.flatnonzero(gt_count)
    recall = true_positive[scored_classes] / gt_count[scored_classes]
    union = gt_count[scored_classes] + pred_count[scored_classes] - true_positive[scored_classes]
    iou = true_positive[scored_classes] / union  # union >= GT_c > 0
    weights = gt_count[scored_classes] / gt_count.sum()
    per_class = {
        class_names[c]: {
            "recall": 100.0 * float(r),
            "iou": 100.0 * float(i),
            "gt_points": int(gt_count[c]),
        }
        for c, r, i in zip(scored_classes, recall, iou, strict=True)
    }
    return SemanticScores(
        mAcc=100.0 * float(recall.mean()),
        F_mIoU=100.0 * float(np.sum(iou * weights)),
        per_class=per_class,
    )


def assign_classes_by_text(
    object_embeddings: np.ndarray, class_text_embeddings: np.ndarray
) -> np.ndarray:
    """int64 [K]: for each object embedding [K, d], the class [C, d] of highest cosine.

    Rows are re-normalised, so non-unit inputs give cosine too; ties go to the lower class.
    """
    objects = np.asarray(object_embeddings, dtype=np.float32)
    classes = np.asarray(class_text_embeddings, dtype=np.float32)
    if classes.ndim != 2 or classes.shape[0] == 0:
        raise ValueError(f"class_text_embeddings must be [C, d], C >= 1, got {classes.shape}")
    if objects.size == 0:
        return np.zeros(0, dtype=np.int64)
    if objects.ndim != 2 or objects.shape[1] != classes.shape[1]:
        raise ValueError(
            f"object_embeddings {list(objects.shape)} do not match class dimension "
            f"{classes.shape[1]}"
        )
    # Zero rows stay zero (score 0 against every class) instead of dividing by zero.
    objects = objects / np.maximum(np.linalg.norm(objects, axis=1, keepdims=True), 1e-12)
    classes = classes / np.maximum(np.linalg.norm(classes, axis=1, keepdims=True), 1e-12)
    return np.argmax(objects @ classes.T, axis=1).astype(np.int64)


def majority_gt_class(
    object_points: list[np.ndarray],
    gt_points: np.ndarray,
    gt_point_class: np.ndarray,
    radius_m: float = 0.05,
) -> np.ndarray:
    """int64 [K]: per object, the most common GT class near its points (-1 if none).

    object_points: K arrays [n_k, 3] metres. Each object point votes for the class of its
    nearest GT point if that lies within `radius_m` and is labelled; ties go to the lower
    class index. Used to check which real class a query answer is.
    """
    gt_points = _points(gt_points, "gt_points")
    gt_point_class = np.asarray(gt_point_class).reshape(-1).astype(np.int64)
    if len(gt_point_class) != len(gt_points):
        raise ValueError(
            f"gt_point_class has {len(gt_point_class)} entries for {len(gt_points)} points"
        )
    majority = np.full(len(object_points), UNLABELLED, dtype=np.int64)
    if len(gt_points) == 0:
        return majority
    tree = cKDTree(gt_points)  # built once, queried per object
    upper_bound = np.nextafter(radius_m, np.inf)
    for k, points in enumerate(object_points):
        points = _points(points, f"object_points[{k}]")
        if len(points) == 0:
            continue
        distance, index = tree.query(points, k=1, distance_upper_bound=upper_bound)
        found = distance <= radius_m
        votes = gt_point_class[index[found]]
        votes = votes[votes >= 0]  # unlabelled GT points do not vote
        if len(votes):
            majority[k] = int(np.argmax(np.bincount(votes)))
    return majority
