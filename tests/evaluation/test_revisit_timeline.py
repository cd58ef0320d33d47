"""The revisit eval's per-change timelines: where a change's time went (the first frame and
keyframe showing its evidence, the map's first doubt, candidates near its new place, what
the map concluded), read from the walks' records and a real engine's map."""

from __future__ import annotations

import dataclasses

from analytic_world import Rect, render_rects

from app.config import Knobs
from app.mapping.engine import MappingEngine, make_perception
from app.mapping.object import Change
from evaluation.revisit import _MapTrace, _timeline, _Walks
from world.changes import GroundTruthChange

WALL = Rect(9, "whiteboard", -3.0, -2.0, 3.0, 2.0, 3.0)
MUG = Rect(1, "mug", -0.5, -0.2, -0.3, 0.0, 2.0)


def test_a_trace_notes_when_the_map_first_saw_confirmed_and_doubted_each_object(encoder):
    knobs = Knobs(min_mapping_bbox_area=100, min_observations=2, cleanup_interval=1000)
    engine = MappingEngine(encoder, knobs, "semanticxr", backend=make_perception(mode="semanticxr"))
    trace = _MapTrace()
    for i, (rects, t, walk2) in enumerate(
        [([WALL, MUG], 0.0, False), ([WALL, MUG], 1.0, False), ([WALL], 600.0, True)]
    ):
        frame = dataclasses.replace(render_rects(rects, seq=5 * i), t=t)
        engine.integrate(frame)
        trace.read(engine, t, walk2)
    (mug,) = [o.id for o in engine.objects.values() if o.label == "mug"]
    assert trace.first_seen[mug][:2] == (-1.0, "mug")  # before the second walk
    assert trace.confirmed_t[mug] == -1.0
    assert trace.doubted_t[mug] == 600.0 and trace.depth_doubted_t[mug] == 600.0


def test_a_timeline_puts_each_step_of_a_move_on_the_second_walks_clock():
    walks = _Walks(scenario=None)  # type: ignore[arg-type]
    walks.old_place_first_frame_t[7] = 705.4
    walks.old_place_shown_t[7] = [712.0, 713.0]
    walks.new_place_first_frame_t[7] = 706.8
    walks.new_place_seen_t[7] = 707.0
    walks.old_place_frames[7] = [{"t": 705.4, "keyframe": False, "visible": 1.0, "px": 832}]
    trace = _MapTrace(
        doubted_t={10: 712.0},
        depth_doubted_t={10: 712.0},
        first_seen={10: (-1.0, "kettle", [0, 0, 1]), 88: (701.0, "kettle", [2.0, 0.0, 1.02])},
        confirmed_t={10: -1.0, 88: 702.0},
    )
    change = GroundTruthChange(7, "moved", "kettle", (0.0, 0.0, 1.0), (2.0, 0.0, 1.0), 700.0)
    concluded = [Change(10, "moved", 712.0, "kettle"), Change(11, "removed", 720.0, "mug")]
    out = _timeline(walks, change, trace, {10: 7, 11: 8}, concluded, t_walk2=700.0)
    assert (out["t_evidence_old"], out["t_evidence_new"]) == (5.4, 6.8)
    assert (out["t_keyframe_old"], out["t_keyframe_new"]) == (12.0, 7.0)
    assert out["old_place_keyframes"] == 2 and out["map_ids"] == [10]
    assert (out["t_doubted"], out["t_depth_doubted"]) == (12.0, 12.0)
    assert out["concluded"] == [{"id": 10, "kind": "moved", "t": 12.0}]
    assert out["old_place_frames"] == [{"t": 5.4, "keyframe": False, "visible": 1.0, "px": 832}]
    (candidate,) = out["candidates"]  # the object the map held before the walk is no candidate
    assert candidate == {
        "id": 88,
        "label": "kettle",
        "t_first_seen": 1.0,
        "t_confirmed": 2.0,
        "distance_m": 0.02,
    }
