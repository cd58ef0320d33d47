"""The thresholds of every relation, in one frozen record (metres, shares in [0, 1], degrees).

Every relation is a degree in [0, 1], smooth where sensible and exactly 0 beyond these
limits, so a box prefilter never changes an answer. The relation functions read the one
record `THRESHOLDS`; a field's docstring says what it bounds, and the fields of one relation
read in order (a "..." continues the one before).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Thresholds:
    """The limits of the relations' degrees (see the module docstring)."""

    # near / next to
    near_full_m: float = 0.2
    """Closest points at most this far apart: near with degree 1..."""
    near_max_m: float = 0.8
    """...falling smoothly to 0 here (0.5 at 0.5 m: "within ~0.5 m")."""
    next_to_min_overlap: float = 0.1
    """Next to: the height ranges overlap by at least this share of the shorter one's height..."""
    next_to_full_overlap: float = 0.5
    """...for degree 1 at this share (side by side at a similar height)."""
    stacked_min_share: float = 0.3
    """Next to fades once this share of one object's points lies over the other's footprint..."""
    stacked_full_share: float = 0.7
    """...and is 0 from this share (stacked or inside, not side by side)."""

    # on / above / below / under
    footprint_margin_m: float = 0.05
    """A footprint (`Footprint`: the polygon around a thing seen from above) is taken this much
    wider when asking whether a thing stands over it (noisy edges), this much narrower when
    asking whether it is covered."""
    support_margin_m: float = 0.15
    """Where a thing stands, its support's points are looked for this far around its footprint:
    the surface right under it is hidden by the thing itself, and a capped large object's
    points are ~10 cm apart."""
    height_quantile: float = 0.02
    """An object's bottom and top are its points' heights at this quantile from each end (a few
    stray points do not lift or sink it)."""
    on_slack_m: float = 0.03
    """The support's surface may stand this much above a thing's bottom (noisy points, a bag
    sunk into a cushion)."""
    on_full_gap_m: float = 0.03
    """On: the bottom at most this far above the support's surface under it, degree 1..."""
    on_max_gap_m: float = 0.10
    """...falling to 0 here ("within a few cm"); `above` takes over from the same gap."""
    on_min_share: float = 0.3
    """On / above: at least this share of the thing's points over the support's footprint..."""
    on_full_share: float = 0.7
    """...for degree 1 at this share ("most of its footprint over it")."""
    on_min_rise_m: float = 0.02
    """On / above: a thing's bottom must stand more than this above the support's bottom (things
    on one floor stand beside each other: a bag under a table by its feet, a ball in a box)..."""
    on_full_rise_m: float = 0.04
    """...for degree 1 from this (a mug on a book lying flat)."""
    cover_clearance_m: float = 0.02
    """Under: what lies more than this above a thing's top covers it..."""
    cover_min_points: int = 2
    """...when at least this many of its points are right over the thing."""
    vertical_full_gap_m: float = 1.0
    """Above / below / under: a vertical gap up to this keeps degree 1..."""
    vertical_max_gap_m: float = 2.0
    """...falling to 0 here (a lamp hanging over a table is above it; one on the ceiling of the
    floor below is not)."""
    under_min_share: float = 0.3
    """Under: at least this share of the smaller footprint covered by the thing above..."""
    under_full_share: float = 0.7
    """...for degree 1 at this share."""

    # in
    in_slack_m: float = 0.02
    """In: a point counts inside a container up to this far below its bottom or above its top."""
    in_min_share: float = 0.3
    """In: at least this share of the thing's points inside the container's extent (its
    footprint times its height range)..."""
    in_full_share: float = 0.7
    """...for degree 1 at this share ("mostly inside")."""
    in_floor_m: float = 0.03
    """The container's walls are its points from this above the thing's bottom (what it stands
    on is a floor, not a wall)..."""
    in_rim_m: float = 0.05
    """...to this below the container's top (a table's top and its edge are a lid, not a
    wall)..."""
    in_edge_share: float = 0.25
    """...each at most this share of the thing's (floor) or the container's (rim) height: an
    apple in a bowl."""
    in_wall_patch_m: float = 0.2
    """Each wall point stands for a patch this wide (a capped object's points are up to ~20 cm
    apart), covering the arc it spans seen from the thing's centre..."""
    in_min_enclosure: float = 0.25
    """...and the walls must enclose at least this share of the full turn (a table's 4 legs seen
    from under its middle: ~0.15; a bookcase's sides and back: ~0.75; a box: 1)..."""
    in_full_enclosure: float = 0.5
    """...for degree 1 at this share..."""
    in_full_opening_deg: float = 90.0
    """...with no opening wider than this (a bookcase's front) for degree 1..."""
    in_max_opening_deg: float = 180.0
    """...and 0 with one this wide (a sofa's back alone walls in half the turn)."""

    # between
    between_lateral_m: float = 0.3
    """Between: the thing's centre within this of the line joining the two anchors' centres..."""
    between_lateral_share: float = 0.25
    """...or within this share of the anchors' distance, whichever is wider, for degree 1; 0 at
    twice that."""
    between_clear_m: float = 0.05
    """Between: the thing's centre at least this far outside either anchor's footprint for degree
    1, 0 over it."""
    between_end_share: float = 0.15
    """Between: along the line, degree 1 from this share of the way from either anchor; 0 at
    the anchors' centres."""

    # viewpoint
    left_right_full_deg: float = 10.0
    """Left / right of: degree 1 once the bearings, seen from the viewer, differ by this; 0 at
    the same bearing."""
    front_full_m: float = 0.3
    """In front of / behind: degree 1 once the depths along the view direction differ by this..."""
    front_lateral_full_m: float = 0.5
    """...with the thing within this of the line of sight to the anchor (degree 1)..."""
    front_lateral_max_m: float = 1.5
    """...and 0 from here."""

    # superlatives
    distance_scale_m: float = 0.5
    """Closest / farthest: a candidate this much farther (nearer) than the winner has degree
    1/e."""
    height_scale_m: float = 0.3
    """Highest / lowest: a candidate's centre this much lower (higher) than the winner's has
    degree 1/e."""

    # how finely (the cost, not the meaning)
    footprint_directions: int = 16
    """A footprint is the points' extents in this many directions seen from above (see
    `Footprint`)."""
    dense_distance_pairs: int = 12_000
    """Closest points by a dense distance matrix up to this many point pairs, a KD-tree beyond."""


THRESHOLDS = Thresholds()
"""The thresholds every relation function reads."""
