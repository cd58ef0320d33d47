"""What one keyframe did to the map: the engine's report of a mapped keyframe."""

from __future__ import annotations

from dataclasses import dataclass, field

from app.mapping.object import Change, MapObject


@dataclass
class IntegrationStats:
    """What one keyframe did to the map."""

    seq: int
    keyframe: int
    detections: int = 0
    skipped: int = 0
    deferred: int = 0
    too_small: int = 0
    over_cap: int = 0
    """New objects not created because the map holds max_objects (their matches still map)."""
    created: int = 0
    matched: int = 0
    removed: int = 0
    objects: int = 0
    confirmed: int = 0
    cleanup: bool = False
    published_ids: list[int] = field(default_factory=list)
    """Confirmed objects this keyframe created or changed (at log seq `seq`)."""
    removed_ids: list[int] = field(default_factory=list)
    """Published objects this keyframe removed (merged, moved into another, or retired)."""
    retired: list[MapObject] = field(default_factory=list)
    """Objects this keyframe found gone from the world: out of the present map (their ids are
    in removed_ids), kept as history with state "removed"."""
    changes: list[Change] = field(default_factory=list)
    """What this keyframe concluded about the world (added, moved, removed)."""
    retracted_added: list[int] = field(default_factory=list)
    """Published objects merged into another: an `added` change of theirs no longer stands."""
    unremoved_ids: list[int] = field(default_factory=list)
    """Objects this keyframe removed and then found at a new place (moved, not removed)."""
    dropped_ids: list[int] = field(default_factory=list)
    """Duplicates of things that moved or left, taken out with them (no change of their own)."""
    retracted_removed: list[int] = field(default_factory=list)
    """Removed objects found at a new place: their `removed` change gives way to `moved`."""
    timings_ms: dict[str, float] = field(default_factory=dict)
