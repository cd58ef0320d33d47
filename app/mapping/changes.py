"""Change detection: what the keyframes say changed in the world (added, moved, removed).

Negative evidence (`app.mapping.living`) makes confirmed objects suspect when a keyframe
shows their place without them, and removes them, or finds them moved, once enough
keyframes agree; a new object is `added` when remembered keyframes had shown its place
empty (docs/architecture.md, the living map).
"""

from __future__ import annotations

REMEMBERED_VIEWS = 600
"""Keyframes remembered (coarse, ~3 KB each) to tell whether a new object's place was seen
empty before: ten minutes of keyframes at one a second."""
REMEMBERED_VIEW_BLOCK = 4
"""Remembered depth keeps the nearest surface of each 4 x 4 block of the uploaded depth."""
REVIVE_WINDOW_S = 120.0
"""A removed object is still found at a new place (moved, not removed) when a like thing
appears within this much device time of its removal: the mug taken from the table before
the shelf it went to came into view."""
RECENTLY_REMOVED = 256
"""Most removed objects kept in memory for REVIVE_WINDOW_S."""
PLACE_TAKEN_OVERLAP = 0.5
"""A new object is no `added` change when this much of it lies on another confirmed object
that is alike..."""
PLACE_TAKEN_BOX_IOU = 0.15
"""...or whose box it shares this much of (intersection over union)."""
VACATED_INSIDE = 0.5
"""An object leaving with most of its box in a place just vacated is a second reading of the
thing that left (`_second_reading_of_vacated`)."""
