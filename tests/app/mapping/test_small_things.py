"""The depth co-design keeps small things: a detection too small to map at the downsampled
depth is mapped from the full-resolution depth patch the device sends with it."""

from __future__ import annotations

import numpy as np
from analytic_world import Rect, RectSource
from scipy import ndimage

from app.config import Knobs
from app.mapping.engine import MappingEngine, make_perception
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
    engine = MappingEngine(
        encoder, Knobs(min_observations=2, cleanup_interval=1000), backend=make_perception()
    )
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
    engine = MappingEngine(
        encoder,
        Knobs(min_observations=1),
        mode="baseline",
        backend=make_perception(mode="baseline"),
    )
    source = RectSource((WALL, CUP), n_frames=1)
    message = FrameEncoder(5).encode_source_frame(source.frame(0)).message
    assert "depth_patches" in message
    engine.integrate(parse_frame(message, rgb_pixels=False))
    # At ÷5 the cup lifts to 4 depth pixels, under min_detection_points: not mapped.
    assert "mug" not in {o.label for o in engine.objects.values()}


FRAME = Rect(3, "picture frame", 0.30, -0.30, 0.34, 0.05, 2.5)
"""4 cm x 35 cm at 2.5 m: a box of about 5 x 39 = 195 px, over a deferral area of 150 px,
but 1 x 8 depth pixels at ÷5: a thin thing the downsampled depth cannot map."""
THIN_KNOBS = dict(min_mapping_bbox_area=150, min_detection_points=20)


def thin_walk(encoder, frame_encoder: FrameEncoder) -> MappingEngine:
    engine = MappingEngine(
        encoder,
        Knobs(min_observations=2, cleanup_interval=1000, **THIN_KNOBS),
        backend=make_perception(),
    )
    source = RectSource((WALL, FRAME), n_frames=4, step_m=0.02)
    for index in range(4):
        message = frame_encoder.encode_source_frame(source.frame(index))
        stats = engine.integrate(parse_frame(message.message, rgb_pixels=False))
        assert stats.deferred == 0  # its box is over the deferral area
    return engine


def test_a_thin_thing_the_downsampled_depth_lifts_too_few_points_of_is_mapped_from_its_patch(
    encoder,
):
    engine = thin_walk(encoder, FrameEncoder(5, depth_patch_max_area_px=400))
    [frame] = [o for o in engine.confirmed_objects() if o.label == "picture frame"]
    assert np.abs(frame.points[:, 2] - FRAME.depth_m).max() < 0.03
    assert (
        FRAME.y0 - 0.03 <= frame.points[:, 1].min() and frame.points[:, 1].max() <= FRAME.y1 + 0.03
    )


def test_without_its_patch_the_thin_thing_is_too_small_to_map(encoder):
    engine = thin_walk(encoder, FrameEncoder(5, depth_patch_max_area_px=100))
    assert "picture frame" not in {o.label for o in engine.objects.values()}


def test_the_device_sends_patches_up_to_twice_the_deferral_area():
    area = Knobs().min_mapping_bbox_area
    px_per_m = 277.0 / 2.5  # at 2.5 m
    height_m = area / px_per_m**2 / 0.5  # a 0.5 m wide rectangle of `area` pixels
    under = Rect(4, "painting", -1.2, -0.2, -0.7, -0.2 + 1.5 * height_m, 2.5)
    over = Rect(5, "window", 0.2, -0.2, 0.7, -0.2 + 2.5 * height_m, 2.5)
    source_frame = RectSource((under, over), n_frames=1).frame(0)
    message = FrameEncoder(5).encode_source_frame(source_frame)
    frame = parse_frame(message.message, rgb_pixels=False)
    ys, xs = np.nonzero(source_frame.instance_ids == under.instance_id)
    box = (int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1)
    assert area < (box[2] - box[0]) * (box[3] - box[1]) < 2 * area
    assert [tuple(p.box_px) for p in frame.depth_patches] == [box]  # not the window's


def test_the_device_follows_the_session_s_deferral_area_unless_told_otherwise():
    from client_sim.encoder import session_encoder_options

    knobs = Knobs(min_mapping_bbox_area=150)
    assert session_encoder_options(knobs) == {"depth_patch_max_area_px": 300}
    assert session_encoder_options(knobs, {"depth_patch_max_area_px": 0}) == {
        "depth_patch_max_area_px": 0
    }
