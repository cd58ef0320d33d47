"""A second visit: the same walk through a scene again after scripted changes, with the ground
truth of every change.

`make_revisit` takes a scene (`before`), walks it, and scripts what happened while the user was
away: small and large things moved to another free spot (in the same room when there is one),
things removed (a thin thing lying on a table among them when the walk sees one), new things
set where the first walk saw empty space, and two occlusion traps: a cardboard box put over an
object, or set in front of it, so that the object stays but the second walk cannot see it.
`after` is the changed copy of the scene; the second walk repeats the first walk's camera path.

Each change is chosen so that an evaluation can score it: both walks are rendered at a small
analysis resolution and a change is kept only when the first walk sees the object well, the
second walk sees its old place empty and the object at its new place, and (for added things)
the first walk saw the new place empty. `measure_visibility` recounts this for any camera.

The planning of the changes is in `world.change_planner`, what the walks see of them in
`world.change_visibility`.

Device clock of the revisit stream: frame i of the first walk is at i / fps; the second walk
starts `gap_s` after the last frame of the first one, and every change happened at that time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from world.change_planner import (
    Planner,
    acceptable,
    apply_edits,
    edit_roles,
    occluders_of,
    xyz,
)
from world.change_visibility import (
    SeenFrames,
    count_seen,
    render_walk,
)
from world.render import Camera, default_camera
from world.rooms import make_scene
from world.scene import Scene
from world.trajectory import walk_trajectory

CHANGE_KINDS: tuple[str, ...] = ("moved", "removed", "added")
REVISIT_FPS = 5.0
"""Frames per second of the revisit stream: `t` advances 0.2 s per frame."""
DEFAULT_WALK_FRAMES = 500
"""Frames per walk: the apartment walk reaches every room well from about 500 frames on."""
DEFAULT_GAP_S = 600.0
"""Device time between the last frame of the first walk and the first of the second."""

ANALYSIS_CAMERA = default_camera(160, 120)
"""The camera `make_revisit` checks visibility with (pixel thresholds scale with its size)."""


@dataclass(frozen=True)
class GroundTruthChange:
    """One change of the world between the two walks."""

    instance_id: int
    """The object's instance id (a moved object keeps its id; an added one has a new id)."""
    kind: str
    """One of CHANGE_KINDS: "moved", "removed" or "added"."""
    category: str
    """Its category (a CATEGORIES key)."""
    from_xyz: tuple[float, float, float] | None
    """Centre of its bounding box before (moved, removed), metres; None when added."""
    to_xyz: tuple[float, float, float] | None
    """Centre of its bounding box after (moved, added), metres; None when removed."""
    t_world: float
    """Device time at which it happened: the t of the first frame of the second walk."""


@dataclass
class RevisitScenario:
    """Two walks along one camera path, before and after scripted changes."""

    before: Scene
    """The scene of the first walk."""
    after: Scene
    """A changed deep copy of it: the scene of the second walk."""
    changes: list[GroundTruthChange]
    """Every change between the walks, sorted by instance id."""
    occluded_ids: list[int]
    """Objects that stay but get something new set over or in front of them."""
    occluders: dict[int, int]
    """Occluded instance id -> instance id of the added thing hiding it."""
    poses: list[np.ndarray]
    """The camera path of both walks: float64 [4, 4] camera-to-world, OpenCV axes."""
    walk1_frames: int
    walk2_frames: int
    gap_s: float
    """Device time between the last frame of walk 1 and the first frame of walk 2."""
    fps: float
    """Frames per second within a walk."""
    seen: dict[int, SeenFrames] = field(default_factory=dict)
    """Per changed or occluded instance id, as `measure_visibility` counts at ANALYSIS_CAMERA."""

    def __len__(self) -> int:
        return self.walk1_frames + self.walk2_frames

    def walk_of(self, index: int) -> int:
        """1 for frames of the first walk, 2 for frames of the second."""
        if not 0 <= index < len(self):
            raise IndexError(f"frame {index} out of range [0, {len(self)})")
        return 1 if index < self.walk1_frames else 2

    def scene_of(self, index: int) -> Scene:
        """The scene frame `index` shows."""
        return self.before if self.walk_of(index) == 1 else self.after

    def pose_of(self, index: int) -> np.ndarray:
        """Camera-to-world pose of frame `index`: the second walk repeats the first."""
        return self.poses[index if self.walk_of(index) == 1 else index - self.walk1_frames]

    @property
    def walk2_start_t(self) -> float:
        """Device time of the first frame of the second walk, seconds."""
        return (self.walk1_frames - 1) / self.fps + self.gap_s

    def t_of(self, index: int) -> float:
        """Device time of frame `index`, seconds."""
        if self.walk_of(index) == 1:
            return index / self.fps
        return self.walk2_start_t + (index - self.walk1_frames) / self.fps


def make_revisit(
    scene: str | Scene = "apartment",
    seed: int = 0,
    walk_frames: int = DEFAULT_WALK_FRAMES,
    gap_s: float = DEFAULT_GAP_S,
    fps: float = REVISIT_FPS,
) -> RevisitScenario:
    """Script a second visit to `scene` (a SCENE_NAMES name built with `seed`, or a Scene).

    Deterministic given the arguments. The walk is `walk_trajectory(before, walk_frames, seed)`
    for both visits. About a dozen changes on the apartment; fewer in one room or on a short
    walk, since only changes both walks see well are kept.
    """
    if walk_frames < 1:
        raise ValueError(f"walk_frames must be >= 1, got {walk_frames}")
    if not fps > 0:
        raise ValueError(f"fps must be > 0, got {fps}")
    if not (math.isfinite(gap_s) and gap_s >= 0):
        raise ValueError(f"gap_s must be finite and >= 0, got {gap_s}")
    before = make_scene(scene, seed) if isinstance(scene, str) else scene
    poses = walk_trajectory(before, int(walk_frames), seed)
    walk1 = render_walk(before, poses, ANALYSIS_CAMERA)
    rng = np.random.default_rng([int(seed), 0x2E71517])
    planner = Planner(before, poses, walk1, ANALYSIS_CAMERA, rng)
    edits = planner.plan()

    # Keep the changes both walks really see; dropping one can uncover another, so recount
    # until all pass (each round drops at least one change, so this ends).
    while True:
        after = apply_edits(before, edits)
        seen = count_seen(
            edit_roles(edits), occluders_of(edits), poses, ANALYSIS_CAMERA, walk1, after=after
        )
        kept = [e for e in edits if acceptable(e, seen)]
        if len(kept) == len(edits):
            break
        edits = kept

    occluders = occluders_of(edits)
    scenario = RevisitScenario(
        before=before,
        after=after,
        changes=[],
        occluded_ids=sorted(occluders),
        occluders=occluders,
        poses=poses,
        walk1_frames=int(walk_frames),
        walk2_frames=int(walk_frames),
        gap_s=float(gap_s),
        fps=float(fps),
        seen=seen,
    )
    scenario.changes = sorted(
        (
            GroundTruthChange(
                instance_id=e.instance_id,
                kind=e.kind,
                category=e.category,
                from_xyz=xyz(e.old.center) if e.old is not None else None,
                to_xyz=xyz(e.new.center) if e.new is not None else None,
                t_world=scenario.walk2_start_t,
            )
            for e in edits
        ),
        key=lambda c: c.instance_id,
    )
    return scenario


def measure_visibility(
    scenario: RevisitScenario, camera: Camera = ANALYSIS_CAMERA
) -> dict[int, SeenFrames]:
    """Render both walks with `camera` and count, per changed or occluded instance id, the
    frames that see it and its places (see SeenFrames); SEEN_PX scales with the image size."""
    roles = {c.instance_id: c.kind for c in scenario.changes}
    roles.update(dict.fromkeys(scenario.occluded_ids, "occluded"))
    return count_seen(
        roles, scenario.occluders, scenario.poses, camera, scenario.before, after=scenario.after
    )
