"""A piece of a thing that a view showed alone merges into the thing at clean-up; a like
thing beside it stays apart (app.mapping.engine `_piece_of`)."""

from __future__ import annotations

import dataclasses

import numpy as np
from analytic_world import Rect, render_rects

from app.config import Knobs
from app.mapping import geometry as geo
from app.mapping.engine import MappingEngine, make_perception
from app.mapping.object import KEYFRAMES_SEEN_KEPT, MapObject

# A sofa of two faces: its back at 2.5 m and its seat's front 20 cm nearer, one mask.
BACK = Rect(1, "sofa", -0.8, -0.4, 0.8, 0.4, 2.5)
SEAT = Rect(9, "sofa", -0.8, 0.1, 0.8, 0.4, 2.3)
# A view that showed a patch of the back alone, read 4 cm off it (within two voxels of the
# back, not within one): inside the sofa's box, so it hardly widens it.
PIECE = Rect(5, "sofa", -0.3, -0.3, 0.3, 0.0, 2.46)
# Two like books side by side, touching, spines facing the camera.
LEFT_BOOK = Rect(2, "book", 0.3, -0.1, 0.35, 0.15, 1.5)
RIGHT_BOOK = Rect(3, "book", 0.35, -0.1, 0.4, 0.15, 1.5)


def _engine(encoder, cleanup_interval: int = 2) -> MappingEngine:
    knobs = Knobs(
        min_mapping_bbox_area=100,
        min_observations=2,
        cleanup_interval=cleanup_interval,
        transient_max_age=1000,
        min_detection_points=5,
        association_threshold=2.0,  # never associate: every view makes a new object
    )
    return MappingEngine(encoder, knobs, mode="semanticxr", backend=make_perception())


def _whole_sofa(extra: list[Rect] = ()):
    """The sofa's back and seat as one detection (the seat's pixels carry the back's id)."""
    frame = render_rects([BACK, SEAT, *extra])
    ids = frame.instance_ids.copy()
    ids[ids == SEAT.instance_id] = BACK.instance_id
    instances = [i for i in frame.instances if i["id"] != SEAT.instance_id]
    return dataclasses.replace(frame, instance_ids=ids, instances=instances)


def test_box_growth():
    box = np.array([0.0, 0.0, 0.0, 1.0, 1.0, 1.0])
    inside = np.array([0.2, 0.2, 0.2, 0.5, 0.5, 0.5])
    beside = np.array([1.0, 0.0, 0.0, 2.0, 1.0, 1.0])
    assert geo.box_growth(inside, box, 0.0) == 1.0
    assert np.isclose(geo.box_growth(beside, box, 0.0), 2.0)
    flat = np.array([0.0, 0.0, 0.0, 1.0, 1.0, 0.0])  # a flat box still has a volume
    assert np.isclose(geo.box_growth(flat, flat, 0.1), 1.0)
    assert np.isclose(geo.box_growth(flat + [0, 0, 0.1, 0, 0, 0.1], flat, 0.1), 0.3 / 0.2)


def test_a_piece_seen_alone_merges_into_its_thing(encoder):
    engine = _engine(encoder)
    for frame in (_whole_sofa(), render_rects([PIECE]), _whole_sofa(), render_rects([PIECE])):
        engine.integrate(frame)
    sofas = [o for o in engine.objects.values() if o.label == "sofa"]
    assert len(sofas) == 1, [(o.id, len(o.points)) for o in sofas]
    assert sofas[0].n_obs == 4


def test_the_piece_is_not_on_the_thing_by_the_older_rule(encoder):
    """What makes the piece test needed: the piece does not lie on the sofa within a voxel."""
    engine = _engine(encoder, cleanup_interval=100)  # no merge check yet
    engine.integrate(_whole_sofa())
    engine.integrate(render_rects([PIECE]))
    sofa, piece = sorted(engine.objects.values(), key=lambda o: o.id)
    voxel_m = engine.knobs.voxel_size_m
    assert geo.overlap_fraction(piece.points, sofa.tree, voxel_m) < 0.7
    assert geo.overlap_fraction(piece.points, sofa.tree, 2 * voxel_m) > 0.8


def test_like_things_side_by_side_stay_apart(encoder):
    engine = _engine(encoder)
    for _ in range(2):
        engine.integrate(render_rects([LEFT_BOOK]))
        engine.integrate(render_rects([RIGHT_BOOK]))
    engine.settle()
    books = sorted(engine.objects.values(), key=lambda o: o.bbox[0])
    assert [o.label for o in books] == ["book", "book"]
    # each book's own: the left one ends where the right one starts
    assert books[0].bbox[3] < 0.36 and books[1].bbox[0] > 0.34


def test_two_things_one_keyframe_saw_apart_are_not_pieces_of_one(encoder):
    """The piece's geometry test passes, but a keyframe showed it and the sofa as two
    detections: two things (the next book on a shelf), kept apart."""
    engine = _engine(encoder)
    engine.integrate(_whole_sofa())
    for _ in range(2):
        engine.integrate(_whole_sofa([PIECE]))  # now a thing stands in front of the back
    sofas = sorted((o for o in engine.objects.values() if o.label == "sofa"), key=lambda o: o.id)
    assert len(sofas) == 2
    assert sofas[0].keyframes_seen & sofas[1].keyframes_seen == {2, 3}
    engine.settle()
    assert len([o for o in engine.objects.values() if o.label == "sofa"]) == 2


def test_keyframes_seen_keeps_the_newest_and_merges_carry_them(encoder):
    obj = MapObject(id=1)
    obj.seen_at(set(range(200)))
    obj.seen_at(7)  # an old one is not kept
    assert obj.keyframes_seen == set(range(200 - KEYFRAMES_SEEN_KEPT, 200))
    engine = _engine(encoder, cleanup_interval=100)
    engine.integrate(_whole_sofa())
    engine.integrate(render_rects([PIECE]))
    engine.settle()
    (sofa,) = [o for o in engine.objects.values() if o.label == "sofa"]
    assert sofa.keyframes_seen == {1, 2}
