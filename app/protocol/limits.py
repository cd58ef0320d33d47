"""The version and every limit of wire protocol v1, and the bounded msgpack unpacking.

A limit is defined here once; validation elsewhere imports it. The msgpack limits are sized
from what a valid message can hold, so a hostile message is refused while it is unpacked
instead of being expanded into memory: msgpack turns each byte of an empty array into a
Python list of ~60 bytes, so 8 MiB of nested empty arrays would otherwise cost ~600 MB.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

import msgpack

from app.codecs import MAX_IMAGE_SIDE_PX
from app.errors import InputError

__all__ = [
    "DEFAULT_EMBEDDING_DIM",
    "FRAME_LIMITS",
    "FrameBudget",
    "LimitError",
    "MAX_IMAGE_SIDE_PX",
    "MAX_INSTANCES_PER_FRAME",
    "MAX_CHANGES_PER_DELTA",
    "MAX_INTRINSIC_PX",
    "MAX_LABEL_CHARS",
    "MAX_REMOVED_PER_DELTA",
    "MAX_STR_BYTES",
    "MAX_UPSERTS_PER_DELTA",
    "PROTOCOL_VERSION",
    "REPLY_LIMITS",
    "UPDATE_LIMITS",
    "UnpackLimits",
    "unpack_limited",
]

PROTOCOL_VERSION = 1
"""The wire protocol this code speaks; announced in the session creation answer."""

# MAX_IMAGE_SIDE_PX (8192) is the image decoders' bomb guard; app.codecs owns it (the codecs
# are below the protocol) and it is re-exported here with the other limits.

MAX_INTRINSIC_PX = 1e6
"""Focal lengths and principal points beyond this many pixels are refused (finite points)."""

DEFAULT_EMBEDDING_DIM = 384
"""Embedding dimension of the default text encoder (all-MiniLM-L6-v2); a session announces
its own in `embedding.dim`."""

MAX_INSTANCES_PER_FRAME = 1024
"""Most `detections.instances` one frame may list (what the `detections` backend accepted
before this limit moved here)."""

MAX_LABEL_CHARS = 200
"""Longest label a device may send with a detection."""

MAX_LABEL_TEXTS = 16
"""Most texts an upsert's optional `label_texts` may list."""

MAX_UPSERTS_PER_DELTA = 50_000
"""Most `upserts` one delta may hold: a full snapshot of the largest map a session is sized
for (the device's target: 50k objects, docs/evaluation.md "Targets")."""

MAX_REMOVED_PER_DELTA = 100_000
"""Most `removed` ids one delta may hold: the tombstones the delta log keeps at most."""

MAX_CHANGES_PER_DELTA = 32
"""Most `changes` one delta carries (the newest; a subscriber that needs them all reads
`GET .../changes?since_seq=`). Small enough to fit the items budget beside a 50k snapshot."""

MAX_STR_BYTES = 4096
"""Longest string (labels, codec names, error messages) in any message, UTF-8 bytes."""


@dataclass(frozen=True)
class UnpackLimits:
    """msgpack limits of one socket direction; a message over any of them is refused.

    Binary fields are bounded by the message itself, which the socket's size limit bounds.
    """

    max_str_len: int
    max_array_len: int
    max_map_len: int
    max_items: int
    """Containers plus their elements over the whole message: what bounds its memory."""


FRAME_LIMITS = UnpackLimits(
    max_str_len=MAX_STR_BYTES,
    max_array_len=MAX_INSTANCES_PER_FRAME,
    max_map_len=64,  # a frame has ~10 keys; the rest is room for optional extensions
    max_items=16 * MAX_INSTANCES_PER_FRAME,  # an instance is a map of 3 pairs
)
"""Device -> server on the stream socket (frames)."""

REPLY_LIMITS = UnpackLimits(
    max_str_len=MAX_STR_BYTES, max_array_len=64, max_map_len=64, max_items=256
)
"""Server -> device on the stream socket (acks and errors)."""

UPDATE_LIMITS = UnpackLimits(
    max_str_len=MAX_STR_BYTES,
    max_array_len=max(MAX_UPSERTS_PER_DELTA, MAX_REMOVED_PER_DELTA),
    max_map_len=64,  # an upsert has 7 keys
    max_items=16 * MAX_UPSERTS_PER_DELTA + MAX_REMOVED_PER_DELTA + 1024,  # upsert: map + bbox
)
"""Server -> subscribers on the updates socket (deltas)."""


class LimitError(InputError):
    """Valid input over a budget the server sets (not malformed): `setting` names the server
    setting, whose flag the message names too (a device may resend it smaller)."""

    def __init__(self, field: str, message: str, setting: str):
        flag = "--" + setting.replace("_", "-")
        super().__init__(field, f"{message} (server setting {setting}, {flag})")
        self.setting = setting


@dataclass(frozen=True)
class FrameBudget:
    """What one frame may cost the server, below the protocol's hard limits; the server sets
    it from its settings of the same names. A frame over it gets a `LimitError`, checked
    from declared sizes and counts before any pixel is decoded."""

    max_frame_pixels: int = MAX_IMAGE_SIDE_PX * MAX_IMAGE_SIDE_PX
    """Most pixels of each image of the frame (RGB, depth, instance ids)."""
    max_instances_per_frame: int = MAX_INSTANCES_PER_FRAME
    """Most `detections.instances` (at most MAX_INSTANCES_PER_FRAME)."""

    def check_pixels(self, field: str, w: int, h: int) -> None:
        if w * h > self.max_frame_pixels:
            raise LimitError(
                field,
                f"{w}x{h} = {w * h} pixels is over the limit of {self.max_frame_pixels}",
                "max_frame_pixels",
            )

    def check_instances(self, field: str, n: int) -> None:
        if n > self.max_instances_per_frame:
            raise LimitError(
                field,
                f"{n} instances is over the limit of {self.max_instances_per_frame}",
                "max_instances_per_frame",
            )


_MSGPACK_LIMIT = re.compile(r"^(\d+) exceeds max_(str|bin|array|map)_len\((\d+)\)$")
_KIND = {"str": "a string of {} bytes", "bin": "binary of {} bytes"}
_KIND |= {"array": "a list of {} items", "map": "a map of {} pairs"}


class _TooManyItems(Exception):
    pass


def unpack_limited(raw: bytes, limits: UnpackLimits) -> Any:
    """The msgpack message `raw`, unpacked within `limits`; InputError("message", ...) naming
    what is over a limit, or saying it is not msgpack. Map keys may be any type (a frame
    with odd keys gets an error naming the field, not "not msgpack")."""
    count = 0

    def counted(container: Any) -> Any:
        nonlocal count
        count += 1 + len(container)
        if count > limits.max_items:
            raise _TooManyItems
        return container

    try:
        return msgpack.unpackb(
            raw,
            raw=False,
            strict_map_key=False,
            max_str_len=limits.max_str_len,
            max_bin_len=len(raw),
            max_array_len=limits.max_array_len,
            max_map_len=limits.max_map_len,
            max_ext_len=0,
            list_hook=counted,
            object_hook=counted,
        )
    except _TooManyItems:
        raise InputError(
            "message", f"holds more than {limits.max_items} items, the protocol's limit"
        ) from None
    except ValueError as exc:
        over = _MSGPACK_LIMIT.match(str(exc))
        if over is None:
            raise InputError("message", f"not msgpack ({type(exc).__name__})") from None
        size, kind, limit = over.groups()
        raise InputError(
            "message", f"{_KIND[kind].format(size)} is over the protocol's limit of {limit}"
        ) from None
    except Exception as exc:  # msgpack raises many types for garbage
        raise InputError("message", f"not msgpack ({type(exc).__name__})") from None
