"""The v1 `delta` (server -> subscribers on the updates socket): pack, unpack, parse.

The server builds deltas with `DeltaMessage.pack` (or `pack_delta`); the device's local map
and the viewer parse them with `parse_delta`, which validates everything and raises one
`DeltaError` naming the first wrong field. Whether a delta is in order (its seq against the
one last applied) is the subscriber's state, so the subscriber checks it.

Extensions of v1 (optional fields): "device_pose", the newest mapped keyframe's
camera-to-world pose in the frame's own encoding (16 float32 LE, row-major); the living map's
"first_seen_t" and "last_seen_t" on upserts (device clock, seconds) and "changes" (at most
MAX_CHANGES_PER_DELTA, never in a full snapshot).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from app.codecs import (
    CodecError,
    float16_points_from_bytes,
    float16_points_to_bytes,
    float16_vector_from_bytes,
    float16_vector_to_bytes,
    pose_from_bytes,
    pose_to_bytes,
)
from app.errors import InputError
from app.protocol.limits import (
    MAX_CHANGES_PER_DELTA,
    MAX_LABEL_CHARS,
    MAX_LABEL_TEXTS,
    MAX_REMOVED_PER_DELTA,
    MAX_UPSERTS_PER_DELTA,
    UPDATE_LIMITS,
    unpack_limited,
)

_INT64_MAX = 2**63 - 1
_FLOAT32_MAX = float(np.finfo(np.float32).max)
SEQ_FIELD = "seq"
"""An update's seq: the delta log position it brings a subscriber to (`?since=` takes it)."""
UPSERT_KEYS = ("id", "version", "label", "embedding", "points", "bbox", "n_obs")
"""The keys of every `upserts[]` entry."""
CHANGE_KINDS = ("added", "moved", "removed")
"""The kinds of a `changes[]` entry (the living map)."""
SINCE_PARAM = "since"
"""The updates socket's query parameter: the last seq the subscriber applied (absent: it
holds nothing, and gets a full snapshot)."""


def delta_seq(message: dict) -> int:
    """The seq of a packed delta (what its subscriber holds once it applies it)."""
    return message["seq"]


def has_news(message: dict) -> bool:
    """Whether a packed delta changes what its subscriber holds: a full snapshot, upserts or
    removals."""
    return bool(message["full"] or message["upserts"] or message["removed"])


class DeltaError(InputError):
    """A malformed delta (or, raised by a subscriber, an out-of-order one); nothing was
    applied, and the subscriber should resync (ask for a full snapshot)."""


@dataclass(eq=False)
class UpsertEntry:
    """One `upserts[]` entry: an object created or changed, at client resolution."""

    id: int
    version: int
    label: str
    embedding: np.ndarray
    """float16 [dim] unit vector as on the wire (any float [dim] packs, rounded to float16)."""
    points: np.ndarray
    """float16 [N, 3] metres as on the wire (any float [N, 3] packs, rounded to float16)."""
    bbox: tuple[float, float, float, float, float, float]
    """[x0, y0, z0, x1, y1, z1] metres, minimum corner first."""
    n_obs: int
    first_seen_t: float | None = None
    """Extension (living map): device-clock time of the first keyframe that observed it."""
    last_seen_t: float | None = None
    """Extension (living map): device-clock time of the newest keyframe that observed it."""
    label_texts: tuple[str, ...] | None = None
    """Extension (label texts): what the server knows the label by (the label, synonyms, a
    definition, its kind), which the match rule rates a query against; None: not sent (the
    label alone)."""

    def pack(self) -> dict:
        """The wire `upserts[]` entry (embedding and points as little-endian float16 bytes)."""
        entry = {
            "id": self.id,
            "version": self.version,
            "label": self.label,
            "embedding": float16_vector_to_bytes(self.embedding),
            "points": float16_points_to_bytes(self.points),
            "bbox": [float(v) for v in self.bbox],
            "n_obs": self.n_obs,
        }
        if self.first_seen_t is not None:
            entry["first_seen_t"] = float(self.first_seen_t)
        if self.last_seen_t is not None:
            entry["last_seen_t"] = float(self.last_seen_t)
        if self.label_texts is not None:
            entry["label_texts"] = list(self.label_texts)
        return entry

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, UpsertEntry):
            return NotImplemented
        return (
            (self.id, self.version, self.label, self.n_obs, self.first_seen_t, self.last_seen_t)
            == (
                other.id,
                other.version,
                other.label,
                other.n_obs,
                other.first_seen_t,
                other.last_seen_t,
            )
            and self.label_texts == other.label_texts
            and tuple(self.bbox) == tuple(other.bbox)
            and np.array_equal(self.embedding, other.embedding)
            and np.array_equal(self.points, other.points)
        )


@dataclass
class ChangeEntry:
    """One `changes[]` entry (the living map): what the map concluded about the world."""

    id: int
    kind: str
    """"added", "moved" or "removed"."""
    t: float
    """Device-clock time of the keyframe at which the map concluded it."""
    label: str
    from_xyz: tuple[float, float, float] | None = None
    to_xyz: tuple[float, float, float] | None = None

    def pack(self) -> dict:
        entry: dict = {"id": self.id, "kind": self.kind, "t": float(self.t), "label": self.label}
        if self.from_xyz is not None:
            entry["from"] = [float(v) for v in self.from_xyz]
        if self.to_xyz is not None:
            entry["to"] = [float(v) for v in self.to_xyz]
        return entry


@dataclass(eq=False)
class DeltaMessage:
    """A v1 `delta`: the objects created or changed and the ids removed after some seq."""

    seq: int
    full: bool
    """A snapshot: it replaces whatever the subscriber holds."""
    upserts: list[UpsertEntry] = field(default_factory=list)
    removed: list[int] = field(default_factory=list)
    device_pose: np.ndarray | None = None
    """Extension: float [4, 4] camera-to-world of the newest mapped keyframe, if any."""
    changes: list[ChangeEntry] = field(default_factory=list)
    """Extension (living map): changes concluded after the subscriber's seq, oldest first,
    at most MAX_CHANGES_PER_DELTA (the newest); never in a full snapshot."""

    def pack(self) -> dict:
        """The v1 `delta` message, ready for `msgpack.packb`."""
        message: dict = {
            "type": "delta",
            "seq": self.seq,
            "full": self.full,
            "upserts": [upsert.pack() for upsert in self.upserts],
            "removed": list(self.removed),
        }
        if self.device_pose is not None:
            message["device_pose"] = pose_to_bytes(self.device_pose)
        if self.changes:
            message["changes"] = [change.pack() for change in self.changes]
        return message

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, DeltaMessage):
            return NotImplemented
        if (self.device_pose is None) != (other.device_pose is None):
            return False
        return (
            (self.seq, self.full, list(self.removed))
            == (other.seq, other.full, list(other.removed))
            and list(self.upserts) == list(other.upserts)
            and list(self.changes) == list(other.changes)
            and (self.device_pose is None or np.array_equal(self.device_pose, other.device_pose))
        )


def pack_delta(
    seq: int,
    upserts: Sequence[UpsertEntry] = (),
    removed: Sequence[int] = (),
    full: bool = False,
    device_pose: np.ndarray | None = None,
) -> dict:
    """The v1 `delta` message of these parts (see `DeltaMessage`)."""
    return DeltaMessage(seq, full, list(upserts), list(removed), device_pose).pack()


def unpack_update(raw: bytes | str) -> dict | str:
    """A message from the updates socket, unpacked within `UPDATE_LIMITS`; or what is wrong
    with it (a string). The delta itself is validated by `parse_delta`."""
    if not isinstance(raw, bytes):
        return "a text message; updates are binary msgpack"
    try:
        return unpack_limited(raw, UPDATE_LIMITS)
    except InputError as exc:
        return str(exc)


# --- parsing --------------------------------------------------------------------------------


def _int(value: Any, field: str) -> int:
    """`value` as an int in [0, 2^63) (ids, versions, seqs); bools and floats refused."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise DeltaError(field, f"expected an integer, got {type(value).__name__}")
    if not 0 <= int(value) <= _INT64_MAX:
        raise DeltaError(field, f"{int(value)} is out of range 0..2^63-1")
    return int(value)


def _list(value: Any, field: str, most: int) -> list | tuple:
    if not isinstance(value, list | tuple):
        raise DeltaError(field, f"expected a list, got {type(value).__name__}")
    if len(value) > most:
        raise DeltaError(field, f"{len(value)} entries, at most {most} per delta")
    return value


def _bbox(value: Any, field: str) -> tuple[float, float, float, float, float, float]:
    """A finite, ordered [x0, y0, z0, x1, y1, z1] (within float32, as subscribers store it)."""
    if not isinstance(value, list | tuple):
        raise DeltaError(field, f"expected a list, got {type(value).__name__}")
    if len(value) != 6 or not all(
        isinstance(v, int | float | np.number) and not isinstance(v, bool) for v in value
    ):
        raise DeltaError(field, f"expected 6 numbers [x0, y0, z0, x1, y1, z1], got {value!r}")
    box = tuple(float(v) for v in value)
    if not all(math.isfinite(v) and abs(v) <= _FLOAT32_MAX for v in box):
        raise DeltaError(field, "not finite (NaN, inf or beyond float32)")
    if any(box[axis] > box[axis + 3] for axis in range(3)):
        raise DeltaError(field, f"minimum corner exceeds maximum corner in {value!r}")
    return box  # type: ignore[return-value]


def _embedding(value: Any, dim: int | None, field: str) -> np.ndarray:
    """float16 [dim]; with `dim` None, the dimension is whatever the bytes hold (>= 1)."""
    if dim is None:
        if not isinstance(value, bytes):
            raise DeltaError(field, f"expected binary data, got {type(value).__name__}")
        if len(value) < 2 or len(value) % 2:
            raise DeltaError(field, f"{len(value)} bytes is not a whole number of float16")
        dim = len(value) // 2
    return float16_vector_from_bytes(value, dim, field)


def _upsert(value: Any, dim: int | None, field: str) -> UpsertEntry:
    if not isinstance(value, dict):
        raise DeltaError(field, f"expected a map, got {type(value).__name__}")
    missing = [key for key in UPSERT_KEYS if key not in value]
    if missing:
        raise DeltaError(field, f"missing {', '.join(missing)}")
    label = value["label"]
    if not isinstance(label, str):
        raise DeltaError(f"{field}.label", f"expected a string, got {type(label).__name__}")
    oid = _int(value["id"], f"{field}.id")
    version = _int(value["version"], f"{field}.version")
    n_obs = _int(value["n_obs"], f"{field}.n_obs")
    bbox = _bbox(value["bbox"], f"{field}.bbox")
    try:
        embedding = _embedding(value["embedding"], dim, f"{field}.embedding")
        points = float16_points_from_bytes(value["points"], f"{field}.points")
    except CodecError as exc:
        raise DeltaError(exc.field, exc.message) from exc
    first_seen_t = _optional_time(value.get("first_seen_t"), f"{field}.first_seen_t")
    last_seen_t = _optional_time(value.get("last_seen_t"), f"{field}.last_seen_t")
    label_texts = _optional_label_texts(value.get("label_texts"), f"{field}.label_texts")
    return UpsertEntry(
        oid, version, label, embedding, points, bbox, n_obs, first_seen_t, last_seen_t, label_texts
    )


def _optional_label_texts(value: Any, field: str) -> tuple[str, ...] | None:
    """None, or at most MAX_LABEL_TEXTS strings of at most MAX_LABEL_CHARS each."""
    if value is None:
        return None
    if not isinstance(value, list) or len(value) > MAX_LABEL_TEXTS:
        raise DeltaError(field, f"expected a list of at most {MAX_LABEL_TEXTS} strings")
    if not all(isinstance(t, str) and len(t) <= MAX_LABEL_CHARS for t in value):
        raise DeltaError(field, f"expected strings of at most {MAX_LABEL_CHARS} characters")
    return tuple(value)


def _optional_time(value: Any, field: str) -> float | None:
    """None, or a finite number of seconds."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise DeltaError(field, f"expected a number, got {type(value).__name__}")
    if not math.isfinite(value):
        raise DeltaError(field, "not finite (NaN or inf)")
    return float(value)


def _point(value: Any, field: str) -> tuple[float, float, float] | None:
    if value is None:
        return None
    if (
        not isinstance(value, list | tuple)
        or len(value) != 3
        or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
    ):
        raise DeltaError(field, f"expected 3 numbers [x, y, z], got {value!r}")
    if not all(math.isfinite(v) and abs(v) <= _FLOAT32_MAX for v in value):
        raise DeltaError(field, "not finite (NaN, inf or beyond float32)")
    return (float(value[0]), float(value[1]), float(value[2]))


def _change(value: Any, field: str) -> ChangeEntry:
    if not isinstance(value, dict):
        raise DeltaError(field, f"expected a map, got {type(value).__name__}")
    for key in ("id", "kind", "t", "label"):
        if key not in value:
            raise DeltaError(field, f"missing {key}")
    if value["kind"] not in CHANGE_KINDS:
        raise DeltaError(f"{field}.kind", f"expected one of {', '.join(CHANGE_KINDS)}")
    label = value["label"]
    if not isinstance(label, str) or len(label) > MAX_LABEL_CHARS:
        raise DeltaError(f"{field}.label", f"expected a string of at most {MAX_LABEL_CHARS}")
    t = _optional_time(value["t"], f"{field}.t")
    if t is None:
        raise DeltaError(f"{field}.t", "missing")
    return ChangeEntry(
        _int(value["id"], f"{field}.id"),
        value["kind"],
        t,
        label,
        _point(value.get("from"), f"{field}.from"),
        _point(value.get("to"), f"{field}.to"),
    )


def parse_delta(message: Any, dim: int | None = None) -> DeltaMessage:
    """The `DeltaMessage` of an unpacked v1 `delta`, or DeltaError naming the first wrong
    field; no side effects.

    dim: the embedding dimension the session announced; None accepts any, but one for all
    upserts (the first one's). Embeddings and points stay float16 (wire precision).
    """
    if not isinstance(message, dict):
        raise DeltaError("message", f"expected a map, got {type(message).__name__}")
    if message.get("type") != "delta":
        raise DeltaError("type", f"expected 'delta', got {message.get('type')!r}")
    for key in ("seq", "full", "upserts", "removed"):
        if key not in message:
            raise DeltaError(key, "missing")
    seq = _int(message["seq"], "seq")
    full = message["full"]
    if not isinstance(full, bool):
        raise DeltaError("full", f"expected a boolean, got {type(full).__name__}")
    raw_upserts = _list(message["upserts"], "upserts", MAX_UPSERTS_PER_DELTA)
    removed = [
        _int(oid, f"removed[{i}]")
        for i, oid in enumerate(_list(message["removed"], "removed", MAX_REMOVED_PER_DELTA))
    ]
    upserts = []
    for i, raw in enumerate(raw_upserts):
        upsert = _upsert(raw, dim, f"upserts[{i}]")
        dim = len(upsert.embedding)  # every later upsert must match the first
        upserts.append(upsert)

    ids = [upsert.id for upsert in upserts]
    if len(set(ids)) != len(ids):
        raise DeltaError("upserts", "an id appears more than once")
    both = set(ids) & set(removed)
    if both:
        raise DeltaError("removed", f"ids {sorted(both)[:5]} are also upserted")

    device_pose = None
    if message.get("device_pose") is not None:
        try:
            device_pose = pose_from_bytes(message["device_pose"], "device_pose")
        except CodecError as exc:
            raise DeltaError(exc.field, exc.message) from exc
        if not np.all(np.isfinite(device_pose)):
            raise DeltaError("device_pose", "not finite (NaN or inf)")
    changes = [
        _change(raw, f"changes[{i}]")
        for i, raw in enumerate(_list(message.get("changes", []), "changes", MAX_CHANGES_PER_DELTA))
    ]
    return DeltaMessage(seq, full, upserts, removed, device_pose, changes)
