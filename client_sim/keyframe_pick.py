"""The device's keyframe pick with the sightings extension: the shared selector's keyframes
(`app.keyframes`), and between them a frame in which a place the server doubts comes into
view once a keyframe could complete its evidence (the ack's `doubted`, docs/protocol.md).

A removal needs several keyframes showing the empty place (`app.mapping.living`); at one
keyframe a second the walk often looks away before they are in. Making the frames that
show a doubted place keyframes brings that evidence in while the place is in view; the
server judges it as any keyframe (occlusion is never evidence), so the pick only decides
which frames the server reads, never what it concludes. Pure: no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from app.keyframes import is_keyframe

DOUBT_MIN_GAP_FRAMES = 2
"""A doubted place in view makes at most every second frame a keyframe (0.4 s apart at
5 fps): the removal rule's span is reached as soon, at half the mapping of every frame."""
DOUBT_IMAGE_MARGIN = 0.05
"""A place is in view when its centre projects this fraction of the image size inside the
image edges (half a place cut off by the edge tells the server little)."""
DOUBT_DEPTH_TOLERANCE_M = 0.05
"""Sensed depth nearer than the place's front (centre depth - radius) by more than this is
something in front of it: occluded, no pick (occlusion is no evidence)."""


def doubted_place_in_view(
    places: np.ndarray,
    t: float,
    pose: np.ndarray,
    intrinsics: tuple[float, float, float, float],
    rgb_size: tuple[int, int],
    depth_m: np.ndarray,
    min_depth_m: float,
    max_depth_m: float,
) -> bool:
    """Whether the frame (device time `t`) shows one of `places` (float [K, 5]: x, y, z,
    radius metres, t_ready) whose t_ready has come: its centre inside the image
    (DOUBT_IMAGE_MARGIN in), at `min_depth_m`..`max_depth_m` from the camera, and the
    sensed depth there not in front of the place.

    pose: float [4, 4] camera-to-world (OpenCV frame); intrinsics (fx, fy, cx, cy) and
    rgb_size (W, H) of the RGB image; depth_m: float [h, w] metres (0: none), the RGB size
    divided by an integer ratio."""
    places = np.asarray(places, np.float64).reshape(-1, 5)
    places = places[places[:, 4] <= t]
    if not len(places):
        return False
    pose = np.asarray(pose, np.float64)
    camera = (places[:, :3] - pose[:3, 3]) @ pose[:3, :3]  # world -> camera: R^T (p - t)
    z = camera[:, 2]
    fx, fy, cx, cy = intrinsics
    width, height = rgb_size
    with np.errstate(divide="ignore", invalid="ignore"):
        u = fx * camera[:, 0] / z + cx
        v = fy * camera[:, 1] / z + cy
    margin_u, margin_v = DOUBT_IMAGE_MARGIN * width, DOUBT_IMAGE_MARGIN * height
    ok = (
        (z >= min_depth_m)
        & (z <= max_depth_m)
        & (u >= margin_u)
        & (u < width - margin_u)
        & (v >= margin_v)
        & (v < height - margin_v)
    )
    if not ok.any():
        return False
    ratio = max(1, round(width / depth_m.shape[1]))
    rows = np.clip(v[ok] // ratio, 0, depth_m.shape[0] - 1).astype(np.int64)
    cols = np.clip(u[ok] // ratio, 0, depth_m.shape[1] - 1).astype(np.int64)
    sensed = depth_m[rows, cols]
    front = z[ok] - places[ok, 3] - DOUBT_DEPTH_TOLERANCE_M
    return bool(np.any((sensed > 0) & (sensed >= front)))


@dataclass
class KeyframePick:
    """Which frames a device with the sightings extension sends whole (keyframes): the
    shared selector's, and frames showing a doubted place at least DOUBT_MIN_GAP_FRAMES
    after the last keyframe. `doubted` is the newest keyframe ack's `doubted` (empty from a
    server that does not send it: the shared selector's keyframes only)."""

    interval: int
    """The `keyframe_interval` knob."""
    min_depth_m: float
    """The `absence_min_depth_m` knob: nearer, the server reads no absence."""
    max_depth_m: float
    """The `absence_max_depth_m` knob."""
    doubted: np.ndarray = field(default_factory=lambda: np.zeros((0, 5)))
    last_keyframe: int | None = None
    """Seq of the last frame picked."""
    doubt_picks: int = 0
    """Frames picked for a doubted place (not the shared selector's)."""

    def pick(
        self,
        seq: int,
        t: float,
        pose: np.ndarray,
        intrinsics: tuple[float, float, float, float],
        rgb_size: tuple[int, int],
        depth_m: np.ndarray,
    ) -> bool:
        """Whether frame `seq` goes whole (module doc); remembers the pick."""
        if is_keyframe(seq, self.interval):
            picked = True
        elif self.last_keyframe is not None and seq - self.last_keyframe < DOUBT_MIN_GAP_FRAMES:
            picked = False
        else:
            picked = doubted_place_in_view(
                self.doubted,
                t,
                pose,
                intrinsics,
                rgb_size,
                depth_m,
                self.min_depth_m,
                self.max_depth_m,
            )
            self.doubt_picks += picked
        if picked:
            self.last_keyframe = seq
        return picked
