"""The revisit frame source: a walk through a synthetic scene, then the same walk again after
scripted changes (`world.changes`), on one device clock."""

from __future__ import annotations

from client_sim.sources.base import FrameSource
from client_sim.sources.synthetic import SyntheticFrame, render_frame
from world.changes import (
    DEFAULT_GAP_S,
    DEFAULT_WALK_FRAMES,
    REVISIT_FPS,
    RevisitScenario,
    make_revisit,
)
from world.noise import DetectionModel
from world.render import Camera, Renderer, default_camera
from world.scene import Scene


class RevisitSource(FrameSource):
    """Walk 1 over `scenario.before`, then walk 2 over `scenario.after` along the same camera
    path; frame t advances 1 / fps within a walk and walk 2 starts `gap_s` after the last frame
    of walk 1 (`RevisitScenario.t_of`). Frames are rendered lazily and are deterministic given
    the scenario, `noise` and `seed`; walk-2 frames carry the instance ids of `after`.
    """

    def __init__(
        self,
        scenario: RevisitScenario | str | Scene = "apartment",
        seed: int = 0,
        walk_frames: int = DEFAULT_WALK_FRAMES,
        gap_s: float = DEFAULT_GAP_S,
        fps: float = REVISIT_FPS,
        camera: Camera | None = None,
        noise: str = "standard",
        texture_noise: float = 0.03,
    ):
        """`scenario` is a scripted revisit, or the scene (a name or a Scene) to script one for
        with make_revisit(scene, seed, walk_frames, gap_s, fps)."""
        if not isinstance(scenario, RevisitScenario):
            scenario = make_revisit(scenario, seed, walk_frames, gap_s, fps)
        self.scenario = scenario
        self.seed = int(seed)
        self.camera = camera or default_camera()
        self.texture_noise = float(texture_noise)
        # Validate `noise` early (DetectionModel raises on an unknown profile).
        self.detectors = (
            DetectionModel(scenario.before, noise, seed),
            DetectionModel(scenario.after, noise, seed),
        )
        self._renderers: list[Renderer | None] = [None, None]
        self.name = f"revisit:{scenario.before.name}"

    def __len__(self) -> int:
        return len(self.scenario)

    def walk_of(self, index: int) -> int:
        """1 for frames of the first walk, 2 for frames of the second."""
        return self.scenario.walk_of(index)

    def renderer(self, walk: int) -> Renderer:
        """The renderer of walk 1 (`before`) or walk 2 (`after`)."""
        if self._renderers[walk - 1] is None:
            scene = self.scenario.before if walk == 1 else self.scenario.after
            self._renderers[walk - 1] = Renderer(scene)
        return self._renderers[walk - 1]

    def frame(self, index: int) -> SyntheticFrame:
        """Render frame `index` (0 <= index < len(self))."""
        walk = self.walk_of(index)  # raises IndexError out of range
        return render_frame(
            index,
            self.scenario.t_of(index),
            self.scenario.pose_of(index),
            self.camera,
            self.renderer(walk),
            self.detectors[walk - 1],
            self.seed,
            self.texture_noise,
        )
