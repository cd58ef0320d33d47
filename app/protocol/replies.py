"""The v1 `ack` and `error` (server -> device on the stream socket): one per frame.

Extensions of v1 (optional fields a v1 client may ignore) on acks: `dropped` (a keyframe was
superseded by a newer one before it was mapped), `update_seq` (the map's seq after mapping
it), `objects` (confirmed objects after mapping it) and `doubted` (the places the map doubts
after mapping it, for a device that picks its keyframes).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

from app.errors import InputError
from app.protocol.limits import REPLY_LIMITS, unpack_limited

MAX_DOUBTED_PLACES = 32
"""At most this many doubted places go in one ack (within `REPLY_LIMITS`)."""


@dataclass
class Ack:
    """A frame was accepted (and, for a keyframe, mapped)."""

    seq: int
    keyframe: bool
    map_ms: float = 0.0
    """Server time from receiving a keyframe to its ack (0 for other frames)."""
    server_t: float = field(default_factory=time.time)
    """Server wall clock when the ack was built, seconds since the epoch."""
    dropped: bool = False
    """Extension: the keyframe was superseded before mapping (packed only when true)."""
    update_seq: int | None = None
    """Extension: the map's seq after this keyframe (packed only when known)."""
    objects: int | None = None
    """Extension: confirmed objects after this keyframe (packed only when known)."""
    doubted: list[list[float]] | None = None
    """Extension: [x, y, z, radius, t_ready] of each place the map doubts after this
    keyframe (a keyframe saw through it): metres, and the device time from which a keyframe
    seeing through it can complete the evidence a removal needs (packed only when known, [] for none; at most
    MAX_DOUBTED_PLACES). A device with the sightings extension may make a frame showing one
    a keyframe (docs/protocol.md)."""

    def pack(self) -> dict:
        """The v1 `ack` message, ready for `msgpack.packb`."""
        message: dict = {
            "type": "ack",
            "seq": self.seq,
            "server_t": self.server_t,
            "keyframe": self.keyframe,
            "map_ms": float(self.map_ms),
        }
        if self.dropped:
            message["dropped"] = True
        if self.update_seq is not None:
            message["update_seq"] = self.update_seq
        if self.objects is not None:
            message["objects"] = self.objects
        if self.doubted is not None:
            message["doubted"] = [
                [float(v) for v in place] for place in self.doubted[:MAX_DOUBTED_PLACES]
            ]
        return message


@dataclass
class ErrorReply:
    """A frame (or a message that was no frame) was refused; `message` names the field."""

    seq: int | None
    """The refused frame's seq, or None if the message had none (then it answers the oldest
    frame in flight: every frame gets exactly one reply)."""
    code: str
    """"bad_frame", "bad_message", "too_big", "internal", or "storage_unavailable" (the
    server cannot save the map now and mapped nothing: retry later)."""
    message: str

    def pack(self) -> dict:
        """The v1 `error` message, ready for `msgpack.packb`."""
        return {"type": "error", "seq": self.seq, "code": self.code, "message": self.message}


def _int(message: dict, key: str, optional: bool = False) -> int | None:
    """message[key] as an int; None where `optional` and it is absent or null."""
    value = message.get(key)
    if value is None and optional:
        return None
    if key not in message:
        raise InputError(key, "is missing")
    if isinstance(value, bool) or not isinstance(value, int):
        raise InputError(key, f"must be an integer, got {type(value).__name__}")
    return value


def _number(message: dict, key: str) -> float:
    if key not in message:
        raise InputError(key, "is missing")
    value = message[key]
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise InputError(key, f"must be a finite number, got {value!r}")
    return float(value)


def _bool(message: dict, key: str, default: bool | None = None) -> bool:
    if key not in message and default is not None:
        return default
    value = message.get(key)
    if not isinstance(value, bool):
        raise InputError(key, f"must be a boolean, got {type(value).__name__}")
    return value


def _places(message: dict, key: str) -> list[list[float]] | None:
    """message[key] as a list of [x, y, z, radius, t_ready] finite numbers; None where
    absent."""
    value = message.get(key)
    if value is None:
        return None
    if not isinstance(value, list):
        raise InputError(key, f"must be a list, got {type(value).__name__}")
    if len(value) > MAX_DOUBTED_PLACES:
        raise InputError(key, f"holds {len(value)} places, at most {MAX_DOUBTED_PLACES}")
    places = []
    for i, place in enumerate(value):
        if (
            not isinstance(place, list)
            or len(place) != 5
            or not all(
                not isinstance(v, bool) and isinstance(v, int | float) and math.isfinite(v)
                for v in place
            )
        ):
            raise InputError(f"{key}[{i}]", "must be 5 finite numbers [x, y, z, radius, t_ready]")
        places.append([float(v) for v in place])
    return places


def _str(message: dict, key: str) -> str:
    value = message.get(key)
    if not isinstance(value, str):
        raise InputError(key, f"must be a string, got {type(value).__name__}")
    return value


def parse_reply(message: Any) -> Ack | ErrorReply:
    """The `Ack` or `ErrorReply` of an unpacked stream-socket reply; InputError naming the
    first wrong field."""
    if not isinstance(message, dict):
        raise InputError("message", f"must be a map, got {type(message).__name__}")
    kind = message.get("type")
    if kind == "error":
        return ErrorReply(
            seq=_int(message, "seq", optional=True),
            code=_str(message, "code"),
            message=_str(message, "message"),
        )
    if kind != "ack":
        raise InputError("type", f"must be 'ack' or 'error', got {kind!r}")
    return Ack(
        seq=_int(message, "seq"),  # type: ignore[arg-type]
        keyframe=_bool(message, "keyframe"),
        map_ms=_number(message, "map_ms"),
        server_t=_number(message, "server_t"),
        dropped=_bool(message, "dropped", default=False),
        update_seq=_int(message, "update_seq", optional=True),
        objects=_int(message, "objects", optional=True),
        doubted=_places(message, "doubted"),
    )


def unpack_reply(raw: bytes | str) -> Ack | ErrorReply:
    """A message from the stream socket (server -> device), unpacked within `REPLY_LIMITS`
    and parsed; InputError if it is text, not msgpack, over a limit or malformed."""
    if not isinstance(raw, bytes):
        raise InputError("message", "a text message; replies are binary msgpack")
    return parse_reply(unpack_limited(raw, REPLY_LIMITS))
