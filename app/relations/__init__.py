"""How things stand to each other, from their points: "the mug on the desk".

Arrays in, arrays out: the server and the device's local map both import this package, so it
depends only on numpy and scipy and on what deltas carry (per object: label and capped points
[N, 3]). Every relation is a degree in [0, 1], smooth where sensible and exactly 0 beyond its
thresholds, so a box prefilter never changes an answer. Answering a question with them is
app.answering's.

- `grammar`: reads a question (target, relation clauses, anchors, superlative); no numpy.
- `thresholds`: every limit of every relation, one frozen record (`THRESHOLDS`).
- `bodies`: one object's points prepared for an up axis (`Body`, its `Footprint`), boxes in
  the up frame, the closest-points distance.
- `pairwise`: on, in, under, above, below, near, next_to (and on the implicit floor);
  `pair_degrees` of two bodies at once; `within_reach`, the box prefilter.
- `between`, `viewpoint` (left_of, right_of, in_front_of, behind from the asker's position),
  `superlatives` (closest / farthest, biggest, smallest, highest, lowest): from centroids or
  one number per thing, over many things at once (`*_degrees`).
- `source`: what a question reads of a map's geometry (`RelationSource`), the floor's height.
- `index`: `RelationIndex`, kept as objects change (the server), `sync`ed by object version;
  `on_demand`: `OnDemandRelations`, measured when asked (the device's local map). Both give
  the same degrees.
"""
