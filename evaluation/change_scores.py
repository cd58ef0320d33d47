"""How well a living map followed a changing world (the revisit scenario's metrics); pure.

A concluded change counts when its object and its kind are right: the map's object is
matched to a ground-truth instance by the caller (nearest ground-truth points, majority), and
each ground-truth change is matched at most once. `added` is scored apart from `moved` and
`removed` (docs/evaluation.md "Measured honestly"); Wilson 95 % lower bounds go beside the rates.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

WILSON_Z = 1.96
"""95 % two-sided."""


@dataclass(frozen=True)
class ConcludedChange:
    """A change the map concluded. instance: the ground-truth instance its object matched
    (None: none); t: device time the map concluded it."""

    instance: int | None
    kind: str
    t: float


@dataclass(frozen=True)
class TrueChange:
    """A change of the world. t_evidence: device time of the first frame (keyframe or not)
    that showed the evidence the map needs (its old place without it, its new place with it);
    None when no frame did. t_bound: the earliest time the map's settled rules could conclude
    it from what the walk's regular keyframes showed (a removal needs several keyframes
    showing the empty place, and the walk may look away between them); None: t_evidence."""

    instance: int
    kind: str
    t_evidence: float | None
    t_bound: float | None = None


def wilson_lower(successes: int, trials: int, z: float = WILSON_Z) -> float:
    """Wilson score lower bound of a proportion (0 with no trials)."""
    if trials <= 0:
        return 0.0
    p = successes / trials
    denominator = 1 + z * z / trials
    centre = p + z * z / (2 * trials)
    spread = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials))
    return max(0.0, (centre - spread) / denominator)


def _percentiles(values: Sequence[float]) -> dict[str, float | None]:
    if not values:
        return {"p50": None, "p95": None}
    return {"p50": float(np.percentile(values, 50)), "p95": float(np.percentile(values, 95))}


def _rates(
    concluded: Sequence[ConcludedChange], truth: Sequence[TrueChange]
) -> tuple[dict, list[float]]:
    """Precision, recall, F1 (with Wilson bounds) and the times to update of the matches."""
    unmatched = {(c.instance, c.kind): c for c in truth}
    hits, delays, beyond, walk_bound, matched, wrong = 0, [], [], [], [], []
    for change in concluded:
        true = unmatched.pop((change.instance, change.kind), None)
        if true is None:
            wrong.append({"instance": change.instance, "kind": change.kind, "t": change.t})
            continue
        hits += 1
        delay = None if true.t_evidence is None else max(0.0, change.t - true.t_evidence)
        bound = true.t_evidence if true.t_bound is None else true.t_bound
        if delay is not None and bound is not None:
            delays.append(delay)
            beyond.append(max(0.0, change.t - bound))
            walk_bound.append(bound - true.t_evidence)
        matched.append(
            {
                "instance": change.instance,
                "kind": change.kind,
                "delay_s": delay,
                "t": change.t,
                "t_evidence": true.t_evidence,
                "t_bound": true.t_bound,
            }
        )
    precision = hits / len(concluded) if concluded else 1.0
    recall = hits / len(truth) if truth else 1.0
    f1 = 2 * precision * recall / (precision + recall) if precision + recall else 0.0
    return {
        "precision": precision,
        "recall": recall,
        "f1": f1,
        "precision_wilson_low": wilson_lower(hits, len(concluded)) if concluded else None,
        "recall_wilson_low": wilson_lower(hits, len(truth)) if truth else None,
        "correct": hits,
        "concluded": len(concluded),
        "true": len(truth),
        "matched": matched,
        "wrong": wrong,
        "missed": [
            {"instance": c.instance, "kind": c.kind, "t_evidence": c.t_evidence}
            for c in unmatched.values()
        ],
        "walk_bound_s": _percentiles(walk_bound),
        "beyond_walk_bound_s": _percentiles(beyond),
    }, delays


def score_changes(concluded: Sequence[ConcludedChange], truth: Sequence[TrueChange]) -> dict:
    """The `changes` figures of `semanticxr eval --scenario revisit` for moved and removed
    (pooled), with `added` apart under "added". Rates are fractions 0..1; times seconds.

    `time_to_update_s` runs from the first frame that showed the evidence; `walk_bound_s`
    is how much of that the walk itself imposes (from the first showing keyframe to the
    earliest the rules could conclude); `beyond_walk_bound_s` is the map's own delay."""
    main = [c for c in concluded if c.kind != "added"]
    main_truth = [c for c in truth if c.kind != "added"]
    scores, delays = _rates(main, main_truth)
    added, added_delays = _rates(
        [c for c in concluded if c.kind == "added"], [c for c in truth if c.kind == "added"]
    )
    added["time_to_update_s"] = _percentiles(added_delays)
    scores["time_to_update_s"] = _percentiles(delays)
    scores["added"] = added
    return scores
