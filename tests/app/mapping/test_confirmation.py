"""Confirmation (a glance is enough: docs/evaluation.md "Targets"): detections a v1 client sends with
every frame count as sightings between keyframes, so an object in view for about 1.5 s of a
sweep is confirmed, while a detection living for a few frames only is never published."""

from __future__ import annotations

import pytest
from analytic_world import Rect, render_rects

from app.config import Knobs
from app.mapping.engine import MappingEngine, make_perception

CHAIR = Rect(1, "chair", -0.6, -0.3, -0.1, 0.3, 2.0)
MUG = Rect(2, "mug", 0.2, -0.1, 0.4, 0.1, 1.5)
BOWL = Rect(2, "bowl", 0.2, -0.1, 0.4, 0.1, 1.5)  # the same place, another label
WINDOW = Rect(3, "window", -0.8, -0.6, 0.8, -0.35, 3.0)
DOOR = Rect(3, "door", -0.8, -0.6, 0.8, -0.35, 3.0)  # the window, under a confused label
FRAMES = 40


def make_engine(encoder) -> MappingEngine:
    knobs = Knobs(min_mapping_bbox_area=100, keyframe_interval=5, min_observations=3)
    return MappingEngine(encoder, knobs, backend=make_perception())


def stream(engine: MappingEngine, scene) -> set[int]:
    """What a server does with a v1 client sending every frame whole: map the keyframes,
    count the other frames' detections as sightings. Returns every id ever published."""
    published: set[int] = set()
    for seq in range(FRAMES):
        frame = render_rects(scene(seq), cam_xy=(0.005 * seq, 0.0), seq=seq)
        if seq % engine.knobs.keyframe_interval == 0:
            published |= set(engine.integrate(frame).published_ids)
        else:
            engine.sight(frame, engine.validate_frame(frame))
    return published


def labels_of(engine: MappingEngine, ids) -> set[str]:
    return {engine.objects[i].label for i in ids if i in engine.objects}


@pytest.mark.parametrize("start", [6, 7, 8, 9, 10])
def test_an_object_in_view_for_8_frames_of_a_sweep_is_confirmed(encoder, start):
    # 8 frames at 5 fps: one or two keyframes, wherever the glance falls between them
    engine = make_engine(encoder)
    published = stream(engine, lambda seq: [CHAIR, MUG] if start <= seq < start + 8 else [CHAIR])
    assert {o.label for o in engine.confirmed_objects()} == {"chair", "mug"}
    assert "mug" in labels_of(engine, published)


@pytest.mark.parametrize("lifetime", [1, 2, 3])
def test_a_detection_living_a_few_frames_is_never_published(encoder, lifetime):
    engine = make_engine(encoder)
    published = stream(engine, lambda seq: [CHAIR, MUG] if 10 <= seq < 10 + lifetime else [CHAIR])
    assert {o.label for o in engine.confirmed_objects()} == {"chair"}
    assert labels_of(engine, published) == {"chair"}


def test_a_sighting_needs_the_objects_label(encoder):
    # a mug on one keyframe, then a bowl detected where it was: not a sighting of the mug
    engine = make_engine(encoder)
    stream(
        engine, lambda seq: [CHAIR, MUG] if seq == 10 else [CHAIR, BOWL] if seq < 18 else [CHAIR]
    )
    assert "mug" not in {o.label for o in engine.confirmed_objects()}


def test_a_label_the_other_frames_contradict_is_not_confirmed(encoder):
    # The detector calls the window a door on a keyframe and on two later frames, spread
    # over more than min_observations frames; every other frame calls it a window. The door
    # is seen on 3 frames, but contradicted on the 6 others it was in view in between.
    engine = make_engine(encoder)
    published = stream(engine, lambda seq: [CHAIR, DOOR if seq in (10, 13, 17) else WINDOW])
    assert {o.label for o in engine.confirmed_objects()} == {"chair", "window"}
    assert "door" not in labels_of(engine, published)


def test_sightings_do_not_change_the_map(encoder):
    engine = make_engine(encoder)
    engine.integrate(render_rects([CHAIR, MUG], seq=0))
    before = {oid: (o.version, o.points.tobytes()) for oid, o in engine.objects.items()}
    log_seq = engine.log.seq
    frame = render_rects([CHAIR, MUG], cam_xy=(0.01, 0.0), seq=1)
    sighted = engine.sight(frame, engine.validate_frame(frame))
    assert sorted(engine.objects[i].label for i in sighted) == ["chair", "mug"]
    assert {oid: (o.version, o.points.tobytes()) for oid, o in engine.objects.items()} == before
    assert engine.log.seq == log_seq and engine.confirmed_objects() == []  # until a keyframe
