"""A session's lane of the keyframe pipeline: the map lock, the keyframe waiting for the
session's turn of a mapping worker, and whether one is on its way.

Each session has one lane (`Session.lane`); the pipeline (`pipeline.py`) moves keyframes
along it, one at a time, and the session's readers of the map take its lock, so they see
whole keyframes.
"""

from __future__ import annotations

import threading
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field

from app.perception.base import FrameDetections
from app.protocol import FrameInput

Reply = Callable[[dict], Awaitable[None]]
"""Sends one reply (an ack or an error) to the device that sent a frame."""


@dataclass
class PendingKeyframe:
    frame: FrameInput
    sent: FrameDetections | None
    """The detections the device sent, as validated (the backend's `sent`)."""
    reply: Reply
    received_t: float
    decode_ms: float
    """Time the frame took to decode and validate (part of its mapping latency)."""
    stream: str | None = None
    """The socket's stream id: a keyframe committed under (session, stream, seq) is acked
    from the store, not mapped again, when it is sent again (a gateway resending after a
    shard failure)."""


@dataclass
class KeyframeLane:
    lock: threading.Lock = field(default_factory=threading.Lock)
    """The map lock: a keyframe maps and commits in one hold of it; readers of the map
    (queries, object lists, deltas, exports, counters saves) take it too."""
    pending: PendingKeyframe | None = None
    """The newest keyframe waiting for the session's turn (an older one is dropped)."""
    mapping: bool = False
    """A keyframe is on its way: waiting for its turn or mapping."""
