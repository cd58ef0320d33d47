"""The JSON bodies of v1's REST answers: typed records with `to_json()` for the server, and
parsers for the clients.

Geometry is rounded to 0.1 mm and scores to 5 decimals on the wire (JSON text is the cost).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from app.errors import InputError
from app.protocol.limits import PROTOCOL_VERSION


def _rounded(values: Sequence[float]) -> list[float]:
    return [round(float(v), 4) for v in values]


@dataclass
class EmbeddingInfo:
    """The session's text embedding: model id and dimension (the same on server and device)."""

    model: str
    dim: int

    def to_json(self) -> dict:
        return {"model": self.model, "dim": self.dim}


@dataclass
class SessionCreated:
    """201 answer of `POST /v1/sessions` (and of an import)."""

    session_id: str
    token: str
    """Bearer token for everything under this session; shown once."""
    embedding: EmbeddingInfo
    knobs: dict[str, Any]
    protocol: int = PROTOCOL_VERSION
    """Extension: the wire protocol version the server speaks."""

    def to_json(self) -> dict:
        return {
            "session_id": self.session_id,
            "token": self.token,
            "embedding": self.embedding.to_json(),
            "knobs": self.knobs,
            "protocol": self.protocol,
        }


@dataclass
class SessionSummary:
    """One entry of `GET /v1/sessions`."""

    session_id: str
    name: str
    mode: str
    objects: int
    frames: int
    keyframes: int
    fps: float
    update_seq: int

    @classmethod
    def from_stats(cls, stats: Mapping[str, Any]) -> SessionSummary:
        """The summary part of a session's full stats (`SessionStats` fields)."""
        return cls(**{f.name: stats[f.name] for f in fields(cls)})

    def to_json(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass
class SessionStats:
    """`GET /v1/sessions/{sid}`: what a session has done so far."""

    session_id: str
    name: str
    mode: str
    perception: str
    """Perception backend mapping the session's keyframes."""
    created_at: float
    frames: int
    """Valid frames received."""
    keyframes: int
    """Keyframes mapped."""
    dropped_frames: int
    """Keyframes superseded by newer ones before mapping."""
    objects: int
    """Confirmed objects."""
    fps: float
    """Frames per second over the last 60 frames."""
    bytes_in: dict[str, int]
    """Upstream bytes by kind (rgb, depth, detections) and "total"."""
    bytes_out: dict[str, int]
    """Downstream update bytes by kind and "total"."""
    mapping_latency_ms: dict[str, float | None]
    """{"p50", "p95"}, None before the first keyframe."""
    update_seq: int
    """Sequence number of the newest map change."""
    subscribers: int
    embedding: EmbeddingInfo
    knobs: dict[str, Any]

    @classmethod
    def from_stats(cls, stats: Mapping[str, Any]) -> SessionStats:
        """The record of a stats mapping (keys beyond the record's fields are left out)."""
        values = {f.name: stats[f.name] for f in fields(cls)}
        embedding = values["embedding"]
        if isinstance(embedding, Mapping):
            values["embedding"] = EmbeddingInfo(embedding["model"], embedding["dim"])
        return cls(**values)

    def to_json(self) -> dict:
        body = {f.name: getattr(self, f.name) for f in fields(self)}
        body["embedding"] = self.embedding.to_json()
        return body


@dataclass
class ObjectRecord:
    """One entry of `GET /v1/sessions/{sid}/objects`: a confirmed object."""

    id: int
    version: int
    label: str
    bbox: Sequence[float]
    """[x0, y0, z0, x1, y1, z1] metres, world frame."""
    centroid: Sequence[float]
    n_obs: int
    points: np.ndarray | None = None
    """float [N, 3] metres at client resolution, or None when not asked for."""

    def to_json(self) -> dict:
        body = {
            "id": self.id,
            "version": self.version,
            "label": self.label,
            "bbox": _rounded(self.bbox),
            "centroid": _rounded(self.centroid),
            "n_obs": self.n_obs,
        }
        if self.points is not None:
            body["points"] = np.asarray(self.points).round(4).tolist()
        return body


@dataclass
class QueryHitRecord:
    """One result of a query: an object and how well it matches."""

    id: int
    label: str
    score: float
    """Cosine similarity of the query and the object's embedding."""
    bbox: Sequence[float]
    centroid: Sequence[float]
    points: np.ndarray | list | None = None
    """float [N, 3] metres, or None when not asked for."""

    def to_json(self) -> dict:
        body = {
            "id": self.id,
            "label": self.label,
            "score": round(float(self.score), 5),
            "bbox": _rounded(self.bbox),
            "centroid": _rounded(self.centroid),
        }
        if self.points is not None:
            body["points"] = np.asarray(self.points).round(4).tolist()
        return body


@dataclass
class QueryResult:
    """`GET /v1/sessions/{sid}/query`: the best matches first."""

    text: str
    results: list[QueryHitRecord] = field(default_factory=list)
    latency_ms: float = 0.0

    def to_json(self) -> dict:
        return {
            "text": self.text,
            "results": [hit.to_json() for hit in self.results],
            "latency_ms": self.latency_ms,
        }


def _require(body: Mapping, key: str, kind: type | tuple[type, ...], where: str = "") -> Any:
    if key not in body:
        raise InputError(f"{where}{key}", "is missing")
    value = body[key]
    if isinstance(value, bool) or not isinstance(value, kind):
        raise InputError(f"{where}{key}", f"has the wrong type ({type(value).__name__})")
    return value


def _numbers(body: Mapping, key: str, count: int, where: str) -> list[float]:
    values = _require(body, key, list, where)
    if len(values) != count or not all(
        isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in values
    ):
        raise InputError(f"{where}{key}", f"must be {count} finite numbers")
    return [float(v) for v in values]


def parse_query_result(body: Any) -> QueryResult:
    """The `QueryResult` of a decoded JSON query answer; InputError naming the first wrong
    field. Points, when present, become float32 [N, 3]."""
    if not isinstance(body, Mapping):
        raise InputError("body", f"must be a JSON object, got {type(body).__name__}")
    text = _require(body, "text", str)
    latency_ms = float(_require(body, "latency_ms", int | float))
    hits = []
    for i, hit in enumerate(_require(body, "results", list)):
        where = f"results[{i}]."
        if not isinstance(hit, Mapping):
            raise InputError(f"results[{i}]", "must be a JSON object")
        points = hit.get("points")
        if points is not None:
            try:
                points = np.asarray(points, dtype=np.float32).reshape(-1, 3)
            except (TypeError, ValueError) as exc:
                raise InputError(f"{where}points", "must be [[x, y, z], ...]") from exc
        hits.append(
            QueryHitRecord(
                id=_require(hit, "id", int, where),
                label=_require(hit, "label", str, where),
                score=float(_require(hit, "score", int | float, where)),
                bbox=_numbers(hit, "bbox", 6, where),
                centroid=_numbers(hit, "centroid", 3, where),
                points=points,
            )
        )
    return QueryResult(text=text, results=hits, latency_ms=latency_ms)
