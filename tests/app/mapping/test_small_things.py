"""The depth co-design keeps small things: a detection too small to map at the downsampled
depth is mapped from the full-resolution depth patch the device sends with it (issue 13)."""

from __future__ import annotations

import numpy as np
from analytic_world import Rect, RectSource
from scipy import ndimage

from app.config import Knobs
from app.mapping.engine import MappingEngine
from app.protocol import parse_frame
from client_sim.encoder import FrameEncoder

WALL = Rect(1, "wall art", -3.0, -2.0, 3.0, 2.0, 4.0)
"""A large picture behind everything, so that a mask bleeding past a small thing hits it."""
CUP = Rect(2, "mug", 0.05, 0.05, 0.15, 0.15, 2.5)
"""10 cm at 2.5 m: about 11 x 11 px of the 320 x 240 image, 2 x 2 depth pixels at ÷5."""


def bled(frame, instance_id: int, px: int):
    """The frame with one instance's mask grown by `px` pixels, as a detector's mask bleeds
    onto what lies behind an object."""
    ids = frame.instance_ids.copy()
    grown = ndimage.binary_dilation(ids == instance_id, iterations=px)
    ids[grown] = instance_id
    frame.instance_ids = ids
    return frame


def walk(encoder, frame_encoder: FrameEncoder, n_frames: int = 4) -> MappingEngine:
    """Map `n_frames` frames of the cup in front of the wall, sent the way the device sends
    them (encoded, then parsed), with the cup's mask bled by 2 px."""
    engine = MappingEngine(encoder, Knobs(min_observations=2, cleanup_interval=1000))
    source = RectSource((WALL, CUP), n_frames=n_frames, step_m=0.02)
    for index in range(n_frames):
        message = frame_encoder.encode_source_frame(bled(source.frame(index), CUP.instance_id, 2))
        engine.integrate(parse_frame(message.message, rgb_pixels=False))
    return engine


def mugs(engine: MappingEngine):
    return [o for o in engine.confirmed_objects() if o.label == "mug"]


def test_a_small_object_seen_only_from_afar_is_mapped_from_its_depth_patch(encoder):
    engine = walk(encoder, FrameEncoder(5))
    [mug] = mugs(engine)
    # On the cup's plane, not on the wall its bled mask also covered.
    assert np.abs(mug.points[:, 2] - CUP.depth_m).max() < 0.03
    assert CUP.x0 - 0.03 <= mug.points[:, 0].min() and mug.points[:, 0].max() <= CUP.x1 + 0.03


def test_without_a_depth_patch_the_small_object_is_deferred(encoder):
    engine = walk(encoder, FrameEncoder(5, depth_patch_max_area_px=0))
    assert mugs(engine) == []
    assert [o.label for o in engine.confirmed_objects()] == ["wall art"]


def test_the_baseline_ignores_depth_patches(encoder):
    engine = MappingEngine(encoder, Knobs(min_observations=1), mode="baseline")
    source = RectSource((WALL, CUP), n_frames=1)
    message = FrameEncoder(5).encode_source_frame(source.frame(0)).message
    assert "depth_patches" in message
    engine.integrate(parse_frame(message, rgb_pixels=False))
    # At ÷5 the cup lifts to 4 depth pixels, under min_detection_points: not mapped.
    assert "mug" not in {o.label for o in engine.objects.values()}
