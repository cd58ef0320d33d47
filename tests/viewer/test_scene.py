"""SceneModel: deltas -> the fewest scene-node operations (no viser, no browser).

`RecordingSink` is the sink interface's second implementation: it records every operation
and keeps the resulting scene (name -> node), so a test can check both what was sent and
what the viewer would show.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pytest

from app.protocol import ChangeEntry, UpsertEntry, pack_delta
from viewer.palette import (
    ANCHOR_RGB,
    BACKGROUND_RGB,
    DIM_GREY_RGB,
    GHOST_FADE_S,
    GHOST_RGB,
    HIT_BOX_RGB,
    MOVE_LINE_RGB,
    TARGET_RGB,
    blend,
    class_color,
    dimmed,
    faded,
    hit_box_color,
    hit_color,
    object_color,
)
from viewer.scene import (
    BOXES_NODE,
    HIT_BOXES_NODE,
    LABELS_GROUP,
    MAX_GHOSTS,
    MOVES_NODE,
    RELATION_BOXES_NODE,
    RELATION_LINES_NODE,
    DeltaError,
    RelationHighlight,
    SceneModel,
    anchor_label_node,
    ghost_label_node,
    ghost_node,
    hit_label_node,
    label_node,
    points_node,
)
from viewer.shapes import box_segments, floor_grid, frame_view
from viewer.words import relation_words

DIM = 8


@dataclass
class RecordingSink:
    """Records operations as (op, name) and holds the scene they build."""

    ops: list[tuple[str, str]] = field(default_factory=list)
    nodes: dict[str, dict[str, Any]] = field(default_factory=dict)

    def add_point_cloud(self, name, points, color):
        self.ops.append(("add_point_cloud", name))
        self.nodes[name] = {"kind": "points", "points": np.asarray(points), "color": color}

    def set_point_color(self, name, color):
        self.ops.append(("set_point_color", name))
        assert self.nodes[name]["kind"] == "points", "recoloured a node that is not a cloud"
        self.nodes[name]["color"] = color

    def add_label(self, name, text, position):
        self.ops.append(("add_label", name))
        self.nodes[name] = {"kind": "label", "text": text, "position": tuple(position)}

    def set_boxes(self, name, segments, colors):
        self.ops.append(("set_boxes", name))
        assert segments.shape == colors.shape and segments.shape[1:] == (2, 3)
        self.nodes[name] = {"kind": "boxes", "segments": segments, "colors": colors}

    def set_lines(self, name, segments, colors):
        self.ops.append(("set_lines", name))
        assert segments.shape == colors.shape and segments.shape[1:] == (2, 3)
        assert colors.dtype == np.uint8
        self.nodes[name] = {"kind": "lines", "segments": segments, "colors": colors}

    def set_visible(self, name, visible):
        self.ops.append(("set_visible", name))
        self.nodes.setdefault(name, {"kind": "group"})["visible"] = visible

    def remove(self, name):
        self.ops.append(("remove", name))
        assert name in self.nodes, f"removed {name}, which is not in the scene"
        for other in [n for n in self.nodes if n == name or n.startswith(name + "/")]:
            del self.nodes[other]

    def take(self) -> list[tuple[str, str]]:
        """The operations since the last take."""
        ops, self.ops = self.ops, []
        return ops


def upsert(
    oid: int,
    version: int,
    label: str = "chair",
    offset: float = 0.0,
    n: int = 20,
    last_seen_t: float | None = None,
):
    """An `upserts[]` entry: n points in a 0.5 m cube at x = oid + offset."""
    rng = np.random.default_rng([oid, version])
    points = rng.uniform(0, 0.5, (n, 3)) + [oid + offset, 0, 0]
    lo, hi = points.min(axis=0), points.max(axis=0)
    return UpsertEntry(
        id=oid,
        version=version,
        label=label,
        embedding=np.ones(DIM) / np.sqrt(DIM),
        points=points,
        bbox=(*lo.tolist(), *hi.tolist()),
        n_obs=version,
        last_seen_t=last_seen_t,
    )


def delta(seq: int, upserts=(), removed=(), full: bool = False, changes=()) -> dict:
    message = pack_delta(seq, upserts, removed, full)
    if changes:  # the living map's extension
        message["changes"] = [change.pack() for change in changes]
    return message


@pytest.fixture
def scene() -> tuple[SceneModel, RecordingSink]:
    """A model holding chair 1, table 2, chair 3 (seq 1); the sink's log starts empty."""
    sink = RecordingSink()
    model = SceneModel(sink)
    model.apply_delta(
        delta(1, [upsert(1, 1), upsert(2, 1, "table"), upsert(3, 1)], full=True),
    )
    sink.take()
    return model, sink


def test_a_first_snapshot_draws_one_cloud_and_label_per_object_and_one_boxes_node():
    sink = RecordingSink()
    model = SceneModel(sink)
    assert sink.take() == [("set_visible", LABELS_GROUP)]

    summary = model.apply_delta(delta(4, [upsert(1, 1), upsert(2, 1, "table")], full=True))

    assert summary.added == [1, 2] and model.seq == 4
    assert sorted(sink.take()) == sorted(
        [
            ("add_point_cloud", points_node(1)),
            ("add_label", label_node(1)),
            ("add_point_cloud", points_node(2)),
            ("add_label", label_node(2)),
            ("set_boxes", BOXES_NODE),
        ]
    )
    assert sink.nodes[label_node(2)]["text"] == "table"
    assert sink.nodes[points_node(1)]["points"].shape == (20, 3)


def test_an_update_replaces_only_the_nodes_of_the_object_that_changed(scene):
    model, sink = scene
    summary = model.apply_delta(delta(2, [upsert(2, 2, "table", offset=0.3)]))

    assert summary.updated == [2] and not summary.added and not summary.removed
    # Its cloud and its label (the box centre moved); the batched boxes once; nothing else.
    assert sink.take() == [
        ("add_point_cloud", points_node(2)),
        ("add_label", label_node(2)),
        ("set_boxes", BOXES_NODE),
    ]


def test_an_update_that_keeps_the_box_and_label_resends_only_the_points(scene):
    model, sink = scene
    changed = upsert(2, 2, "table")
    changed.bbox = upsert(2, 1, "table").bbox  # same box, new points inside it
    model.apply_delta(delta(2, [changed]))
    assert sink.take() == [("add_point_cloud", points_node(2))]


def test_an_object_at_a_version_already_held_causes_no_node_operation(scene):
    model, sink = scene
    summary = model.apply_delta(delta(2, [upsert(1, 1), upsert(3, 1)]))
    assert summary.unchanged == [1, 3] and not summary.changed
    assert sink.take() == []
    assert model.seq == 2  # the seq still advances: resuming starts after it


def test_an_older_version_never_replaces_a_newer_one(scene):
    model, sink = scene
    model.apply_delta(delta(2, [upsert(1, 3, "sofa")]))
    sink.take()
    model.apply_delta(delta(3, [upsert(1, 2, "chair")]))
    assert sink.take() == [] and model.objects[1].label == "sofa"


def test_a_removal_removes_exactly_that_objects_nodes(scene):
    model, sink = scene
    summary = model.apply_delta(delta(2, removed=[3, 99]))  # 99: never held, not an error

    assert summary.removed == [3]
    assert sink.take() == [
        ("remove", points_node(3)),
        ("remove", label_node(3)),
        ("set_boxes", BOXES_NODE),
    ]
    assert len(sink.nodes[BOXES_NODE]["segments"]) == 2 * 12
    assert set(model.objects) == {1, 2}


def test_a_full_snapshot_removes_stale_nodes_and_leaves_unchanged_objects_alone(scene):
    model, sink = scene
    summary = model.apply_delta(delta(9, [upsert(1, 1), upsert(4, 1, "lamp")], full=True))

    assert (summary.added, summary.removed, summary.unchanged) == ([4], [2, 3], [1])
    ops = sink.take()
    assert not [op for op in ops if op[1] in (points_node(1), label_node(1))]
    assert {name for name in sink.nodes if name.startswith("/objects/")} == {
        points_node(1),
        points_node(4),
    }
    assert {name for name in sink.nodes if name.startswith(LABELS_GROUP + "/")} == {
        label_node(1),
        label_node(4),
    }


def test_all_boxes_are_one_line_segments_node_with_twelve_edges_each(scene):
    _, sink = scene
    boxes = [name for name, node in sink.nodes.items() if node["kind"] == "boxes"]
    assert boxes == [BOXES_NODE]
    segments = sink.nodes[BOXES_NODE]["segments"]
    assert segments.shape == (3 * 12, 2, 3)


def test_box_segments_are_the_twelve_unit_length_edges_of_the_box():
    segments = box_segments(np.array([[0, 0, 0, 1, 2, 3]]))
    lengths = np.linalg.norm(segments[:, 1] - segments[:, 0], axis=1)
    assert sorted(lengths.tolist()) == [1.0] * 4 + [2.0] * 4 + [3.0] * 4
    corners = {tuple(p) for p in segments.reshape(-1, 3).tolist()}
    assert len(corners) == 8


def test_a_malformed_or_out_of_order_delta_changes_nothing(scene):
    model, sink = scene
    model.apply_delta(delta(5, [upsert(1, 2)]))
    sink.take()
    bad_points = delta(6, [upsert(3, 5), upsert(2, 5)])  # 3 is valid, but not applied
    bad_points["upserts"][1]["points"] = b"\x00" * 7
    with pytest.raises(DeltaError, match="points"):
        model.apply_delta(bad_points)
    with pytest.raises(DeltaError, match="out of order"):
        model.apply_delta(delta(4, [upsert(3, 6)]))
    with pytest.raises(DeltaError, match="more than once"):
        model.apply_delta(delta(7, [upsert(3, 6), upsert(3, 7)]))
    assert sink.take() == [] and model.seq == 5 and model.objects[3].version == 1


def test_highlight_brightens_hits_labels_them_with_scores_and_dims_the_rest(scene):
    model, sink = scene
    model.highlight([(3, 0.8123), (1, 0.41)])

    assert sink.nodes[hit_label_node(3)]["text"] == "chair 0.81"
    assert sink.nodes[hit_label_node(1)]["text"] == "chair 0.41"
    hit_boxes = sink.nodes[HIT_BOXES_NODE]
    assert hit_boxes["segments"].shape == (2 * 12, 2, 3)
    assert (hit_boxes["colors"][:12] == hit_box_color(0.8123)).all()
    assert sink.nodes[points_node(2)]["color"] == dimmed(object_color(2))
    assert sink.nodes[points_node(3)]["color"] == hit_color(object_color(3), 0.8123)
    assert sink.nodes[LABELS_GROUP]["visible"] is False  # plain labels make way for the hits
    # Recolouring sends colours only: no cloud is sent again.
    assert not [op for op in sink.take() if op[0] == "add_point_cloud"]


def test_hits_are_highlighted_in_proportion_to_their_relevance(scene):
    model, sink = scene
    model.highlight([(3, 1.0), (1, 0.3), (2, 0.0)])

    def brightness(rgb) -> float:  # distance from the grey that dimmed colours fade to
        return float(np.linalg.norm(np.subtract(rgb, DIM_GREY_RGB)))

    colors = {oid: sink.nodes[points_node(oid)]["color"] for oid in (1, 2, 3)}
    assert colors[3] == object_color(3)  # fully relevant: its own colour
    assert colors[2] == dimmed(object_color(2))  # irrelevant: as dim as a non-hit
    assert brightness(dimmed(object_color(1))) < brightness(colors[1])
    assert brightness(colors[1]) < brightness(object_color(1))
    box_colors = sink.nodes[HIT_BOXES_NODE]["colors"].reshape(3, 12, -1, 3)[:, 0, 0]
    assert tuple(box_colors[0]) == HIT_BOX_RGB and tuple(box_colors[2]) == DIM_GREY_RGB
    assert brightness(box_colors[1]) < brightness(box_colors[0])


def test_clear_highlight_restores_the_plain_view(scene):
    model, sink = scene
    before = {name: dict(node) for name, node in sink.nodes.items()}
    model.highlight([(2, 0.5)])
    model.clear_highlight()

    assert not [name for name in sink.nodes if name.startswith("/hits")]
    assert sink.nodes[LABELS_GROUP]["visible"] is True
    for oid in (1, 2, 3):
        assert sink.nodes[points_node(oid)]["color"] == before[points_node(oid)]["color"]
    assert np.array_equal(sink.nodes[BOXES_NODE]["colors"], before[BOXES_NODE]["colors"])
    sink.take()
    model.clear_highlight()  # nothing highlighted: nothing to do
    assert sink.take() == []


def test_a_hit_not_held_yet_is_highlighted_when_it_arrives(scene):
    model, sink = scene
    model.highlight([(7, 0.9)])
    assert hit_label_node(7) not in sink.nodes
    sink.take()

    model.apply_delta(delta(2, [upsert(7, 1, "mug")]))

    assert sink.nodes[hit_label_node(7)]["text"] == "mug 0.90"
    assert sink.nodes[points_node(7)]["color"] == hit_color(object_color(7), 0.9)  # a hit
    assert ("set_boxes", HIT_BOXES_NODE) in sink.take()


def test_removing_a_highlighted_object_removes_its_hit_nodes(scene):
    model, sink = scene
    model.highlight([(1, 0.7)])
    model.apply_delta(delta(2, removed=[1]))
    assert not [name for name in sink.nodes if name.startswith("/hits")]


def test_colour_by_class_recolours_without_sending_points_again(scene):
    model, sink = scene
    model.set_color_by_class(True)

    ops = sink.take()
    assert {op for op, _ in ops} == {"set_point_color", "set_boxes"}
    assert sink.nodes[points_node(1)]["color"] == sink.nodes[points_node(3)]["color"]
    assert sink.nodes[points_node(1)]["color"] == class_color("chair")
    assert sink.nodes[points_node(2)]["color"] == class_color("table")
    model.set_color_by_class(True)  # already on
    assert sink.take() == []


def test_object_colours_are_stable_and_tell_neighbours_apart():
    assert object_color(5) == object_color(5) and class_color("mug") == class_color("mug")
    assert len({object_color(i) for i in range(1, 50)}) == 49


def test_the_labels_toggle_is_one_group_operation_and_the_boxes_toggle_one_node(scene):
    model, sink = scene
    model.set_show_labels(False)
    assert sink.take() == [("set_visible", LABELS_GROUP)]
    model.set_show_boxes(False)
    assert sink.take() == [("remove", BOXES_NODE)]
    model.apply_delta(delta(2, [upsert(4, 1)]))  # hidden boxes are not sent
    assert ("set_boxes", BOXES_NODE) not in sink.take()
    model.set_show_boxes(True)
    assert sink.take() == [("set_boxes", BOXES_NODE)]
    assert len(sink.nodes[BOXES_NODE]["segments"]) == 4 * 12


# --- framing the first camera and the floor -------------------------------------------------


def _project(view, point, up, fov_y, aspect):
    """NDC (x, y) of `point` seen by a pinhole camera at `view` (+y up on screen)."""
    forward = np.subtract(view.look_at, view.position)
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    true_up = np.cross(right, forward)
    rel = np.subtract(point, view.position)
    depth = rel @ forward
    assert depth > 0, "the point is behind the camera"
    tan_y = np.tan(fov_y / 2)
    return (rel @ right) / depth / (aspect * tan_y), (rel @ true_up) / depth / tan_y


@pytest.mark.parametrize("up", [(0, 0, 1), (0, 1, 0), (0, 0, -1)])
@pytest.mark.parametrize("aspect", [1400 / 860, 0.8])
def test_the_first_camera_shows_every_corner_of_the_map_left_of_the_panel(up, aspect):
    up = np.array(up, float)
    bounds = (np.array([-1.0, 2.0, 0.0]), np.array([4.0, 5.5, 2.2]))  # a 5 x 3.5 m room
    fov_y, panel_share = np.deg2rad(75.0), 400 / 1400
    view = frame_view(bounds, up, fov_y, aspect, panel_share)
    corners = np.where(
        np.array([[(k >> a) & 1 for a in range(3)] for k in range(8)]), *bounds[::-1]
    )
    ndc = np.array([_project(view, c, up, fov_y, aspect) for c in corners])
    # every corner on screen and none under the panel (NDC x > 1 - 2 * share)
    assert ndc[:, 0].min() > -1 and ndc[:, 0].max() < 1 - 2 * panel_share
    assert np.abs(ndc[:, 1]).max() < 1
    # and the map is not a speck: it fills a good part of the free width or the height
    free_span = max(np.ptp(ndc[:, 0]) / (2 - 2 * panel_share), np.ptp(ndc[:, 1]) / 2)
    assert free_span > 0.5
    # looking down on it from above
    assert np.dot(np.subtract(view.position, view.look_at), up) > 0


def test_without_the_panel_the_camera_aims_at_the_map_centre():
    bounds = (np.zeros(3), np.array([2.0, 2.0, 1.0]))
    view = frame_view(bounds, np.array([0, 0, 1.0]), np.deg2rad(60), 1.5, panel_share=0.0)
    assert np.allclose(view.look_at, (1.0, 1.0, 0.5))


@pytest.mark.parametrize(
    ("up", "plane", "floor_axis", "floor"),
    [((0, 0, 1), "xy", 2, 0.1), ((0, 1, 0), "xz", 1, 0.3), ((0, 0, -1), "xy", 2, 2.5)],
)
def test_the_floor_grid_lies_under_the_map_along_up(up, plane, floor_axis, floor):
    bounds = (np.array([-0.4, 0.3, 0.1]), np.array([3.2, 4.1, 2.5]))
    grid = floor_grid(bounds, np.array(up, float))
    assert grid is not None and grid.plane == plane
    assert grid.position[floor_axis] == pytest.approx(floor)  # the lowest face along up
    # it covers the footprint with a margin, its edges on multiples of half a metre
    for extent, axis in zip(
        (grid.width, grid.height), ("xyz".index(plane[0]), "xyz".index(plane[1])), strict=True
    ):
        start, end = grid.position[axis] - extent / 2, grid.position[axis] + extent / 2
        assert start <= bounds[0][axis] - 0.25 and end >= bounds[1][axis] + 0.25
        assert 2 * start == round(2 * start) and 2 * end == round(2 * end)


def test_the_floor_grid_follows_the_map_bounds_when_they_cross_half_a_metre(scene):
    model, _ = scene  # objects at x = 1, 2, 3 (0.5 m cubes)
    up = np.array([0, 0, 1.0])
    grid = floor_grid(model.bounds(), up)
    assert grid is not None
    model.apply_delta(delta(2, [upsert(4, 1, offset=-1.4)]))  # x 2.6..3.1: inside the footprint
    assert floor_grid(model.bounds(), up) == grid
    model.apply_delta(delta(3, [upsert(9, 1)]))  # x 9: the footprint grows
    wider = floor_grid(model.bounds(), up)
    assert wider is not None and wider.width > grid.width and wider.height == grid.height
    model.apply_delta(delta(4, [], full=True))  # the map emptied: no floor
    assert model.bounds() is None and floor_grid(model.bounds(), up) is None


# --- the living map: ghosts of removed objects, lines of moved ones -------------------------


def removal(oid: int, t: float, label: str = "chair") -> ChangeEntry:
    return ChangeEntry(oid, "removed", t, label, from_xyz=(oid + 0.25, 0.25, 0.25))


def move(oid: int, t: float, start=None, end=None) -> ChangeEntry:
    return ChangeEntry(oid, "moved", t, "chair", start, end)


def test_a_removed_object_leaves_a_grey_ghost_of_the_points_the_viewer_held(scene):
    model, sink = scene  # chair 1, table 2, chair 3
    held = model.objects[3].points

    summary = model.apply_delta(delta(2, removed=[3], changes=[removal(3, 100.0)]))

    assert summary.removed == [3] and summary.ghosted == [3] and model.ghosts == {3: 100.0}
    assert points_node(3) not in sink.nodes and label_node(3) not in sink.nodes
    ghost = sink.nodes[ghost_node(3)]
    assert np.array_equal(ghost["points"], held) and ghost["color"] == GHOST_RGB
    assert sink.nodes[ghost_label_node(3)]["text"] == "chair (removed)"
    assert 3 not in model.objects  # a ghost is not an object: no box, no query hit


def test_a_removal_without_a_removed_change_leaves_no_ghost(scene):
    """Merges and clean-ups remove ids without a change, as does an older server."""
    model, sink = scene
    summary = model.apply_delta(delta(2, removed=[3]))

    assert summary.ghosted == [] and model.ghosts == {}
    assert not [name for name in sink.nodes if "ghost" in name]


def test_a_ghost_fades_into_the_background_with_device_time_and_then_goes(scene):
    model, sink = scene
    model.apply_delta(delta(2, removed=[3], changes=[removal(3, 100.0)]))
    sink.take()

    half = 100.0 + GHOST_FADE_S / 2  # the device's clock: a sighting's last_seen_t
    model.apply_delta(delta(3, [upsert(1, 2, last_seen_t=half)]))

    assert model.device_t == half
    assert ("set_point_color", ghost_node(3)) in sink.take()  # recoloured, points not resent
    assert sink.nodes[ghost_node(3)]["color"] == blend(GHOST_RGB, BACKGROUND_RGB, 0.5)

    model.apply_delta(delta(4, [upsert(1, 3, last_seen_t=100.0 + GHOST_FADE_S)]))

    assert model.ghosts == {}
    assert ghost_node(3) not in sink.nodes and ghost_label_node(3) not in sink.nodes


def test_fading_recolours_a_ghost_only_when_its_colour_changes(scene):
    model, sink = scene
    model.apply_delta(delta(2, removed=[3], changes=[removal(3, 100.0)]))
    sink.take()

    model.apply_delta(delta(3, [upsert(1, 2, last_seen_t=100.01)]))  # not one step of 255

    assert ("set_point_color", ghost_node(3)) not in sink.take()


def test_a_moved_object_gets_a_line_from_its_old_place_to_its_new_one(scene):
    model, sink = scene
    start, end = (2.25, 0.25, 0.25), (5.25, 0.25, 0.25)

    summary = model.apply_delta(
        delta(2, [upsert(2, 2, "table", offset=3.0)], changes=[move(2, 50.0, start, end)])
    )

    assert summary.updated == [2] and summary.moved == [2]
    assert model.move_lines == {2: (start, end)}
    assert ("set_lines", MOVES_NODE) in sink.take()
    line = sink.nodes[MOVES_NODE]
    assert line["segments"].tolist() == [[list(start), list(end)]]
    assert [tuple(c) for c in line["colors"][0]] == [GHOST_RGB, MOVE_LINE_RGB]  # grey -> blue
    assert ghost_node(2) not in sink.nodes  # moved, not removed: no ghost


def test_a_move_without_places_is_drawn_between_the_centres_the_viewer_held(scene):
    model, _ = scene
    old_center = model.objects[2].center

    model.apply_delta(delta(2, [upsert(2, 2, "table", offset=3.0)], changes=[move(2, 50.0)]))

    assert model.move_lines == {2: (old_center, model.objects[2].center)}


def test_all_move_lines_are_one_node_and_a_moved_again_object_keeps_one_line(scene):
    model, sink = scene
    model.apply_delta(delta(2, [upsert(1, 2, offset=1.0)], changes=[move(1, 10.0)]))
    model.apply_delta(delta(3, [upsert(3, 2, offset=1.0)], changes=[move(3, 11.0)]))
    model.apply_delta(delta(4, [upsert(1, 3, offset=2.0)], changes=[move(1, 12.0)]))

    assert set(model.move_lines) == {1, 3}
    assert model.move_lines[1][1] == model.objects[1].center
    assert [name for name, node in sink.nodes.items() if node["kind"] == "lines"] == [MOVES_NODE]
    assert sink.nodes[MOVES_NODE]["segments"].shape == (2, 2, 3)


def test_move_lines_fade_as_ghosts_do(scene):
    model, sink = scene
    model.apply_delta(delta(2, [upsert(2, 2, "table", offset=3.0)], changes=[move(2, 0.0)]))

    model.apply_delta(delta(3, [upsert(1, 2, last_seen_t=GHOST_FADE_S / 4)]))

    colors = sink.nodes[MOVES_NODE]["colors"][0]
    quarter = [faded(GHOST_RGB, GHOST_FADE_S / 4), faded(MOVE_LINE_RGB, GHOST_FADE_S / 4)]
    assert [tuple(c) for c in colors] == quarter
    model.apply_delta(delta(4, [upsert(1, 3, last_seen_t=GHOST_FADE_S)]))
    assert model.move_lines == {} and MOVES_NODE not in sink.nodes


def test_only_the_newest_ghosts_are_kept():
    sink = RecordingSink()
    model = SceneModel(sink)
    n = MAX_GHOSTS + 8
    model.apply_delta(delta(1, [upsert(oid, 1) for oid in range(n)], full=True))

    model.apply_delta(delta(2, removed=range(20), changes=[removal(i, i) for i in range(20)]))
    model.apply_delta(delta(3, removed=range(20, n), changes=[removal(i, i) for i in range(20, n)]))

    assert sorted(model.ghosts) == list(range(n - MAX_GHOSTS, n))
    assert {name for name in sink.nodes if name.startswith("/ghosts/")} == {
        ghost_node(oid) for oid in range(n - MAX_GHOSTS, n)
    }


def test_an_object_back_in_the_map_loses_its_ghost(scene):
    model, sink = scene
    model.apply_delta(delta(2, removed=[3], changes=[removal(3, 100.0)]))

    model.apply_delta(delta(3, [upsert(3, 2)]))

    assert model.ghosts == {} and ghost_node(3) not in sink.nodes
    assert points_node(3) in sink.nodes


def test_a_full_snapshot_clears_the_ghosts_and_lines_that_no_longer_apply(scene):
    model, sink = scene
    model.apply_delta(
        delta(
            2, [upsert(2, 2, "table", offset=3.0)], [1, 3], changes=[removal(1, 5.0), move(2, 6.0)]
        )
    )
    model.apply_delta(delta(3, [upsert(3, 2)]))  # 3 came back after the removal
    assert set(model.ghosts) == {1} and set(model.move_lines) == {2}

    # a resync: 2 has gone since (no ghost: a snapshot carries no changes), 1 is still gone
    model.apply_delta(delta(9, [upsert(3, 2)], full=True))

    assert set(model.ghosts) == {1} and ghost_node(1) in sink.nodes
    assert model.move_lines == {} and MOVES_NODE not in sink.nodes
    assert ghost_node(2) not in sink.nodes


def test_a_ghost_of_an_object_the_viewer_never_held_is_not_drawn(scene):
    model, sink = scene
    summary = model.apply_delta(delta(2, removed=[77], changes=[removal(77, 1.0, "laptop")]))

    assert summary.ghosted == [] and ghost_node(77) not in sink.nodes


# --- relational answers ("the mug on the desk") ---------------------------------------------


def chair_next_to_the_table(target: int | None = 3) -> RelationHighlight:
    return RelationHighlight(target=target, anchors=(2,), words="next to the table")


def relation_nodes(sink: RecordingSink) -> list[str]:
    return sorted(n for n in sink.nodes if n.startswith(("/hits/relation", "/hits/anchors")))


def test_a_relational_answer_draws_target_and_anchor_in_two_colours_with_a_line_between(scene):
    model, sink = scene
    # "the chair next to the table": chair 3 answers, chair 1 does not; the table is no hit
    model.highlight([(3, 0.9), (1, 0.0)], chair_next_to_the_table())
    chair, table = model.objects[3], model.objects[2]

    boxes = sink.nodes[RELATION_BOXES_NODE]  # one node, the target's box then the anchor's
    assert np.allclose(boxes["segments"], box_segments(np.array([chair.bbox, table.bbox])))
    assert (boxes["colors"][:12] == TARGET_RGB).all() and (boxes["colors"][12:] == ANCHOR_RGB).all()
    line = sink.nodes[RELATION_LINES_NODE]
    assert line["kind"] == "lines"  # drawn bolder than box edges
    assert np.allclose(line["segments"], [[chair.center, table.center]])
    assert line["colors"].tolist() == [[list(TARGET_RGB), list(ANCHOR_RGB)]]
    assert sink.nodes[points_node(3)]["color"] == TARGET_RGB
    assert sink.nodes[points_node(2)]["color"] == ANCHOR_RGB  # the anchor stands out too
    assert sink.nodes[points_node(1)]["color"] == dimmed(object_color(1))
    assert sink.nodes[hit_label_node(3)]["text"] == "chair — next to the table"
    assert sink.nodes[hit_label_node(1)]["text"] == "chair 0.00"
    assert sink.nodes[anchor_label_node(2)] == {
        "kind": "label",
        "text": "table",
        "position": table.center,
    }
    assert sink.nodes[HIT_BOXES_NODE]["segments"].shape == (12, 2, 3)  # chair 1's box alone
    assert model.relation == chair_next_to_the_table()


def test_an_anchor_among_the_hits_is_labelled_once_as_the_anchor(scene):
    model, sink = scene
    model.highlight([(2, 0.6)])  # a plain answer labels the table as a hit
    model.highlight([(3, 0.9), (2, 0.1)], chair_next_to_the_table())
    assert hit_label_node(2) not in sink.nodes
    assert sink.nodes[anchor_label_node(2)]["text"] == "table"
    assert sink.nodes[points_node(2)]["color"] == ANCHOR_RGB


def test_between_draws_a_line_from_the_target_to_each_anchor(scene):
    model, sink = scene
    model.highlight([(2, 0.8)], RelationHighlight(2, (1, 3), "between the chair and the chair"))
    table = model.objects[2]
    line = sink.nodes[RELATION_LINES_NODE]
    assert np.allclose(
        line["segments"],
        [[table.center, model.objects[1].center], [table.center, model.objects[3].center]],
    )
    assert sink.nodes[RELATION_BOXES_NODE]["segments"].shape == (3 * 12, 2, 3)
    assert {anchor_label_node(1), anchor_label_node(3)} <= sink.nodes.keys()
    assert HIT_BOXES_NODE not in sink.nodes  # the only hit is the target, in the relation's node


def test_clearing_or_a_new_query_removes_the_target_anchors_and_line(scene):
    model, sink = scene
    plain = {name: dict(node) for name, node in sink.nodes.items()}
    model.highlight([(3, 0.9)], chair_next_to_the_table())
    model.highlight([(1, 0.7)])  # a plain question next
    assert relation_nodes(sink) == [] and model.relation is None
    assert sink.nodes[points_node(2)]["color"] == dimmed(object_color(2))
    assert sink.nodes[hit_label_node(1)]["text"] == "chair 0.70"

    model.highlight([(3, 0.9)], chair_next_to_the_table())
    model.clear_highlight()
    assert not [name for name in sink.nodes if name.startswith("/hits")]
    for oid in (1, 2, 3):
        assert sink.nodes[points_node(oid)]["color"] == plain[points_node(oid)]["color"]


def test_an_anchor_not_held_yet_is_drawn_when_it_arrives_and_goes_when_it_is_removed(scene):
    model, sink = scene
    model.highlight([(3, 0.9)], RelationHighlight(3, (9,), "on the desk"))
    assert RELATION_LINES_NODE not in sink.nodes  # nothing to draw the line to yet
    assert sink.nodes[RELATION_BOXES_NODE]["segments"].shape == (12, 2, 3)  # the target's box

    model.apply_delta(delta(2, [upsert(9, 1, "desk")]))
    assert sink.nodes[points_node(9)]["color"] == ANCHOR_RGB
    assert sink.nodes[anchor_label_node(9)]["text"] == "desk"
    assert np.allclose(
        sink.nodes[RELATION_LINES_NODE]["segments"],
        [[model.objects[3].center, model.objects[9].center]],
    )
    model.apply_delta(delta(3, [upsert(9, 2, "desk", offset=1.0)]))  # the desk moved
    assert np.allclose(sink.nodes[RELATION_LINES_NODE]["segments"][0, 1], model.objects[9].center)

    model.apply_delta(delta(4, removed=[9]))
    assert relation_nodes(sink) == [RELATION_BOXES_NODE]  # the target's box stays
    sink.take()
    model.apply_delta(delta(5, [upsert(1, 2)]))  # an object outside the answer: no redraw
    assert not [op for op in sink.take() if "relation" in op[1] or "anchors" in op[1]]


def test_without_a_confident_match_only_the_anchors_are_shown(scene):
    # "the chair under the table" when no chair is: the table is shown, no chair singled out
    model, sink = scene
    model.highlight([(3, 0.2)], chair_next_to_the_table(target=None))
    assert relation_nodes(sink) == [anchor_label_node(2), RELATION_BOXES_NODE]
    assert (sink.nodes[RELATION_BOXES_NODE]["colors"] == ANCHOR_RGB).all()
    assert sink.nodes[points_node(3)]["color"] == hit_color(object_color(3), 0.2)
    assert sink.nodes[hit_label_node(3)]["text"] == "chair 0.20"


@pytest.mark.parametrize(
    "kind, anchors, words",
    [
        ("on", ["desk"], "on the desk"),
        ("in", ["box"], "in the box"),
        ("under", ["table"], "under the table"),
        ("above", ["sofa"], "above the sofa"),
        ("below", ["shelf"], "below the shelf"),
        ("near", ["sofa"], "near the sofa"),
        ("next_to", ["sofa"], "next to the sofa"),
        ("between", ["chair", "sofa"], "between the chair and the sofa"),
        ("left_of", ["lamp"], "left of the lamp"),
        ("right_of", ["lamp"], "right of the lamp"),
        ("in_front_of", ["tv"], "in front of the tv"),
        ("behind", ["door"], "behind the door"),
        ("closest", [], "closest to you"),
        ("farthest", [], "farthest from you"),
        ("closest", ["window"], "closest to the window"),
        ("near", [], "near you"),
        ("left_of", [], "on your left"),
        ("biggest", [], "the biggest"),
        ("smallest", [], "the smallest"),
        ("highest", [], "the highest"),
        ("lowest", [], "the lowest"),
        ("beside", ["bed"], "beside the bed"),  # a kind a newer server may add
    ],
)
def test_a_relation_in_words(kind, anchors, words):
    assert relation_words(kind, anchors) == words


def test_a_relation_is_read_from_a_query_hit():
    hit = {
        "id": 10,
        "label": "mug",
        "relation": {"kind": "on", "anchors": [{"id": 1, "label": "desk"}], "degree": 0.93},
    }
    assert RelationHighlight.of_hit(hit) == RelationHighlight(10, (1,), "on the desk")
    assert RelationHighlight.of_hit(hit, matched=False) == RelationHighlight(
        None, (1,), "on the desk"
    )
    assert RelationHighlight.of_hit({"id": 10, "label": "mug", "relation": None}) is None
    assert RelationHighlight.of_hit({"id": 10, "label": "mug"}) is None  # an older server
