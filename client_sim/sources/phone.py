"""What the iPhone and iPad capture sources (`record3d:`, `stray:`) share.

Both apps record ARKit frames: a colour image (1920x1440 on LiDAR iPhones), LiDAR depth in
metres at a lower resolution with the same field of view (ARKit's `sceneDepth`, 256x192),
a confidence per depth pixel (ARConfidenceLevel: 0 low, 1 medium, 2 high), the camera's
intrinsics and its camera-to-world pose in ARKit's world (y up, gravity-aligned, metres).

Conventions handled here, once:

- **Camera axes.** ARKit's camera looks down -z with y up and x right (OpenGL's camera);
  the protocol's camera is OpenCV's (x right, y down, z forward). `arkit_pose_to_opencv`
  turns one into the other.
- **Confidence.** Depth pixels under `min_confidence` become 0 (no depth). The default,
  `MIN_CONFIDENCE` = 1, drops ARKit's "low" only, as Stray Scanner's own visualiser does
  by default (kekeblom/StrayVisualizer, `--confidence 1`); Record3D readers often keep only
  "high" (nerfstudio-project/viser's `_record3d.py`: `conf == 2`), which loses most depth
  beyond ~3 m. `min_confidence=2` does that.
- **Depth at RGB size.** The frame encoder needs depth registered at RGB size; the sensor
  depth is resized to the output RGB size with nearest neighbour (`depth_at_rgb_size`),
  whose pixel grids share the image borders (1920/256 = 7.5: not an integer). A depth pixel
  therefore lands within half a sensor pixel of where it was measured (~5 mm at 2 m at
  256x192); with the protocol's depth ÷5, an RGB size of 5x the sensor's (1280x960) sends
  every sensor pixel once, exactly where it was measured.
- **Size.** Frames are scaled down so their longer side is at most `max_side_px` (default
  `DEVICE_MAX_SIDE_PX` = 640: 1920x1440 becomes 640x480, the emulated device's camera and the
  size the encoder's defaults were tuned at); the intrinsics are scaled with them. None keeps
  the capture's size.
"""

from __future__ import annotations

import numpy as np
from PIL import Image

from client_sim.sources.base import (
    FrameSource,
    Intrinsics,
    SourceError,
    SourceFrame,
    depth_at_rgb_size,
)

DEVICE_MAX_SIDE_PX = 640
"""Default longer side of a phone capture's frames: the emulated device's camera
(`world.render.default_camera`, 640x480)."""
MIN_CONFIDENCE = 1
"""Depth pixels with ARKit confidence below this (0 low, 1 medium, 2 high) are dropped."""

_ARKIT_TO_OPENCV_CAMERA = np.diag([1.0, -1.0, -1.0, 1.0])
"""The camera-frame change from ARKit's axes (x right, y up, z back) to OpenCV's (x right,
y down, z forward): a half turn about x, its own inverse."""


def arkit_pose_to_opencv(pose_arkit: np.ndarray) -> np.ndarray:
    """float64 [4, 4] camera-to-world with OpenCV camera axes (x right, y down, z forward) of an
    ARKit camera-to-world [4, 4] (camera axes x right, y up, looking down -z).

    The world is unchanged (ARKit's: y up); only the camera's y and z axes flip. A point the
    ARKit camera sees at (x, y, -z) is at (x, -y, z) in the OpenCV camera.
    """
    return np.asarray(pose_arkit, dtype=np.float64) @ _ARKIT_TO_OPENCV_CAMERA


def output_size_px(capture_size_px: tuple[int, int], max_side_px: int | None) -> tuple[int, int]:
    """(width, height) of frames of `capture_size_px` (width, height) scaled down so that the
    longer side is at most `max_side_px` (None: unscaled; never scaled up)."""
    width_px, height_px = capture_size_px
    longer = max(width_px, height_px)
    if max_side_px is None or longer <= max_side_px:
        return width_px, height_px
    scale = max_side_px / longer
    return max(1, round(width_px * scale)), max(1, round(height_px * scale))


def scale_intrinsics(
    intrinsics: Intrinsics, from_size_px: tuple[int, int], to_size_px: tuple[int, int]
) -> Intrinsics:
    """(fx, fy, cx, cy) of an image of `from_size_px` (width, height) resized to `to_size_px`.

    Both images cover the same field of view edge to edge; with pixel centres at integer
    coordinates, x_to + 0.5 = (x_from + 0.5) * scale.
    """
    fx, fy, cx, cy = intrinsics
    scale_x = to_size_px[0] / from_size_px[0]
    scale_y = to_size_px[1] / from_size_px[1]
    return (fx * scale_x, fy * scale_y, (cx + 0.5) * scale_x - 0.5, (cy + 0.5) * scale_y - 0.5)


def check_same_aspect(
    rgb_size_px: tuple[int, int], depth_size_px: tuple[int, int], where: str
) -> None:
    """SourceError naming `where` unless depth and RGB (width, height) share an aspect ratio
    (within 1 %): ARKit's depth covers the colour image's field of view at a lower resolution;
    another aspect means a rotated or cropped image, whose depth would land in the wrong place."""
    rgb_aspect = rgb_size_px[0] / rgb_size_px[1]
    depth_aspect = depth_size_px[0] / depth_size_px[1]
    if abs(depth_aspect / rgb_aspect - 1.0) > 0.01:
        raise SourceError(
            f"{where}: depth is {depth_size_px[0]}x{depth_size_px[1]}, which is not the aspect "
            f"of the {rgb_size_px[0]}x{rgb_size_px[1]} colour image"
        )


class PhoneCaptureSource(FrameSource):
    """A recording from an iPhone/iPad capture app; subclasses read the files and call
    `_phone_frame`. They set `capture_size_px` (the colour image's width, height),
    `capture_intrinsics` (of that image), `max_side_px` and `min_confidence`.

    `intrinsics` and `size_px` are those of the frames the source gives, after scaling.
    """

    capture_size_px: tuple[int, int]
    capture_intrinsics: Intrinsics
    max_side_px: int | None = DEVICE_MAX_SIDE_PX
    min_confidence: int = MIN_CONFIDENCE

    def _set_output(
        self,
        capture_size_px: tuple[int, int],
        capture_intrinsics: Intrinsics,
        max_side_px: int | None,
        min_confidence: int,
    ) -> None:
        """Check the options and fix the output size and intrinsics."""
        if max_side_px is not None and (
            isinstance(max_side_px, bool) or not isinstance(max_side_px, int) or max_side_px < 1
        ):
            raise ValueError(f"max_side_px must be a positive integer or None, got {max_side_px!r}")
        if isinstance(min_confidence, bool) or min_confidence not in (0, 1, 2):
            raise ValueError(f"min_confidence must be 0, 1 or 2, got {min_confidence!r}")
        self.capture_size_px = capture_size_px
        self.capture_intrinsics = capture_intrinsics
        self.max_side_px = max_side_px
        self.min_confidence = min_confidence
        self.size_px = output_size_px(capture_size_px, max_side_px)
        """(width, height) of the frames this source gives."""
        self.intrinsics = scale_intrinsics(capture_intrinsics, capture_size_px, self.size_px)
        """(fx, fy, cx, cy) of the frames this source gives."""

    def _phone_frame(
        self,
        index: int,
        t: float,
        rgb: np.ndarray,
        depth_m: np.ndarray,
        confidence: np.ndarray | None,
        pose: np.ndarray,
        where: str,
    ) -> SourceFrame:
        """The SourceFrame of a capture's colour image uint8 [H, W, 3] at `capture_size_px`,
        sensor depth float [h, w] in metres, its confidence uint8 [h, w] (None: keep all) and
        an OpenCV camera-to-world pose [4, 4]; `where` names the frame's files in errors."""
        height_px, width_px = depth_m.shape
        check_same_aspect(self.capture_size_px, (width_px, height_px), where)
        with np.errstate(invalid="ignore"):  # NaN is ARKit's "no depth"
            depth_m = np.where(np.isfinite(depth_m) & (depth_m > 0), depth_m, 0.0)
        depth_m = depth_m.astype(np.float32)
        if confidence is not None:
            if confidence.shape != depth_m.shape:
                raise SourceError(
                    f"{where}: confidence is {confidence.shape[1]}x{confidence.shape[0]}, "
                    f"depth {width_px}x{height_px}"
                )
            depth_m[confidence < self.min_confidence] = 0.0
        if self.size_px != self.capture_size_px:
            rgb = np.asarray(
                Image.fromarray(rgb).resize(self.size_px, Image.Resampling.BILINEAR), np.uint8
            )
        return SourceFrame(
            index=index,
            t=t,
            rgb=rgb,
            depth_m=depth_at_rgb_size(depth_m, rgb.shape),
            pose=pose,
            intrinsics=self.intrinsics,
        )
