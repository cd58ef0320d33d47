"""Device-side frame encoding: the one owner of each representation that goes upstream.

`downsample_depth` owns the downsampled depth, `depth_to_uint16` its wire units, and
`FrameEncoder.encode` turns full-resolution sensor data into a protocol-v1 "frame" message.
The encoder downsamples depth itself and only ever packs the downsampled image, so the
original can never be sent by mistake.

Depth/RGB pixel correspondence after downsampling by `ratio` (exact, both methods):
depth pixel (u_d, v_d) stands for RGB pixel (u_d * ratio + ratio // 2, v_d * ratio + ratio // 2),
the centre of its ratio x ratio block. With RGB intrinsics (fx, fy, cx, cy), the depth image's
intrinsics are therefore (fx / ratio, fy / ratio, (cx - ratio // 2) / ratio,
(cy - ratio // 2) / ratio).
"""

from __future__ import annotations

import io
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import msgpack
import numpy as np
from PIL import Image
from scipy import ndimage

if TYPE_CHECKING:
    from client_sim.sources.base import SourceFrame

from app.codecs import (
    DEPTH_CODECS,
    MAX_ZSTD_LEVEL,
    encode_jpeg,
    encode_uint16_image,
    pose_to_bytes,
    validate_rigid_pose,
)
from app.codecs import PNG_LEVEL as DEFAULT_PNG_LEVEL
from app.codecs import ZSTD_LEVEL as DEFAULT_ZSTD_LEVEL
from app.config import Knobs
from app.protocol import (
    EncodedDepthPatches,
    Uint16Image,
    pack_depth_patches,
    pack_frame,
    pack_sighting,
)

DEPTH_DOWNSAMPLING_METHODS: tuple[str, ...] = ("nearest", "min")
"""'nearest': the block's centre pixel; 'min': the block's nearest valid depth."""

MAX_UINT16 = 65535

# Upstream defaults, chosen with `python -m bench.device`: together they keep a
# 640x480 frame with depth ÷5 and detections under 1.25 Mbps at 5 fps.
DEFAULT_JPEG_QUALITY = 50
"""RGB JPEG quality (pillow's 1..100 scale). The `detections` backend never looks at RGB."""
DEFAULT_JPEG_OPTIMIZE = True
"""Optimised Huffman tables: lossless, about 2 kB less per 640x480 frame for ~1 ms."""
DEFAULT_DEPTH_CODEC = "png"
"""PNG's row prediction beats zstd on depth images (smooth surfaces)."""
DEFAULT_DEPTH_SCALE_M = 0.01
"""Depth units on the wire (the frame's depth.scale): 1 cm. Depth comes back within 5 mm (RMS
2.9 mm), a fifth of a 2.5 cm map voxel and under Kinect-like noise beyond ~1.4 m; the low
bits of finer units are mostly that noise, which no lossless codec can compress."""
DEFAULT_DETECTIONS_CODEC = "zstd"
"""zstd beats PNG on instance-id images (large flat regions)."""
PATCH_AREA_FACTOR = 2
"""Detections whose box is smaller than this many times the session's `min_mapping_bbox_area`
get a full-resolution depth patch: the ones the server would otherwise defer (under the
knob), and up to twice it, where thin or partly visible things (a picture frame at the image
border) still lift to too few points at depth ÷5. On the 400-frame apartment walk the second
half maps the picture frame (query top-1 +2.3 points on both paraphrase sets) for 3.6 kB more
per keyframe; three times the knob gained nothing more."""
DEFAULT_DEPTH_PATCH_MAX_AREA_PX = PATCH_AREA_FACTOR * Knobs().min_mapping_bbox_area
"""The patch threshold (px) for the default knobs."""


def session_encoder_options(knobs: Knobs, options: dict | None = None) -> dict:
    """FrameEncoder options (besides the depth ratio) for a session with these knobs: `options`,
    with depth patches for boxes under PATCH_AREA_FACTOR x its `min_mapping_bbox_area`
    unless they set `depth_patch_max_area_px` themselves."""
    return {
        "depth_patch_max_area_px": PATCH_AREA_FACTOR * knobs.min_mapping_bbox_area,
        **(options or {}),
    }


# A sighting (the sightings extension, app/protocol/sighting.py) carries what confirmation
# needs at coarse resolution; chosen on the 400-frame apartment walk, where these ratios
# confirm the same objects as whole frames do (a glance is enough: docs/evaluation.md,
# "Targets").
DEFAULT_SIGHTING_DETECTIONS_RATIO = 8
"""A sighting's instance image is the RGB size divided by this (80x60 at 640x480, ~250 B)."""
DEFAULT_SIGHTING_DEPTH_RATIO = 20
"""A sighting's depth is the RGB size divided by this (32x24 at 640x480, ~700 B), each pixel
its block's nearest depth: what it hides is behind that surface, so visibility stays
conservative however coarse the image."""
# The zstd and PNG levels of uint16 images are the codecs' defaults (app.codecs.ZSTD_LEVEL,
# PNG_LEVEL), imported above as DEFAULT_ZSTD_LEVEL and DEFAULT_PNG_LEVEL.


def _is_int(value: object) -> bool:
    return not isinstance(value, bool) and isinstance(value, int | np.integer)


def downsample_depth(depth_m: np.ndarray, ratio: int, method: str = "nearest") -> np.ndarray:
    """Depth [H, W] (metres) -> [H // ratio, W // ratio], one pixel per ratio x ratio block.

    "nearest" keeps the pixel at (v_d * ratio + ratio // 2, u_d * ratio + ratio // 2);
    "min" keeps the smallest valid (> 0, finite) depth of the block, 0 if it has none.
    Neither method averages: a mean across an object's silhouette would invent depths that
    belong to no surface (flying pixels). Trailing rows/columns that do not fill a whole
    block are dropped. `ratio` 1 returns `depth_m` itself.
    """
    if isinstance(ratio, bool) or not isinstance(ratio, int | np.integer) or ratio < 1:
        raise ValueError(f"depth downsampling ratio must be a positive integer, got {ratio!r}")
    if method not in DEPTH_DOWNSAMPLING_METHODS:
        raise ValueError(f"unknown method {method!r}, expected one of {DEPTH_DOWNSAMPLING_METHODS}")
    depth_m = np.asarray(depth_m)
    if depth_m.ndim != 2:
        raise ValueError(f"depth must be [H, W], got shape {list(depth_m.shape)}")
    if ratio == 1:
        return depth_m
    height_px, width_px = depth_m.shape
    out_height, out_width = height_px // ratio, width_px // ratio
    if out_height == 0 or out_width == 0:
        raise ValueError(f"ratio {ratio} is larger than the {width_px}x{height_px} depth image")

    if method == "nearest":
        centre = ratio // 2
        picked = depth_m[centre::ratio, centre::ratio][:out_height, :out_width]
        return np.ascontiguousarray(picked, dtype=np.float32)

    blocks = depth_m[: out_height * ratio, : out_width * ratio].astype(np.float32)
    blocks = blocks.reshape(out_height, ratio, out_width, ratio)
    with np.errstate(invalid="ignore"):  # NaN comparisons are expected: NaN is invalid depth
        valid = np.isfinite(blocks) & (blocks > 0)
    nearest_valid = np.where(valid, blocks, np.inf).min(axis=(1, 3))
    nearest_valid[~np.isfinite(nearest_valid)] = 0.0
    return nearest_valid


def small_boxes(instance_ids: np.ndarray, max_area_px: int) -> list[tuple | None]:
    """For each instance id 1..max of `instance_ids` [H, W], its mask's box (x0, y0, x1, y1),
    half-open, if the box is smaller than `max_area_px`; None for larger or absent ids."""
    out: list[tuple | None] = []
    for found in ndimage.find_objects(np.asarray(instance_ids).astype(np.int64)):
        if found is None:
            out.append(None)
            continue
        rows, cols = found
        box = (int(cols.start), int(rows.start), int(cols.stop), int(rows.stop))
        area = (box[2] - box[0]) * (box[3] - box[1])
        out.append(box if area < max_area_px else None)
    return out


def depth_to_uint16(depth_m: np.ndarray, scale_m: float = 0.001) -> np.ndarray:
    """Depth [h, w] in metres -> uint16 [h, w] in units of `scale_m` metres (rounded).

    Invalid depth (0, negative, NaN, inf) becomes 0, the protocol's "no depth"; depth beyond
    65535 units is clipped to 65535.
    """
    if not (np.isfinite(scale_m) and scale_m > 0):
        raise ValueError(f"depth scale must be a positive number of metres, got {scale_m!r}")
    depth_m = np.asarray(depth_m, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(depth_m) & (depth_m > 0)
    units = np.rint(np.where(valid, depth_m, 0.0) / scale_m)
    return np.clip(units, 0, MAX_UINT16).astype(np.uint16)


def encode_rgb_jpeg(rgb: np.ndarray, quality: int, optimize: bool) -> bytes:
    """JPEG bytes of `rgb`, uint8 [H, W, 3]; `optimize` adds optimised Huffman tables.

    Any baseline JPEG decodes with `app.codecs.decode_jpeg`; the optimised one only differs
    in its entropy coding, so the decoded pixels are the same.
    """
    if not optimize:
        return encode_jpeg(rgb, quality)
    rgb = np.asarray(rgb)
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"rgb must be uint8 [H, W, 3], got {rgb.dtype} {list(rgb.shape)}")
    buffer = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb)).save(
        buffer, format="JPEG", quality=quality, optimize=True
    )
    return buffer.getvalue()


def encode_uint16_image_at_level(img: np.ndarray, codec: str, zstd_level: int) -> bytes:
    """`app.codecs.encode_uint16_image` at the device's levels: zstd at `zstd_level`, PNG at
    `DEFAULT_PNG_LEVEL`. The wire format does not depend on the level."""
    img = np.asarray(img)
    if img.dtype != np.uint16 or img.ndim != 2 or img.size == 0:
        raise ValueError(f"expected uint16 [h, w], got {img.dtype} {list(img.shape)}")
    level = {"zstd": zstd_level, "png": DEFAULT_PNG_LEVEL}.get(codec)
    return encode_uint16_image(img, codec, level)


@dataclass
class EncodedFrame:
    """One encoded frame and what each part of it costs on the wire."""

    message: dict
    """The protocol-v1 "frame" message, ready for `msgpack.packb`."""

    bytes_by_kind: dict[str, int] = field(default_factory=dict)
    """Payload bytes of "rgb", "depth", "detections" (0 if absent) and "pose"; "total" is
    the size of the whole msgpack-packed message (payloads + framing)."""


class FrameEncoder:
    """Encodes full-resolution device frames into protocol-v1 "frame" messages."""

    def __init__(
        self,
        depth_downsampling_ratio: int = 5,
        jpeg_quality: int = DEFAULT_JPEG_QUALITY,
        depth_codec: str = DEFAULT_DEPTH_CODEC,
        detections_codec: str = DEFAULT_DETECTIONS_CODEC,
        depth_scale_m: float = DEFAULT_DEPTH_SCALE_M,
        depth_method: str = "nearest",
        jpeg_optimize: bool = DEFAULT_JPEG_OPTIMIZE,
        zstd_level: int = DEFAULT_ZSTD_LEVEL,
        depth_patch_max_area_px: int = DEFAULT_DEPTH_PATCH_MAX_AREA_PX,
        sighting_detections_ratio: int = DEFAULT_SIGHTING_DETECTIONS_RATIO,
        sighting_depth_ratio: int = DEFAULT_SIGHTING_DEPTH_RATIO,
    ) -> None:
        """depth_scale_m: metres per depth unit on the wire (0 < scale <= 1, the protocol's
        range); depth is rounded to it, so it comes back within scale / 2. zstd_level: 1..22,
        for whichever of depth and detections uses zstd. depth_patch_max_area_px: with a
        depth ratio above 1, each detection whose box is smaller than this also goes up as a
        full-resolution depth patch of its box (0: none). sighting_*_ratio: how much smaller
        than the RGB image a sighting's instance image and depth are (`encode_sighting`).
        Bad values raise ValueError."""
        if depth_codec not in DEPTH_CODECS:
            raise ValueError(f"unknown depth codec {depth_codec!r}, expected one of {DEPTH_CODECS}")
        if detections_codec not in DEPTH_CODECS:
            raise ValueError(
                f"unknown detections codec {detections_codec!r}, expected one of {DEPTH_CODECS}"
            )
        if depth_method not in DEPTH_DOWNSAMPLING_METHODS:
            raise ValueError(
                f"unknown depth method {depth_method!r}, "
                f"expected one of {DEPTH_DOWNSAMPLING_METHODS}"
            )
        if not _is_int(depth_downsampling_ratio) or depth_downsampling_ratio < 1:
            raise ValueError(
                f"depth_downsampling_ratio must be a positive integer, "
                f"got {depth_downsampling_ratio!r}"
            )
        for name, ratio in (
            ("sighting_detections_ratio", sighting_detections_ratio),
            ("sighting_depth_ratio", sighting_depth_ratio),
        ):
            if not _is_int(ratio) or ratio < 1:
                raise ValueError(f"{name} must be a positive integer, got {ratio!r}")
        if not _is_int(jpeg_quality) or not 1 <= jpeg_quality <= 100:
            raise ValueError(f"jpeg_quality must be an integer in 1..100, got {jpeg_quality!r}")
        if not _is_int(zstd_level) or not 1 <= zstd_level <= MAX_ZSTD_LEVEL:
            raise ValueError(
                f"zstd_level must be an integer in 1..{MAX_ZSTD_LEVEL}, got {zstd_level!r}"
            )
        if (
            isinstance(depth_scale_m, bool)
            or not isinstance(depth_scale_m, int | float | np.floating)
            or not (np.isfinite(depth_scale_m) and 0 < depth_scale_m <= 1)
        ):
            raise ValueError(
                f"depth_scale_m must be metres per unit in (0, 1], got {depth_scale_m!r}"
            )
        if not _is_int(depth_patch_max_area_px) or depth_patch_max_area_px < 0:
            raise ValueError(
                f"depth_patch_max_area_px must be an integer >= 0, got {depth_patch_max_area_px!r}"
            )
        self.depth_patch_max_area_px = int(depth_patch_max_area_px)
        self.depth_downsampling_ratio = depth_downsampling_ratio
        self.jpeg_quality = int(jpeg_quality)
        self.jpeg_optimize = bool(jpeg_optimize)
        self.depth_codec = depth_codec
        self.detections_codec = detections_codec
        self.depth_scale_m = float(depth_scale_m)
        self.depth_method = depth_method
        self.zstd_level = int(zstd_level)
        self.sighting_detections_ratio = int(sighting_detections_ratio)
        self.sighting_depth_ratio = int(sighting_depth_ratio)

    def encode_source_frame(self, frame: SourceFrame, seq: int | None = None) -> EncodedFrame:
        """The wire message of a frame from a FrameSource (seq defaults to its index)."""
        return self.encode(
            seq=frame.index if seq is None else seq,
            t=frame.t,
            rgb=frame.rgb,
            depth_m=frame.depth_m,
            pose=frame.pose,
            intrinsics=frame.intrinsics,
            instance_ids=frame.instance_ids,
            instances=frame.instances,
        )

    def encode_source_frame_as_sighting(
        self, frame: SourceFrame, seq: int | None = None
    ) -> EncodedFrame:
        """The `sighting` of a frame from a FrameSource (seq defaults to its index); the
        frame must carry detections."""
        if frame.instance_ids is None:
            raise ValueError("a sighting needs the frame's detections (instance_ids)")
        return self.encode_sighting(
            seq=frame.index if seq is None else seq,
            t=frame.t,
            depth_m=frame.depth_m,
            pose=frame.pose,
            intrinsics=frame.intrinsics,
            instance_ids=frame.instance_ids,
            instances=frame.instances,
        )

    def encode_sighting(
        self,
        seq: int,
        t: float,
        depth_m: np.ndarray,
        pose: np.ndarray,
        intrinsics: tuple,
        instance_ids: np.ndarray,
        instances: list[dict],
    ) -> EncodedFrame:
        """The `sighting` message of one frame that is not a keyframe (the sightings
        extension): its detections and its depth at coarse resolution, no RGB.

        depth_m: float [H, W] metres at RGB size; instance_ids: integer [H, W] (0 = none)
        described by `instances` [{"id", "label", "score"}]; pose and intrinsics as in
        `encode`. The instance image is sampled at the centre of each
        `sighting_detections_ratio` block, the depth keeps each `sighting_depth_ratio`
        block's nearest valid depth."""
        instance_ids = np.asarray(instance_ids)
        depth_m = np.asarray(depth_m)
        if instance_ids.ndim != 2 or instance_ids.dtype.kind not in "iu":
            raise ValueError(
                f"instance_ids must be an integer [H, W] image, got {instance_ids.dtype} "
                f"{list(instance_ids.shape)}"
            )
        if depth_m.shape != instance_ids.shape:
            raise ValueError(
                f"depth {list(depth_m.shape)} must be at the instance image's (RGB) size "
                f"{list(instance_ids.shape)}"
            )
        if instance_ids.size and (instance_ids.min() < 0 or instance_ids.max() > MAX_UINT16):
            raise ValueError("instance ids must lie in 0..65535 (0 = no instance)")
        if len(intrinsics) != 4:
            raise ValueError(f"intrinsics must be (fx, fy, cx, cy), got {intrinsics!r}")
        height_px, width_px = instance_ids.shape
        ratio = self.sighting_detections_ratio
        centre = ratio // 2
        ids_small = np.ascontiguousarray(
            instance_ids[centre::ratio, centre::ratio][: height_px // ratio, : width_px // ratio],
            np.uint16,
        )
        depth_units = depth_to_uint16(
            downsample_depth(depth_m, self.sighting_depth_ratio, "min"), self.depth_scale_m
        )
        depth_data = encode_uint16_image_at_level(depth_units, self.depth_codec, self.zstd_level)
        ids_data = encode_uint16_image_at_level(ids_small, self.detections_codec, self.zstd_level)
        present = set(np.unique(ids_small).tolist())
        pose_data = pose_to_bytes(validate_rigid_pose(pose))
        message = pack_sighting(
            seq=seq,
            t=t,
            pose=pose_data,
            intrinsics=intrinsics,
            rgb_size=(width_px, height_px),
            depth=Uint16Image(
                self.depth_codec, int(depth_units.shape[1]), int(depth_units.shape[0]), depth_data
            ),
            depth_scale_m=self.depth_scale_m,
            detections=Uint16Image(
                self.detections_codec, int(ids_small.shape[1]), int(ids_small.shape[0]), ids_data
            ),
            # what the coarse image lost is not described
            instances=[inst for inst in instances if inst["id"] in present],
        )
        bytes_by_kind = {
            "rgb": 0,
            "depth": len(depth_data),
            "detections": len(ids_data),
            "pose": len(pose_data),
            "total": len(msgpack.packb(message, use_bin_type=True)),
        }
        return EncodedFrame(message=message, bytes_by_kind=bytes_by_kind)

    def encode(
        self,
        seq: int,
        t: float,
        rgb: np.ndarray,
        depth_m: np.ndarray,
        pose: np.ndarray,
        intrinsics: tuple,
        instance_ids: np.ndarray | None = None,
        instances: list[dict] | None = None,
    ) -> EncodedFrame:
        """The wire message of one frame.

        rgb: uint8 [H, W, 3]. depth_m: float [H, W] metres, registered to the RGB image
        (0/NaN = no depth); it is downsampled here. pose: camera-to-world [4, 4], rigid.
        intrinsics: (fx, fy, cx, cy) of the RGB image in pixels. instance_ids: optional
        integer [H, W], instance id per pixel (0 = none, at most 65535), described by
        `instances` = [{"id", "label", "score"}].
        """
        rgb = np.asarray(rgb)
        if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
            raise ValueError(f"rgb must be uint8 [H, W, 3], got {rgb.dtype} {list(rgb.shape)}")
        rgb_size_hw = rgb.shape[:2]
        depth_m = np.asarray(depth_m)
        if depth_m.shape != rgb_size_hw:
            # The pixel correspondence (module docstring) assumes depth registered at RGB size.
            raise ValueError(
                f"depth {list(depth_m.shape)} must be at RGB size {list(rgb_size_hw)} "
                f"before downsampling"
            )
        if len(intrinsics) != 4:
            raise ValueError(f"intrinsics must be (fx, fy, cx, cy), got {intrinsics!r}")
        if instances is not None and instance_ids is None:
            raise ValueError("instances given without an instance_ids image")

        rgb_jpeg = encode_rgb_jpeg(rgb, self.jpeg_quality, self.jpeg_optimize)
        depth_small_m = downsample_depth(depth_m, self.depth_downsampling_ratio, self.depth_method)
        depth_units = depth_to_uint16(depth_small_m, self.depth_scale_m)
        depth_data = encode_uint16_image_at_level(depth_units, self.depth_codec, self.zstd_level)
        pose_data = pose_to_bytes(validate_rigid_pose(pose))

        detections, detections_bytes = None, 0
        patches, patches_bytes = None, 0
        if instance_ids is not None:
            detections = self._encode_detections(instance_ids, rgb)
            detections_bytes = len(detections.data)
            patches = self._encode_depth_patches(np.asarray(instance_ids), depth_m)
            patches_bytes = len(patches.data) if patches is not None else 0
        message = pack_frame(
            seq=seq,
            t=t,
            pose=pose_data,
            intrinsics=intrinsics,
            rgb_jpeg=rgb_jpeg,
            depth=Uint16Image(
                self.depth_codec,
                int(depth_units.shape[1]),
                int(depth_units.shape[0]),
                depth_data,
            ),
            depth_scale_m=self.depth_scale_m,
            detections=detections,
            instances=instances or [],
            depth_patches=patches,
        )

        bytes_by_kind = {
            "rgb": len(rgb_jpeg),
            "depth": len(depth_data),
            "detections": detections_bytes,
            "depth_patches": patches_bytes,
            "pose": len(pose_data),
            "total": len(msgpack.packb(message, use_bin_type=True)),
        }
        return EncodedFrame(message=message, bytes_by_kind=bytes_by_kind)

    def _encode_depth_patches(
        self, instance_ids: np.ndarray, depth_m: np.ndarray
    ) -> EncodedDepthPatches | None:
        """Full-resolution depth of the boxes of the detections smaller than
        `depth_patch_max_area_px` (the ones the server could not map at the downsampled
        depth), or None when there are none or depth is not downsampled."""
        if self.depth_downsampling_ratio == 1 or self.depth_patch_max_area_px == 0:
            return None
        boxes = [
            box
            for box in small_boxes(instance_ids, self.depth_patch_max_area_px)
            if box is not None
        ]
        if not boxes:
            return None
        level = self.zstd_level
        return pack_depth_patches(
            depth_to_uint16(depth_m, self.depth_scale_m), boxes, "zstd", level
        )

    def _encode_detections(self, instance_ids: np.ndarray, rgb: np.ndarray) -> Uint16Image:
        """The instance-id image of the "detections" part, at RGB size."""
        instance_ids = np.asarray(instance_ids)
        if instance_ids.shape != rgb.shape[:2] or instance_ids.dtype.kind not in "iu":
            raise ValueError(
                f"instance_ids must be integer [H, W] at RGB size {list(rgb.shape[:2])}, "
                f"got {instance_ids.dtype} {list(instance_ids.shape)}"
            )
        if instance_ids.size and (instance_ids.min() < 0 or instance_ids.max() > MAX_UINT16):
            raise ValueError("instance ids must lie in 0..65535 (0 = no instance)")
        height_px, width_px = instance_ids.shape
        return Uint16Image(
            self.detections_codec,
            int(width_px),
            int(height_px),
            encode_uint16_image_at_level(
                instance_ids.astype(np.uint16), self.detections_codec, self.zstd_level
            ),
        )
