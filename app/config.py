"""Knobs: one typed dataclass, a docstring per field, the single source of their defaults.

The names and defaults follow the paper's Table 3 (docs/architecture.md "Knobs"). The CLI help and
the server's validation are generated from this module, so a knob is documented once.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Literal

Mode = Literal["semanticxr", "baseline"]
MODES: tuple[str, ...] = ("semanticxr", "baseline")


class KnobError(ValueError):
    """An unknown knob or a value out of range; the message names the knob."""


@dataclass
class Knobs:
    """Per-session settings of the mapping pipeline and the device."""

    net_latency_switch_threshold_ms: float = 100.0
    """Device switches from server query (SQ) to local query (LQ) above this smoothed RTT."""

    skip_mapping_set: list[str] = field(default_factory=list)
    """Labels the server never maps (compared case-insensitively)."""

    max_object_points_server: int = 2000
    """Per-object point cap on the server (semanticxr mode; the baseline is uncapped)."""

    max_object_spacing_m: float | None = 0.035
    """The server's cap never spreads an object's points wider apart than this: a large object
    keeps more than `max_object_points_server` points rather than become sparser than the
    small things beside it, which would then win its surface (a cap by surface density;
    semanticxr mode). None: the count cap alone."""

    max_object_points_client: int = 200
    """Per-object point cap in downstream updates and on the device."""

    priority_class: list[str] = field(default_factory=list)
    """Classes the device keeps first when its local map is over budget."""

    distance_threshold_m: float | None = None
    """Device keeps objects within this distance of the user before farther ones."""

    local_map_budget_mb: float = 500.0
    """Device local-map memory budget; over it, the lowest-priority objects are evicted."""

    local_map_update_frequency: int = 2
    """Keyframes between downstream updates."""

    min_mapping_bbox_area: int = 2000
    """Detections whose mask bounding box is smaller than this (px at RGB size) are deferred
    unless the frame carries a full-resolution depth patch of their box, which our device
    sends for exactly these (semanticxr mode; the baseline integrates every detection)."""

    depth_downsampling_ratio: int = 5
    """Per-dimension depth downsampling on the device before upload."""

    keyframe_interval: int = 5
    """Every n-th received frame is mapped (a keyframe)."""

    min_observations: int = 3
    """Frames an object must be seen in before it is confirmed (queryable, published)."""

    association_threshold: float = 1.2
    """Match a detection to an object when spatial + semantic similarity reaches this..."""

    association_min_semantic: float = 0.7
    """...and only when their embeddings agree at least this much, so that things lying on
    or in a larger object (books in a bookshelf, a cushion on a sofa) stay separate."""

    voxel_size_m: float = 0.025
    """Voxel for spatial similarity and point de-duplication."""

    max_depth_m: float = 8.0
    """Depth beyond this is treated as invalid."""

    min_detection_points: int = 30
    """Detections that lift to fewer valid points are skipped."""

    cleanup_interval: int = 10
    """Keyframes between map clean-ups (outlier removal, merge of duplicates, pruning)."""

    transient_max_age: int = 10
    """Unconfirmed objects not seen for this many keyframes are pruned as transients."""

    negative_evidence: bool = True
    """The living map: keyframes that show an object's place without it count as evidence of
    its absence; objects are then removed, or merged with their new place (moved)."""

    absence_min_depth_m: float = 0.3
    """Negative evidence: an object's place counts as in view from this distance..."""

    absence_max_depth_m: float = 4.0
    """...up to this one (farther, depth is too coarse to tell)."""

    absence_depth_tolerance_m: float = 0.03
    """A projected point matches the sensed depth within this plus `absence_depth_tolerance_rel`
    of its depth; the sensed depth beyond that sees through it, nearer depth occludes it."""

    absence_depth_tolerance_rel: float = 0.01
    """The part of the depth tolerance that grows with distance (1 % of depth)."""

    absence_min_visible: float = 0.3
    """A keyframe tells about an object only if at least this fraction of its projected
    points are visible (matching or seen through, not occluded): occlusion is no evidence."""

    absence_min_seen_through: float = 0.7
    """Depth evidence of absence: at least this fraction of the visible points seen through."""

    min_absence_area_px: int = 400
    """Thin things (a laptop on a table barely changes depth) count as absent when in view,
    unoccluded, projected at least this big (px at RGB size) and not detected; that weaker
    evidence needs two viewpoints."""

    removal_min_evidence: int = 3
    """Keyframes of evidence before an object is removed (or found moved)..."""

    removal_min_span_s: float = 1.5
    """...spanning at least this much device time, or seen from two viewpoints..."""

    removal_min_baseline_m: float = 0.5
    """...at least this far apart..."""

    removal_min_angle_deg: float = 20.0
    """...or this many degrees apart in viewing direction."""

    move_min_similarity: float = 0.8
    """A new object merges with a suspect (or removed-by-evidence) one as a move when their
    labels agree or their embeddings are at least this similar."""


KNOB_RANGES: dict[str, tuple[float, float]] = {  # inclusive bounds of numeric knobs
    "net_latency_switch_threshold_ms": (0, 60_000),
    "max_object_points_server": (10, 1_000_000),
    "max_object_spacing_m": (0.001, 10),
    "max_object_points_client": (1, 1_000_000),
    "distance_threshold_m": (0, 10_000),
    "local_map_budget_mb": (0.001, 1_000_000),
    "local_map_update_frequency": (1, 10_000),
    "min_mapping_bbox_area": (0, 100_000_000),
    "depth_downsampling_ratio": (1, 32),
    "keyframe_interval": (1, 10_000),
    "min_observations": (1, 10_000),
    "association_threshold": (0, 2),
    "association_min_semantic": (-1, 1),
    "voxel_size_m": (0.001, 1),
    "max_depth_m": (0.1, 1000),
    "min_detection_points": (1, 1_000_000),
    "cleanup_interval": (1, 10_000),
    "transient_max_age": (1, 1_000_000),
    "absence_min_depth_m": (0, 100),
    "absence_max_depth_m": (0.1, 100),
    "absence_depth_tolerance_m": (0.001, 1),
    "absence_depth_tolerance_rel": (0, 1),
    "absence_min_visible": (0, 1),
    "absence_min_seen_through": (0, 1),
    "min_absence_area_px": (1, 100_000_000),
    "removal_min_evidence": (1, 1000),
    "removal_min_span_s": (0, 1_000_000),
    "removal_min_baseline_m": (0, 1000),
    "removal_min_angle_deg": (0, 180),
    "move_min_similarity": (-1, 1),
}

KNOB_NAMES: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(Knobs))
NULLABLE_KNOBS: frozenset[str] = frozenset(
    f.name for f in dataclasses.fields(Knobs) if "None" in str(f.type)
)
"""Knobs that may be null (their type says `| None`)."""


def knob_docs() -> dict[str, str]:
    """Knob name -> its docstring, read from the source of this module."""
    import ast
    import inspect

    tree = ast.parse(inspect.getsource(Knobs))
    docs: dict[str, str] = {}
    body = tree.body[0].body  # type: ignore[attr-defined]
    for node, nxt in zip(body, body[1:], strict=False):
        if isinstance(node, ast.AnnAssign) and isinstance(nxt, ast.Expr):
            docs[node.target.id] = str(nxt.value.value)  # type: ignore[union-attr]
    return docs


def _coerce(name: str, value: Any, default: Any) -> Any:
    if isinstance(default, list) or name in ("skip_mapping_set", "priority_class"):
        if isinstance(value, str):
            value = [v for v in value.split(",") if v.strip()]
        if not isinstance(value, list | tuple) or not all(isinstance(v, str) for v in value):
            raise KnobError(f"knob {name!r} must be a list of strings, got {value!r}")
        if len(value) > 1000 or any(len(v) > 200 for v in value):
            raise KnobError(f"knob {name!r} is too long")
        return [v.strip() for v in value]
    if isinstance(default, bool):
        return _coerce_bool(name, value)
    if value is None:
        if name in NULLABLE_KNOBS:
            return None
        raise KnobError(f"knob {name!r} cannot be null")
    if isinstance(value, bool):
        raise KnobError(f"knob {name!r} must be a number, got a boolean")
    is_int = isinstance(default, int) and not isinstance(default, bool)
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise KnobError(f"knob {name!r} must be a number, got {value!r}") from None
    if number != number or number in (float("inf"), float("-inf")):
        raise KnobError(f"knob {name!r} must be finite, got {value!r}")
    if is_int:
        if number != int(number):
            raise KnobError(f"knob {name!r} must be an integer, got {value!r}")
        number = int(number)
    lo, hi = KNOB_RANGES.get(name, (float("-inf"), float("inf")))
    if not lo <= number <= hi:
        raise KnobError(f"knob {name!r} must be within [{lo:g}, {hi:g}], got {value!r}")
    return number


_BOOL_WORDS = {"true": True, "1": True, "on": True, "false": False, "0": False, "off": False}


def _coerce_bool(name: str, value: Any) -> bool:
    """A boolean knob from a boolean, or (from a flag) true/false, on/off, 1/0."""
    if isinstance(value, bool):
        return value
    if isinstance(value, str) and value.strip().lower() in _BOOL_WORDS:
        return _BOOL_WORDS[value.strip().lower()]
    raise KnobError(f"knob {name!r} must be true or false, got {value!r}")


def updated_knobs(knobs: Knobs, changes: dict[str, Any]) -> Knobs:
    """A copy of `knobs` with `changes` applied and validated; raises KnobError naming the knob."""
    if not isinstance(changes, dict):
        raise KnobError("knobs must be an object of {name: value}")
    new = dataclasses.replace(knobs)
    for name, value in changes.items():
        if name not in KNOB_NAMES:
            raise KnobError(f"unknown knob {name!r}; known knobs: {', '.join(KNOB_NAMES)}")
        setattr(new, name, _coerce(name, value, getattr(Knobs(), name)))
    return new


def knobs_to_dict(knobs: Knobs) -> dict[str, Any]:
    return dataclasses.asdict(knobs)
