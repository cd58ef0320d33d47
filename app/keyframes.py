"""Keyframe selection: which frames of a stream the server maps.

One function for everyone who must agree on it: the server, for a device that sends every
frame whole (it counts the frames it receives); the device, which with the sightings
extension (`app.protocol.sighting`) picks its keyframes itself and sends only those whole;
and the evaluation driver, which maps the same keyframes in both organisations. Today a fixed
interval (the `keyframe_interval` knob); a selector by motion would take the pose here.
"""

from __future__ import annotations


def is_keyframe(index: int, interval: int) -> bool:
    """Whether frame `index` (0-based, in the order the stream's frames are sent) is a
    keyframe: the first frame and every `interval`-th one after it."""
    return index % interval == 0
