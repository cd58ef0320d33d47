"""The embedded synthetic frame source: a procedural scene, a walk through it, rendered frames
and emulated detections."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from client_sim.sources.base import FrameSource, SourceFrame
from world.noise import DetectionModel, NoisyDetections
from world.render import Camera, Renderer, View, default_camera
from world.rooms import make_scene
from world.scene import Scene
from world.trajectory import walk_trajectory


@dataclass
class SyntheticFrame(SourceFrame):
    """One frame of the walk: what the device captures (the SourceFrame fields: RGB, noisy
    depth, pose, intrinsics, the emulated detector's instance image and labels) plus the
    ground truth behind it.

    camera:     intrinsics of view and detections
    view:       ground-truth render (rgb, z-depth, instance ids)
    detections: what the emulated on-device detector reports (with noisy depth)
    """

    camera: Camera | None = None
    view: View | None = field(default=None, repr=False)
    detections: NoisyDetections | None = field(default=None, repr=False)


def render_frame(
    index: int,
    t: float,
    pose: np.ndarray,
    camera: Camera,
    renderer: Renderer,
    detector: DetectionModel,
    seed: int,
    texture_noise: float,
) -> SyntheticFrame:
    """Frame `index` of a walk, rendered at `pose` [4, 4] and passed through the detector;
    its texture noise is seeded by (seed, index), so any frame renders alone the same."""
    rng = np.random.default_rng([seed, index, 3])
    view = renderer.render(pose, camera, texture_noise, rng)
    detections = detector.detect(view, index)
    return SyntheticFrame(
        index=index,
        t=t,
        rgb=view.rgb,
        depth_m=detections.depth_m,
        pose=pose,
        intrinsics=camera.intrinsics,
        instance_ids=detections.instance_ids,
        instances=detections.instances,
        camera=camera,
        view=view,
        detections=detections,
    )


class SyntheticSource(FrameSource):
    """Frames of a walk through a procedural scene, rendered lazily.

    Everything (scene, walk, texture and sensor noise, detections) is deterministic given
    (scene, n_frames, seed, noise), and frame i is the same whichever frames are rendered.
    """

    def __init__(
        self,
        scene: str | Scene = "apartment",
        n_frames: int = 300,
        camera: Camera | None = None,
        noise: str = "standard",
        seed: int = 0,
        fps: float = 30.0,
        texture_noise: float = 0.03,
    ):
        if n_frames < 1:
            raise ValueError(f"n_frames must be >= 1, got {n_frames}")
        if fps <= 0:
            raise ValueError(f"fps must be > 0, got {fps}")
        self.scene = make_scene(scene, seed) if isinstance(scene, str) else scene
        self.n_frames = int(n_frames)
        self.camera = camera or default_camera()
        self.noise = noise
        self.seed = int(seed)
        self.fps = float(fps)
        self.texture_noise = float(texture_noise)
        self.detector = DetectionModel(self.scene, noise, seed)  # validates `noise` early
        self.poses = walk_trajectory(self.scene, self.n_frames, seed)
        self._renderer: Renderer | None = None
        self.name = f"synthetic:{self.scene.name}"

    @property
    def renderer(self) -> Renderer:
        if self._renderer is None:
            self._renderer = Renderer(self.scene)
        return self._renderer

    def __len__(self) -> int:
        return self.n_frames

    def frame(self, index: int) -> SyntheticFrame:
        """Render frame `index` (0 <= index < n_frames)."""
        if not 0 <= index < self.n_frames:
            raise IndexError(f"frame {index} out of range [0, {self.n_frames})")
        return render_frame(
            index,
            index / self.fps,
            self.poses[index],
            self.camera,
            self.renderer,
            self.detector,
            self.seed,
            self.texture_noise,
        )
