"""Map updates -> scene-node operations, with no viser and no I/O (testable without a browser).

`SceneModel` applies v1 `delta` messages with the device's semantics (a `full` snapshot
replaces the map, upserts are keyed by id and ordered by version, removals drop ids) and
tells a `SceneSink` the fewest node operations that make the scene match: an object that did
not change causes none. `viewer.app` implements the sink on viser; tests record it.

Node names (stable per object, so an update replaces exactly its own nodes):

    /objects/{id}          the object's point cloud, one colour per object (or per class)
    /labels/{id}           its label, under the /labels group (toggled by one visibility op)
    /boxes                 every object's bounding box, batched into ONE line-segments node
    /hits/boxes            the boxes of the highlighted query hits, bright
    /hits/labels/{id}      a hit's label with its score
    /hits/relation/boxes   a relational answer's target box and its anchors' boxes, in two
                           colours (TARGET_RGB, ANCHOR_RGB), ONE line-segments node
    /hits/relation/lines   a line from the target's centre to each anchor's centre, ONE node
    /hits/anchors/{id}     an anchor's label (anchors need not be among the hits)
    /ghosts/{id}           a removed object's last points, grey, fading (the living map)
    /labels/ghosts/{id}    its label, "(removed)"
    /moves                 a line from old to new place per moved object, ONE node

The cloud is the object's node itself, not a child like /objects/{id}/points: viser would
create an implicit frame node for every /objects/{id} parent, which costs a fifth of a
5,000-object snapshot's time for nothing. Labels live in their own group for the same
reason and so that hiding them all is one operation.

While a query is highlighted the other objects are dimmed (points and boxes) and the plain
labels are hidden, so the hits stand out.

A relational answer ("the mug on the desk") also shows what it is measured
against: the target (the top hit) and its anchors are drawn in two colours of their own,
points and boxes, with a line from the target's centre to each anchor's; the target's label
says the relation in words ("mug — on the desk"). Anchors are drawn from the objects the
viewer holds (an anchor not held yet is drawn when it arrives). Without a confident match
there is no target: only the anchors are shown, so "the mug under the sofa" points at the
sofa but at no mug. Clearing the highlight, or the next one, removes it all.

Changes (the delta's optional `changes`, the living map): a "removed" change leaves a ghost
of the object where it was, drawn from the points the viewer held before the removal; a
"moved" change draws a line from its old place to its new one. Both fade towards the
background over GHOST_FADE_S seconds of device time (the newest `t` the viewer has seen, from
changes and `last_seen_t`), then go; at most MAX_GHOSTS and MAX_MOVE_LINES, the newest, are
kept. A ghost goes when its id is back in the map, a move line when its object is gone, so a
full snapshot (which never carries changes) clears what no longer applies.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from app.protocol import ChangeEntry, DeltaError, parse_delta
from viewer.palette import (
    ANCHOR_RGB,
    GHOST_FADE_S,
    GHOST_RGB,
    MOVE_LINE_RGB,
    TARGET_RGB,
    Rgb,
    class_color,
    dimmed,
    faded,
    hit_box_color,
    hit_color,
    object_color,
)
from viewer.shapes import box_segments, segment_colors
from viewer.words import relation_words

OBJECTS_GROUP = "/objects"
LABELS_GROUP = "/labels"
BOXES_NODE = "/boxes"
HITS_GROUP = "/hits"
HIT_BOXES_NODE = "/hits/boxes"
RELATION_BOXES_NODE = "/hits/relation/boxes"
RELATION_LINES_NODE = "/hits/relation/lines"
ANCHORS_GROUP = "/hits/anchors"
GHOSTS_GROUP = "/ghosts"
MOVES_NODE = "/moves"

MAX_GHOSTS = 32
"""Ghosts kept at most (the newest); one delta carries at most 32 changes."""
MAX_MOVE_LINES = 32
"""Move lines kept at most (the newest)."""


def points_node(object_id: int) -> str:
    """Scene name of an object's point cloud."""
    return f"{OBJECTS_GROUP}/{object_id}"


def label_node(object_id: int) -> str:
    """Scene name of an object's plain label."""
    return f"{LABELS_GROUP}/{object_id}"


def hit_label_node(object_id: int) -> str:
    """Scene name of a highlighted hit's label (with its score)."""
    return f"{HITS_GROUP}/labels/{object_id}"


def anchor_label_node(object_id: int) -> str:
    """Scene name of a relational answer's anchor's label."""
    return f"{ANCHORS_GROUP}/{object_id}"


def ghost_node(object_id: int) -> str:
    """Scene name of a removed object's ghost (its last points)."""
    return f"{GHOSTS_GROUP}/{object_id}"


def ghost_label_node(object_id: int) -> str:
    """Scene name of a ghost's label (under /labels: hidden with the other labels)."""
    return f"{LABELS_GROUP}/ghosts/{object_id}"


class SceneSink(Protocol):
    """Where scene-node operations go (viser in the app, a recorder in tests).

    `add_*` and `set_boxes` create the node or replace it whole; the others change one
    property of an existing node.
    """

    def add_point_cloud(self, name: str, points: np.ndarray, color: Rgb) -> None:
        """points: float16 or float32 [N, 3] metres; one colour for all of them."""

    def set_point_color(self, name: str, color: Rgb) -> None:
        """Recolour an existing point cloud (its points are not sent again)."""

    def add_label(self, name: str, text: str, position: tuple[float, float, float]) -> None:
        """A text label anchored at `position` (metres)."""

    def set_boxes(self, name: str, segments: np.ndarray, colors: np.ndarray) -> None:
        """One line-segments node: segments float32 [M, 2, 3] metres, colors uint8 [M, 2, 3]."""

    def set_lines(self, name: str, segments: np.ndarray, colors: np.ndarray) -> None:
        """As `set_boxes`, for lines that are not box edges (drawn bolder): move lines."""

    def set_visible(self, name: str, visible: bool) -> None:
        """Show or hide a node and its children (used for groups)."""

    def remove(self, name: str) -> None:
        """Remove a node and its children."""


@dataclass(frozen=True)
class ViewObject:
    """One confirmed object as the viewer holds it (client resolution, wire precision)."""

    id: int
    version: int
    label: str
    bbox: tuple[float, float, float, float, float, float]
    """[x0, y0, z0, x1, y1, z1] metres."""
    points: np.ndarray = field(repr=False)
    """float16 [N, 3] metres, as received."""
    n_obs: int

    @property
    def center(self) -> tuple[float, float, float]:
        x0, y0, z0, x1, y1, z1 = self.bbox
        return ((x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2)


@dataclass
class DeltaSummary:
    """What one `apply_delta` changed, by object id."""

    seq: int
    full: bool
    added: list[int] = field(default_factory=list)
    updated: list[int] = field(default_factory=list)
    removed: list[int] = field(default_factory=list)
    unchanged: list[int] = field(default_factory=list)
    """Upserts whose version the viewer already held (or newer): no node operation."""
    ghosted: list[int] = field(default_factory=list)
    """Removed objects this delta left a ghost of (a "removed" change for a held object)."""
    moved: list[int] = field(default_factory=list)
    """Objects this delta drew a move line for (a "moved" change)."""

    @property
    def changed(self) -> bool:
        return bool(self.added or self.updated or self.removed)


@dataclass(frozen=True)
class RelationHighlight:
    """A relational answer as the viewer draws it: the thing asked about and what it is
    measured against."""

    target: int | None
    """The top hit's id; None when the answer is no confident match (only anchors shown)."""
    anchors: tuple[int, ...]
    """The anchors' ids: two for `between`, none for the asker or a superlative."""
    words: str
    """The relation in words (`relation_words`): "on the desk"."""

    @classmethod
    def of_hit(cls, hit: Mapping, matched: bool = True) -> RelationHighlight | None:
        """From a query answer's hit (a dict as the protocol has it); None for a plain hit.
        matched: whether the answer is a confident match (else the hit is not the target)."""
        relation = hit.get("relation")
        if not isinstance(relation, Mapping):
            return None
        anchors = relation.get("anchors") or []
        return cls(
            target=int(hit["id"]) if matched else None,
            anchors=tuple(int(a["id"]) for a in anchors),
            words=relation_words(str(relation.get("kind")), [str(a["label"]) for a in anchors]),
        )

    @property
    def ids(self) -> set[int]:
        """The target's and the anchors' ids."""
        return set(self.anchors) | ({self.target} if self.target is not None else set())


# --- the model ------------------------------------------------------------------------------

Xyz = tuple[float, float, float]


@dataclass
class _Ghost:
    """A removed object as last held, drawn grey where it was."""

    t: float
    """Device time of the removal (the change's `t`)."""
    label: str
    points: np.ndarray = field(repr=False)
    center: Xyz
    color: Rgb | None = None
    """The colour its node has now (None: not drawn yet)."""


@dataclass(frozen=True)
class _MoveLine:
    t: float
    """Device time of the move (the change's `t`)."""
    start: Xyz
    """The old place (the change's `from`, else the centre the viewer held)."""
    end: Xyz
    """The new place."""


class SceneModel:
    """The viewer's copy of a session's confirmed map and the scene nodes that draw it.

    Not thread-safe: the caller serialises `apply_delta`, the toggles and highlighting.
    On construction it tells the sink the initial visibility of the /labels group.
    """

    def __init__(
        self,
        sink: SceneSink,
        *,
        color_by_class: bool = False,
        show_boxes: bool = True,
        show_labels: bool = True,
    ):
        self.sink = sink
        self.seq = 0
        """Seq of the last applied delta (what `?since=` resumes from)."""
        self._objects: dict[int, ViewObject] = {}
        self._color_by_class = color_by_class
        self._show_boxes = show_boxes
        self._show_labels = show_labels
        self._hits: dict[int, float] = {}
        """Highlighted query hits: id -> score; hits not (yet) held are shown when they arrive."""
        self._highlighting = False
        self._point_colors: dict[int, Rgb] = {}  # the colour each points node has now
        self._hit_labels: dict[int, tuple[str, tuple[float, float, float]]] = {}
        """(text, position) each hit label node has now."""
        self._boxes_shown = False  # whether /boxes exists in the scene
        self._hit_boxes_shown = False
        self._relation: RelationHighlight | None = None
        """The highlighted relational answer (None: a plain answer or no highlight)."""
        self._relation_nodes: set[str] = set()  # /hits/relation/* nodes in the scene now
        self._anchor_labels: dict[int, tuple[str, tuple[float, float, float]]] = {}
        """(text, position) each anchor label node has now."""
        self._device_t: float | None = None
        """The newest device time seen (changes' `t`, upserts' `last_seen_t`): fading's clock."""
        self._ghosts: dict[int, _Ghost] = {}
        self._move_lines: dict[int, _MoveLine] = {}
        self._move_lines_drawn: tuple = ()  # what /moves shows now (empty: no node)
        self._labels_visible = self._labels_group_visible()
        sink.set_visible(LABELS_GROUP, self._labels_visible)

    # --- reading ----------------------------------------------------------------------------

    @property
    def objects(self) -> Mapping[int, ViewObject]:
        return self._objects

    @property
    def hits(self) -> Mapping[int, float]:
        """The highlighted hits (id -> relevance); empty when nothing is highlighted."""
        return dict(self._hits)

    @property
    def highlighting(self) -> bool:
        return self._highlighting

    @property
    def relation(self) -> RelationHighlight | None:
        """The highlighted relational answer; None for a plain one or no highlight."""
        return self._relation

    @property
    def ghosts(self) -> Mapping[int, float]:
        """Removed objects shown as ghosts: id -> device time of the removal."""
        return {oid: ghost.t for oid, ghost in self._ghosts.items()}

    @property
    def move_lines(self) -> Mapping[int, tuple[Xyz, Xyz]]:
        """Moved objects shown with a line: id -> (old place, new place)."""
        return {oid: (line.start, line.end) for oid, line in self._move_lines.items()}

    @property
    def device_t(self) -> float | None:
        """The newest device time the viewer has seen (None: no living-map field yet)."""
        return self._device_t

    @property
    def color_by_class(self) -> bool:
        return self._color_by_class

    def bounds(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(min, max) corners of all boxes, metres; None when the map is empty."""
        if not self._objects:
            return None
        boxes = np.array([o.bbox for o in self._objects.values()], np.float64)
        return boxes[:, :3].min(axis=0), boxes[:, 3:].max(axis=0)

    # --- updates ----------------------------------------------------------------------------

    def apply_delta(self, message: dict) -> DeltaSummary:
        """Apply one v1 `delta` (msgpack-unpacked, bytes fields) and update the scene.

        Validates first: a malformed delta, or a non-full one older than `seq`, raises
        DeltaError and changes nothing. Upserts at a version the viewer already holds (or
        older) cause no node operation, so a resync snapshot only redraws what changed.
        """
        delta = parse_delta(message)  # the embedding is decoded (validated), not drawn
        seq, full, removed = delta.seq, delta.full, delta.removed
        if not full and seq < self.seq:
            raise DeltaError(
                "seq", f"{seq} is older than the applied seq {self.seq} (out of order)"
            )
        upserts = [
            ViewObject(u.id, u.version, u.label, u.bbox, u.points, u.n_obs) for u in delta.upserts
        ]
        summary = DeltaSummary(seq=seq, full=full)
        if full:
            fresh = {o.id for o in upserts}
            removed = [oid for oid in self._objects if oid not in fresh]
        before = {  # where moved objects were, for a change that does not say
            c.id: self._objects[c.id].center
            for c in delta.changes
            if c.kind == "moved" and c.id in self._objects
        }
        gone: dict[int, ViewObject] = {}  # what removed objects looked like, for their ghosts
        boxes_changed = False  # /boxes is one node: resend it only when a box looks different
        hits_changed = False
        members = self._relation.ids if self._relation is not None else set()
        relation_changed = False  # the target or an anchor came, went or changed
        for oid in removed:
            held = self._objects.pop(oid, None)
            if held is not None:
                gone[oid] = held
                self._drop_nodes(oid)
                summary.removed.append(oid)
                boxes_changed = True
                hits_changed |= oid in self._hits
                relation_changed |= oid in members
        for obj in upserts:
            held = self._objects.get(obj.id)
            if held is not None and obj.version <= held.version:
                summary.unchanged.append(obj.id)
                continue
            self._objects[obj.id] = obj
            self._draw_object(obj, held)
            (summary.updated if held is not None else summary.added).append(obj.id)
            looks_different = (
                held is None or held.bbox != obj.bbox or self._color_of(held) != self._color_of(obj)
            )
            boxes_changed |= looks_different
            hits_changed |= looks_different and obj.id in self._hits
            relation_changed |= obj.id in members
        self.seq = seq
        if boxes_changed or hits_changed:
            self._redraw_boxes(all_boxes=boxes_changed, hits=hits_changed)
        if relation_changed:
            self._redraw_relation()
        seen_t = [u.last_seen_t for u in delta.upserts if u.last_seen_t is not None]
        self._note_changes(delta.changes, gone, before, summary)
        self._advance_device_t([c.t for c in delta.changes] + seen_t)
        self._redraw_changes()
        return summary

    def _draw_object(self, obj: ViewObject, held: ViewObject | None) -> None:
        """The point and label nodes of a new or changed object (only the parts that changed)."""
        color = self._color_of(obj)
        if held is None or not np.array_equal(held.points, obj.points):
            if len(obj.points):
                self.sink.add_point_cloud(points_node(obj.id), obj.points, color)
                self._point_colors[obj.id] = color
            elif obj.id in self._point_colors:  # nothing to draw any more
                self.sink.remove(points_node(obj.id))
                del self._point_colors[obj.id]
        elif obj.id in self._point_colors and self._point_colors[obj.id] != color:
            self.sink.set_point_color(points_node(obj.id), color)  # its class changed
            self._point_colors[obj.id] = color
        if held is None or held.label != obj.label or held.center != obj.center:
            self.sink.add_label(label_node(obj.id), obj.label, obj.center)
        if obj.id in self._hits:
            self._draw_hit_label(obj)

    def _note_changes(
        self,
        changes: list[ChangeEntry],
        gone: Mapping[int, ViewObject],
        before: Mapping[int, Xyz],
        summary: DeltaSummary,
    ) -> None:
        """Ghosts and move lines of a delta's changes, oldest first (drawn by the caller)."""
        for change in changes:
            if change.kind == "removed" and change.id in gone:
                obj = gone[change.id]
                self._ghosts.pop(change.id, None)  # re-inserted: the newest come last
                self._ghosts[change.id] = _Ghost(change.t, obj.label, obj.points, obj.center)
                summary.ghosted.append(change.id)
            elif change.kind == "moved":
                start = change.from_xyz or before.get(change.id)
                held = self._objects.get(change.id)
                end = change.to_xyz or (held.center if held is not None else None)
                if start is not None and end is not None:
                    self._move_lines.pop(change.id, None)
                    self._move_lines[change.id] = _MoveLine(change.t, start, end)
                    summary.moved.append(change.id)

    def _advance_device_t(self, times: list[float]) -> None:
        """The fading clock only moves forward (a `t` that goes backwards leaves it)."""
        if times:
            newest = max(times)
            if self._device_t is None or newest > self._device_t:
                self._device_t = newest

    def _age_s(self, t: float) -> float:
        return 0.0 if self._device_t is None else max(self._device_t - t, 0.0)

    def _redraw_changes(self) -> None:
        """Bring ghosts and move lines up to date: drop those faded out, over their cap, or
        no longer true (a ghost whose id is back, a line whose object is gone); recolour
        the rest as they fade (only when a colour changes)."""
        keep = self._still_shown(self._ghosts, present=False, most=MAX_GHOSTS)
        for oid in [oid for oid in self._ghosts if oid not in keep]:
            self._drop_ghost(oid)
        for oid, ghost in self._ghosts.items():
            color = faded(GHOST_RGB, self._age_s(ghost.t))
            if ghost.color is None:
                if len(ghost.points):
                    self.sink.add_point_cloud(ghost_node(oid), ghost.points, color)
                self.sink.add_label(ghost_label_node(oid), f"{ghost.label} (removed)", ghost.center)
            elif color != ghost.color and len(ghost.points):
                self.sink.set_point_color(ghost_node(oid), color)
            ghost.color = color

        keep = self._still_shown(self._move_lines, present=True, most=MAX_MOVE_LINES)
        self._move_lines = {oid: line for oid, line in self._move_lines.items() if oid in keep}
        drawn = tuple(  # per line: both ends, the old one grey, the new one blue
            (line.start, line.end, faded(GHOST_RGB, age), faded(MOVE_LINE_RGB, age))
            for line in self._move_lines.values()
            for age in [self._age_s(line.t)]
        )
        if drawn == self._move_lines_drawn:
            return
        if drawn:
            self.sink.set_lines(
                MOVES_NODE,
                np.array([(start, end) for start, end, _, _ in drawn], np.float32),
                np.array([(old, new) for _, _, old, new in drawn], np.uint8),
            )
        else:
            self.sink.remove(MOVES_NODE)
        self._move_lines_drawn = drawn

    def _still_shown(
        self, shown: Mapping[int, _Ghost | _MoveLine], present: bool, most: int
    ) -> set[int]:
        """Ids of `shown` to keep: whose object is (present=True) or is not in the map, not
        faded out, the newest `most` of them (by `t`; ties: the later noted)."""
        live = [oid for oid in shown if (oid in self._objects) == present]
        newest = sorted(live, key=lambda oid: shown[oid].t)[max(len(live) - most, 0) :]
        return {oid for oid in newest if self._age_s(shown[oid].t) < GHOST_FADE_S}

    def _drop_ghost(self, oid: int) -> None:
        ghost = self._ghosts.pop(oid)
        if ghost.color is not None:
            if len(ghost.points):
                self.sink.remove(ghost_node(oid))
            self.sink.remove(ghost_label_node(oid))

    def _drop_nodes(self, oid: int) -> None:
        if self._point_colors.pop(oid, None) is not None:
            self.sink.remove(points_node(oid))
        self.sink.remove(label_node(oid))
        if self._hit_labels.pop(oid, None) is not None:
            self.sink.remove(hit_label_node(oid))

    # --- toggles ----------------------------------------------------------------------------

    def set_color_by_class(self, by_class: bool) -> None:
        """Colour objects by class label (True) or by object id (False)."""
        if by_class != self._color_by_class:
            self._color_by_class = by_class
            self._recolor()
            self._redraw_boxes(all_boxes=True, hits=False)

    def set_show_boxes(self, show: bool) -> None:
        """Show or hide the batched /boxes node (highlighted hits keep their boxes)."""
        if show != self._show_boxes:
            self._show_boxes = show
            self._redraw_boxes(all_boxes=True, hits=False)

    def set_show_labels(self, show: bool) -> None:
        """Show or hide every plain label at once (one group visibility operation)."""
        if show != self._show_labels:
            self._show_labels = show
            self._update_labels_group()

    # --- query highlighting -----------------------------------------------------------------

    def highlight(
        self, hits: Iterable[tuple[int, float]], relation: RelationHighlight | None = None
    ) -> None:
        """Highlight query hits (id, relevance in [0, 1]), best first: boxes and colours as
        bright as their relevance (a 0.3 hit stays near the dimmed rest, a 0.8 one stands
        out), labels with the relevance; everything else dimmed. Replaces any earlier
        highlight.

        relation: a relational answer's target and anchors, drawn in TARGET_RGB and
        ANCHOR_RGB with a line between their centres (see the module docstring)."""
        new_hits = {int(oid): float(relevance) for oid, relevance in hits}
        for oid in [o for o in self._hit_labels if o not in new_hits]:
            self.sink.remove(hit_label_node(oid))
            del self._hit_labels[oid]
        self._hits = new_hits
        self._relation = relation
        self._highlighting = True
        for oid in new_hits:
            if oid in self._objects:
                self._draw_hit_label(self._objects[oid])
        self._recolor()
        self._update_labels_group()
        self._redraw_boxes(all_boxes=True, hits=True)
        self._redraw_relation()

    def clear_highlight(self) -> None:
        """Back to the plain view: hit nodes removed, colours and labels restored."""
        if not self._highlighting:
            return
        for oid in list(self._hit_labels):
            self.sink.remove(hit_label_node(oid))
        self._hit_labels.clear()
        self._hits = {}
        self._relation = None
        self._highlighting = False
        self._recolor()
        self._update_labels_group()
        self._redraw_boxes(all_boxes=True, hits=True)
        self._redraw_relation()

    # --- internals --------------------------------------------------------------------------

    def _base_color(self, obj: ViewObject) -> Rgb:
        return class_color(obj.label) if self._color_by_class else object_color(obj.id)

    def _color_of(self, obj: ViewObject) -> Rgb:
        color = self._base_color(obj)
        if not self._highlighting:
            return color
        if self._relation is not None and obj.id == self._relation.target:
            return TARGET_RGB
        if self._relation is not None and obj.id in self._relation.anchors:
            return ANCHOR_RGB
        if obj.id in self._hits:
            return hit_color(color, self._hits[obj.id])
        return dimmed(color)

    def _recolor(self) -> None:
        """Recolour the point clouds whose colour changed (the caller redraws the boxes)."""
        for oid, current in list(self._point_colors.items()):
            color = self._color_of(self._objects[oid])
            if color != current:
                self.sink.set_point_color(points_node(oid), color)
                self._point_colors[oid] = color

    def _draw_hit_label(self, obj: ViewObject) -> None:
        """A hit's label with its relevance, the target's with its relation in words, none
        for an anchor (its anchor label says it) (sent only if its text or place changed)."""
        if self._relation is not None and obj.id in self._relation.anchors:
            if self._hit_labels.pop(obj.id, None) is not None:
                self.sink.remove(hit_label_node(obj.id))
            return
        if self._relation is not None and obj.id == self._relation.target:
            drawn = (f"{obj.label} — {self._relation.words}", obj.center)
        else:
            drawn = (f"{obj.label} {self._hits[obj.id]:.2f}", obj.center)
        if self._hit_labels.get(obj.id) != drawn:
            self.sink.add_label(hit_label_node(obj.id), *drawn)
            self._hit_labels[obj.id] = drawn

    def _labels_group_visible(self) -> bool:
        return self._show_labels and not self._highlighting

    def _update_labels_group(self) -> None:
        visible = self._labels_group_visible()
        if visible != self._labels_visible:
            self.sink.set_visible(LABELS_GROUP, visible)
            self._labels_visible = visible

    def _redraw_boxes(self, all_boxes: bool = True, hits: bool = True) -> None:
        """Send /boxes (every object, one node) and /hits/boxes (the held hits), or remove
        them when there is nothing to show."""
        if all_boxes:
            shown = list(self._objects.values()) if self._show_boxes else []
            if shown:
                self.sink.set_boxes(
                    BOXES_NODE,
                    box_segments(np.array([o.bbox for o in shown], np.float32)),
                    segment_colors([self._color_of(o) for o in shown]),
                )
                self._boxes_shown = True
            elif self._boxes_shown:
                self.sink.remove(BOXES_NODE)
                self._boxes_shown = False
        if hits:  # the target's and anchors' boxes are /hits/relation/boxes
            members = self._relation.ids if self._relation is not None else set()
            held_hits = [
                self._objects[oid]
                for oid in self._hits
                if oid in self._objects and oid not in members
            ]
            if held_hits:
                self.sink.set_boxes(
                    HIT_BOXES_NODE,
                    box_segments(np.array([o.bbox for o in held_hits], np.float32)),
                    segment_colors([hit_box_color(self._hits[o.id]) for o in held_hits]),
                )
                self._hit_boxes_shown = True
            elif self._hit_boxes_shown:
                self.sink.remove(HIT_BOXES_NODE)
                self._hit_boxes_shown = False

    def _redraw_relation(self) -> None:
        """Bring the relational answer's nodes up to date with the held objects: the target's
        and the anchors' boxes (one node), a line from the target's centre to each held
        anchor's (one node), the anchors' labels; removed when there is nothing to show."""
        relation, held = self._relation, self._objects
        target = held.get(relation.target) if relation and relation.target is not None else None
        anchors = [held[a] for a in relation.anchors if a in held] if relation else []
        anchors = [a for a in anchors if target is None or a.id != target.id]
        wanted: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        framed = [(target, TARGET_RGB)] if target is not None else []
        framed += [(anchor, ANCHOR_RGB) for anchor in anchors]
        if framed:
            wanted[RELATION_BOXES_NODE] = (
                box_segments(np.array([o.bbox for o, _ in framed], np.float32)),
                segment_colors([color for _, color in framed]),
            )
        if target is not None and anchors:
            wanted[RELATION_LINES_NODE] = (
                np.array([(target.center, a.center) for a in anchors], np.float32),
                np.array([(TARGET_RGB, ANCHOR_RGB)] * len(anchors), np.uint8),
            )
        for name in sorted(self._relation_nodes - wanted.keys()):
            self.sink.remove(name)
        for name, (segments, colors) in wanted.items():
            draw = self.sink.set_boxes if name == RELATION_BOXES_NODE else self.sink.set_lines
            draw(name, segments, colors)
        self._relation_nodes = set(wanted)

        labels = {a.id: (a.label, a.center) for a in anchors}
        for oid in [o for o in self._anchor_labels if o not in labels]:
            self.sink.remove(anchor_label_node(oid))
            del self._anchor_labels[oid]
        for oid, drawn in labels.items():
            if self._anchor_labels.get(oid) != drawn:
                self.sink.add_label(anchor_label_node(oid), *drawn)
                self._anchor_labels[oid] = drawn
