"""The JSON bodies of v1's REST calls: one pydantic model per body.

These models are the one definition of each body: the server builds its answers with them,
FastAPI validates requests and writes the OpenAPI document from them, and clients parse
answers with them (`parse_query_result`). Field docs are the attribute docstrings.

Geometry is rounded to 0.1 mm and scores to 5 decimals on the wire (JSON text is the cost).
"""

from __future__ import annotations

import dataclasses
from typing import Annotated, Any, Literal, TypeVar, get_args

import numpy as np
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError, create_model

from app.config import KNOB_RANGES, NULLABLE_KNOBS, Knobs, knob_docs
from app.errors import InputError
from app.protocol.limits import DEFAULT_EMBEDDING_DIM, PROTOCOL_VERSION

MAX_QUERY_CHARS = 500
"""Longest query text."""
MAX_NAME_CHARS = 200
"""Longest session name."""
UPDATES_BYTES = "updates"
"""The kind of a session's `bytes_out`: update messages sent to its subscribers."""

UpAxis = Literal["+x", "-x", "+y", "-y", "+z", "-z"]
"""Which way is up in the world frame: a world axis and its sense ("+z": our synthetic world,
"+y": XR runtimes)."""
UP_AXES: tuple[str, ...] = get_args(UpAxis)
TextTower = Literal["minilm", "static"]
"""A session's text tower: "minilm" (all-MiniLM-L6-v2, the default) or "static" (a static
embedding table distilled from it, served by hash at `GET /v1/text-towers/{sha256}`)."""
TEXT_TOWERS: tuple[str, ...] = get_args(TextTower)
DEFAULT_TEXT_TOWER = "minilm"
UpSource = Literal["set", "inferred", "default"]
"""Where a session's up comes from: set at creation, inferred from the device's poses, or
the default (+z) while neither."""


def _rounded_floats(values: Any) -> Any:
    """Numbers (or an array) -> floats rounded to 0.1 mm; anything else is left to validation."""
    if isinstance(values, np.ndarray):
        return np.asarray(values, np.float64).round(4).tolist()
    if isinstance(values, list | tuple) and all(
        isinstance(v, int | float | np.floating | np.integer) and not isinstance(v, bool)
        for v in values
    ):
        return [round(float(v), 4) for v in values]
    return values


def _rounded_points(points: Any) -> Any:
    if isinstance(points, np.ndarray):
        return np.asarray(points, np.float64).round(4).tolist()
    return points


def _rounded_score(score: Any) -> Any:
    if isinstance(score, float | np.floating):
        return round(float(score), 5)
    return score


Box = Annotated[list[float], BeforeValidator(_rounded_floats), Field(min_length=6, max_length=6)]
"""[x0, y0, z0, x1, y1, z1] metres, world frame."""
Point = Annotated[list[float], BeforeValidator(_rounded_floats), Field(min_length=3, max_length=3)]
Points = Annotated[
    list[Annotated[list[float], Field(min_length=3, max_length=3)]] | None,
    BeforeValidator(_rounded_points),
    Field(exclude_if=lambda points: points is None),  # left out when not asked for
]
Score = Annotated[float, BeforeValidator(_rounded_score)]


class Record(BaseModel):
    """A REST body; keys beyond its fields are left out when parsing."""

    model_config = ConfigDict(use_attribute_docstrings=True, extra="ignore")

    def to_json(self) -> dict:
        """The JSON body."""
        return self.model_dump(mode="json")


R = TypeVar("R", bound=Record)


class ErrorBody(Record):
    """Every 4xx/5xx answer but FastAPI's own 422 for a body of the wrong shape."""

    detail: str
    """What is wrong, in words."""


class UnprocessableBody(Record):
    detail: str
    """What is wrong, naming the field: a bad knob value or setting, or a body or parameter
    of the wrong shape ("where: what; ...")."""


def _knobs_model() -> type[BaseModel]:
    """The knobs in force, generated from app.config.Knobs (each knob documented once)."""
    docs, defaults = knob_docs(), Knobs()
    fields: dict[str, Any] = {
        f.name: (f.type, Field(getattr(defaults, f.name), description=docs.get(f.name)))
        for f in dataclasses.fields(Knobs)
    }
    return create_model("Knobs", **fields)


def _knob_changes_schema() -> dict[str, Any]:
    """JSON schema of a knob-changes body: known knobs only, each of its type and range.

    Validation itself stays in app.config.updated_knobs (one place, and it names the knob of
    a bad value); it also takes numbers as strings and lists as comma-separated strings,
    which is what the device's command-line flags send."""
    docs, defaults = knob_docs(), Knobs()
    properties: dict[str, Any] = {}
    for f in dataclasses.fields(Knobs):
        default = getattr(defaults, f.name)
        if isinstance(default, list):
            prop: dict[str, Any] = {
                "anyOf": [
                    {"type": "array", "items": {"type": "string", "maxLength": 200}},
                    {"type": "string", "description": "comma-separated"},
                ]
            }
        elif isinstance(default, bool):
            prop = {"anyOf": [{"type": "boolean"}, {"type": "string", "enum": ["true", "false"]}]}
        else:
            lo, hi = KNOB_RANGES[f.name]
            kind = "integer" if isinstance(default, int) else "number"
            prop = {"type": kind, "minimum": lo, "maximum": hi}
            if f.name in NULLABLE_KNOBS:
                prop = {"anyOf": [prop, {"type": "null"}]}
        properties[f.name] = {**prop, "description": docs.get(f.name, "")}
    return {"type": "object", "properties": properties, "additionalProperties": False}


KnobsBody = _knobs_model()
KNOB_CHANGES_SCHEMA = _knob_changes_schema()
"""JSON schema of `PATCH .../knobs` and of the `knobs` of `POST /v1/sessions`."""


class EmbeddingInfo(Record):
    """The session's text embedding (the same on server and device)."""

    model: str
    """Encoder model id."""
    dim: int
    """Embedding dimension."""
    sha256: Annotated[str | None, Field(exclude_if=lambda value: value is None)] = None
    """Extension: the SHA-256 of a static text tower's file (64 hex digits), which the
    device downloads from `GET /v1/text-towers/{sha256}`; None (left out of the body) for
    every other encoder."""


class CreateSession(Record):
    """Body of `POST /v1/sessions`."""

    name: str | None = Field(None, max_length=MAX_NAME_CHARS)
    """Human-readable name."""
    mode: Literal["semanticxr", "baseline"] = "semanticxr"
    """System organisation."""
    knobs: dict[str, Any] = Field(default_factory=dict, json_schema_extra=KNOB_CHANGES_SCHEMA)
    """Knob overrides (see GET knobs)."""
    perception: str | None = Field(None, max_length=100)
    """Perception backend: detections or one the server loaded with --perception (default:
    the first of those)."""
    up: UpAxis | None = None
    """Extension: which world axis is up ("+x", "-x", "+y", "-y", "+z" or "-z"), for the
    relations and places answers. Left out, the server infers it from the device's poses."""
    text_tower: TextTower = DEFAULT_TEXT_TOWER
    """Extension: the text tower labels and questions are embedded with: "minilm"
    (all-MiniLM-L6-v2) or "static" (a static table distilled from it, which devices and the
    page download by hash; `embedding` then names it). Only `detections` sessions have a
    static tower so far."""


class SessionCreated(Record):
    """201 answer of `POST /v1/sessions`."""

    session_id: str
    token: str
    """Bearer token for everything under this session; shown once."""
    embedding: EmbeddingInfo
    knobs: KnobsBody  # type: ignore[valid-type]
    protocol: int = PROTOCOL_VERSION
    """Extension: the wire protocol version the server speaks."""


class SessionCounts(Record):
    """What `GET /v1/sessions` and `GET /v1/sessions/{sid}` both say of a session."""

    session_id: str
    name: str
    mode: str
    objects: int
    """Confirmed objects."""
    frames: int
    """Frames walked: valid frames received, whole or as sightings."""
    frames_whole: int | None = None
    """Extension: of `frames`, those received whole (None from a server that does not count
    them apart)."""
    sightings: int | None = None
    """Extension: of `frames`, those received as sightings, the sightings extension's frames
    between keyframes (None from a server that does not count them apart)."""
    keyframes: int
    """Keyframes mapped."""
    fps: float
    """Frames per second over the last 60 frames."""
    update_seq: int
    """Sequence number of the newest map change."""
    up: Annotated[UpAxis | None, Field(exclude_if=_none)] = None
    """Extension: the world axis that is up, what relations and places are measured along
    (None from a server that does not say; then left out of the body)."""
    up_source: Annotated[UpSource | None, Field(exclude_if=_none)] = None
    """Extension: "set" at creation, "inferred" from the device's poses, or "default" (+z)
    until the poses say (None from a server that does not say; then left out)."""


class SessionSummary(SessionCounts):
    """One entry of `GET /v1/sessions`."""

    resident: bool = True
    """Whether the session's map is in memory now (else it loads on first use)."""
    last_used_at: float | None = None
    """Unix time of the session's last frame or use (what retention counts from)."""


class LatencySummary(Record):
    p50: float | None
    p95: float | None


class SessionStats(SessionCounts):
    """`GET /v1/sessions/{sid}`: what a session has done so far."""

    perception: str
    """Perception backend mapping the session's keyframes."""
    created_at: float
    dropped_frames: int
    """Keyframes superseded by newer ones before mapping."""
    bytes_in: dict[str, int]
    """Upstream bytes by kind (rgb, depth, detections) and "total"."""
    bytes_out: dict[str, int]
    """Downstream update bytes by kind (UPDATES_BYTES) and "total"."""
    mapping_latency_ms: LatencySummary
    """Server time per mapped keyframe, p50 and p95 (None before the first keyframe):
    decode + perception + mapping + delta."""
    streams: Annotated[int | None, Field(exclude_if=_none)] = None
    """Extension: frame streams open, each counted until its close has settled the map and
    published the result, so a device that closed its stream waits for 0 to read the settled
    `update_seq` (None from a server that does not count them; then left out)."""
    subscribers: int
    embedding: EmbeddingInfo
    knobs: KnobsBody  # type: ignore[valid-type]
    warnings: list[str] = Field(default_factory=list)
    """Extension: problems with what the session is fed, each once, with the fix (e.g.
    frames without detections on a backend that needs them)."""


class ObjectRecord(Record):
    """One entry of `GET /v1/sessions/{sid}/objects`: a confirmed object."""

    id: int
    version: int
    label: str
    bbox: Box
    """[x0, y0, z0, x1, y1, z1] metres, world frame."""
    centroid: Point
    n_obs: int
    """Frames the object was seen in."""
    points: Points = None
    """[[x, y, z], ...] metres at client resolution; left out when not asked for."""
    state: Literal["present", "removed"] = "present"
    """Extension (living map): "removed" objects are history, listed with include=removed."""
    first_seen_t: float | None = None
    """Extension (living map): frame `t` of the first keyframe that observed it (device
    clock, seconds); null for objects mapped before times were kept."""
    last_seen_t: float | None = None
    """Extension (living map): frame `t` of the newest keyframe that observed it."""


class PlaceRecord(Record):
    """Extension (living map): where something is, in words ("on the dining table"): the
    object it rests on, else the nearest large object it stands near, in the present map."""

    relation: Literal["on", "near"]
    id: int
    """The object it is on or near."""
    label: str
    """That object's label."""


class AnchorRecord(Record):
    """An object a relational hit is measured against."""

    id: int
    label: str


class HitRelation(Record):
    """Why a relational hit answers ("the mug on the desk"): the relation it stands in."""

    kind: str
    """A relation (on, in, under, above, below, near, next_to, between, left_of, right_of,
    in_front_of, behind) or a superlative (closest, farthest, biggest, smallest, highest,
    lowest); the question's first relation when it names several."""
    anchors: list[AnchorRecord]
    """What it is measured against: two for `between`; none for the asker ("near me",
    "closest to me") or a superlative within the category ("the biggest table")."""
    degree: Annotated[Score, Field(ge=0.0, le=1.0)]
    """How much the hit stands in `kind` to the anchors, in [0, 1] (0: not at all)."""


class QueryHit(Record):
    """One result of a query: an object and how well it matches."""

    id: int
    label: str
    score: Score
    """Cosine similarity of the query and the object's embedding (raw, uncalibrated)."""
    relevance: Annotated[Score, Field(ge=0.0, le=1.0)]
    """Calibrated in [0, 1]: how well the object's label answers the query against every
    other label it could mean (>= 0.5 is a confident match); what pages highlight by."""
    bbox: Box
    centroid: Point
    points: Points = None
    """[[x, y, z], ...] metres; left out when not asked for."""
    state: Literal["present", "removed"] = "present"
    """Extension (living map): "removed" hits come only with include=removed: where the
    thing was last seen."""
    last_seen_t: float | None = None
    """Extension (living map): frame `t` of the newest keyframe that observed it."""
    place: PlaceRecord | None = None
    """Extension (living map): where it is (a removed hit: where it was last seen), told by
    the other objects of the present map; null when nothing large is near."""
    relation: HitRelation | None = None
    """Extension (relations): set when the question was answered as relational ("the mug
    on the desk"); null for a plain answer."""


class QueryResult(Record):
    """`GET /v1/sessions/{sid}/query`: the best matches first."""

    text: str
    match: bool
    """False when no hit is a confident match (the hits are still listed)."""
    results: list[QueryHit]
    latency_ms: float
    now_t: float | None = None
    """Extension (living map): the session's newest frame `t` (device clock), what "last
    seen ... ago" counts from; null before the first keyframe."""
    ranked_by: Annotated[str | None, Field(exclude_if=_none)] = None
    """Extension (text towers): the `embedding.model` of the tower that ranked and rated the
    hits: the session's own, or with `rerank=true` on a static session the tower it was
    distilled from (None from a server that does not say; then left out)."""


class SpokenQueryResult(QueryResult):
    """`POST /v1/sessions/{sid}/query/speech`: the answer to the recognised text, as
    `GET .../query?text=<transcript>` answers it (`text` is the transcript too), and what
    was heard."""

    transcript: str
    """What the recogniser heard, the question answered."""
    confidence: float | None = None
    """The recogniser's confidence in the transcript, in [0, 1]; null when it has none."""
    asr_ms: float
    """Decoding and recognising the audio, from the whole body received to the transcript
    (`latency_ms` stays the query's own)."""


def parse_query_result(body: Any) -> QueryResult:
    """The `QueryResult` of a decoded JSON query answer; InputError naming the first wrong
    field (e.g. `results[0].bbox`)."""
    if not isinstance(body, dict):
        raise InputError("body", f"must be a JSON object, got {type(body).__name__}")
    try:  # strict: a client takes no "3" for 3 and no true for a score
        return QueryResult.model_validate(body, strict=True)
    except ValidationError as exc:
        first = exc.errors()[0]
        raise InputError(_field_name(first["loc"]), first["msg"]) from None


def parse_record(model: type[R], body: Any) -> R:
    """A decoded JSON answer as its `model` (keys beyond its fields left out); InputError
    naming the first wrong field (e.g. `mapping_latency_ms.p50`)."""
    if not isinstance(body, dict):
        raise InputError("body", f"must be a JSON object, got {type(body).__name__}")
    try:
        return model.model_validate(body)
    except ValidationError as exc:
        first = exc.errors()[0]
        raise InputError(".".join(map(str, first["loc"])) or "body", first["msg"]) from None


def _field_name(loc: tuple) -> str:
    """('results', 0, 'bbox', 2) -> 'results[0].bbox': the field, not the item inside it."""
    name = ""
    for part in loc:
        if isinstance(part, int):
            if name != "results":
                break
            name += f"[{part}]"
        else:
            name += f".{part}" if name else str(part)
    return name


# ---------------------------------------------------------------------- export and import
EXPORT_FORMAT = "semanticxr-map"
EXPORT_VERSION = 1
Finite = Annotated[float, Field(allow_inf_nan=False, strict=True)]
"""A JSON number that is neither NaN nor infinite."""


def _none(value: object) -> bool:
    return value is None


class ExportedSession(Record):
    """The session an export was taken from (what an import creates)."""

    name: str = Field(max_length=MAX_NAME_CHARS)
    mode: Literal["semanticxr", "baseline"]
    knobs: dict[str, Any] = Field(json_schema_extra=KNOB_CHANGES_SCHEMA)
    """The knobs in force (as GET knobs answers)."""
    embedding: EmbeddingInfo
    """The encoder the objects' embeddings come from; an import needs the same dimension."""
    perception: str | None = Field(None, max_length=100)
    """Extension: the session's perception backend (an import falls back to the server's
    default when it is not loaded)."""
    up: Annotated[UpAxis | None, Field(exclude_if=_none)] = None
    """Extension: the session's up axis, when it was set or inferred (absent while the
    session used the default); an import keeps it."""
    up_source: Annotated[Literal["set", "inferred"] | None, Field(exclude_if=_none)] = None
    """Extension: where `up` came from ("set" when absent); an import keeps it."""
    text_tower: Annotated[TextTower | None, Field(exclude_if=_none)] = None
    """Extension: the session's text tower (absent: "minilm"); an import keeps it."""


MAX_EXPORTED_STAYS = 32
"""Stays an exported object may hold: the map's MAX_STAYS (app.mapping.object)."""


class ExportedStay(Record):
    """One place an object stayed at (device clock, metres)."""

    t_from: Finite
    """Frame `t` of the first keyframe that observed it there (seconds)."""
    t_to: Finite
    """Frame `t` of the last keyframe that observed it there (seconds)."""
    centroid: Annotated[list[Finite], Field(min_length=3, max_length=3)]
    bbox: Annotated[list[Finite], Field(min_length=6, max_length=6)]
    """[x0, y0, z0, x1, y1, z1]"""


class ExportedChange(Record):
    """One change the map concluded (the wire's change entry) and the update seq that
    published it."""

    model_config = ConfigDict(serialize_by_alias=True)  # "from" is a Python keyword

    id: int = Field(ge=1, le=2**31 - 1)
    kind: Literal["added", "moved", "removed"]
    t: Finite
    """Frame `t` of the keyframe at which the map concluded it (device clock, seconds)."""
    label: str = Field(max_length=MAX_NAME_CHARS)
    from_: Annotated[
        Annotated[list[Finite], Field(min_length=3, max_length=3)] | None,
        Field(alias="from", exclude_if=_none),
    ] = None
    """The old place [x, y, z] (moved, removed)."""
    to: Annotated[
        Annotated[list[Finite], Field(min_length=3, max_length=3)] | None,
        Field(exclude_if=_none),
    ] = None
    """The new place [x, y, z] (added, moved)."""
    seq: int = Field(ge=1, le=2**62)
    """The update seq of the commit that published it (an import keeps it)."""


class ExportedObject(Record):
    """One confirmed object of an export, at full server resolution (0.1 mm)."""

    id: int = Field(ge=1, le=2**31 - 1)
    """Kept by an import."""
    version: int = Field(ge=1)
    label: str = Field(min_length=1, max_length=MAX_NAME_CHARS)
    bbox: Annotated[list[Finite], Field(min_length=6, max_length=6)]
    """[x0, y0, z0, x1, y1, z1] metres of the points (an import derives it again)."""
    centroid: Annotated[list[Finite], Field(min_length=3, max_length=3)]
    """Mean of the points (an import derives it again)."""
    n_obs: int = Field(ge=1)
    """Frames the object was seen in."""
    points: Annotated[
        list[Annotated[list[Finite], Field(min_length=3, max_length=3)]], Field(min_length=1)
    ]
    """[[x, y, z], ...] metres, world frame."""
    embedding: Annotated[
        Annotated[list[Finite], Field(min_length=1)] | None,
        Field(exclude_if=lambda embedding: embedding is None),
    ] = None
    """The object's unit embedding (`?embeddings=true`); without it (absent or null, never
    empty) an import embeds the label."""
    first_seen_t: Annotated[Finite | None, Field(exclude_if=_none)] = None
    """Frame `t` of the first keyframe that observed it (device clock, seconds)."""
    last_seen_t: Annotated[Finite | None, Field(exclude_if=_none)] = None
    """Frame `t` of the newest keyframe that observed it."""
    stays: Annotated[
        list[ExportedStay] | None, Field(max_length=MAX_EXPORTED_STAYS, exclude_if=_none)
    ] = None
    """Where it has been, oldest first (absent: no history)."""


class MapExport(Record):
    """`GET /v1/sessions/{sid}/export?format=json`, and the body of `POST
    /v1/sessions/import`."""

    # The example of /docs and of API fuzzers: an import a default server takes.
    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "format": EXPORT_FORMAT,
                    "version": EXPORT_VERSION,
                    "session": {
                        "name": "kitchen",
                        "mode": "semanticxr",
                        "knobs": {},
                        "embedding": {"model": "all-MiniLM-L6-v2", "dim": DEFAULT_EMBEDDING_DIM},
                    },
                    "objects": [
                        {
                            "id": 1,
                            "version": 1,
                            "label": "chair",
                            "bbox": [0.0, 0.0, 0.0, 0.4, 0.4, 0.8],
                            "centroid": [0.2, 0.2, 0.4],
                            "n_obs": 3,
                            "points": [[0.0, 0.0, 0.0], [0.4, 0.4, 0.8]],
                        }
                    ],
                }
            ]
        }
    )

    format: Literal["semanticxr-map"]
    version: Literal[1]
    session: ExportedSession
    objects: list[ExportedObject]
    """Confirmed objects, in id order."""
    removed_objects: Annotated[list[ExportedObject] | None, Field(exclude_if=_none)] = None
    """Objects removed from the map but kept as history (their last points and stays), in
    id order; ids distinct from the objects'."""
    changes: Annotated[list[ExportedChange] | None, Field(exclude_if=_none)] = None
    """The changes the map concluded, in the order they arrived (seq never decreasing)."""


class ChangeRecord(ExportedChange):
    """One entry of `GET .../changes`: a change and where it happened, in words (the export
    keeps `ExportedChange`, without the place)."""

    place: PlaceRecord | None = None
    """Extension (living map): where `to` (else `from`) is, told by the present map's other
    objects when the list is read; null when nothing large is near."""


class ChangeList(Record):
    """`GET /v1/sessions/{sid}/changes`: what the map concluded, in arrival order."""

    changes: list[ChangeRecord]
    now_t: float | None = None
    """The session's newest frame `t` (device clock): what "ago" counts from."""


class ObjectHistory(Record):
    """`GET /v1/sessions/{sid}/objects/{id}/history`: where an object has been."""

    id: int
    label: str
    state: Literal["present", "removed"]
    first_seen_t: float | None = None
    last_seen_t: float | None = None
    stays: list[ExportedStay]
    """Oldest first; the last is where it is (or was last seen, when removed)."""
