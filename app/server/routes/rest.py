"""REST: sessions, knobs, objects, queries (DESIGN.md "Wire protocol v1", REST)."""

from __future__ import annotations

import time
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Body, Depends, HTTPException, Query, Request, Response
from pydantic import BaseModel, Field

from app import protocol
from app.config import KnobError, knobs_to_dict
from app.mapping.object import MapObject
from app.mapping.publish import client_points
from app.perception import UnknownBackendError
from app.server.auth import authorize_session, bearer, require_api_key
from app.server.sessions import Session, SessionManager

MAX_QUERY_CHARS = 500


class ErrorOut(BaseModel):
    detail: str = Field(description="what is wrong, in words")


class UnprocessableOut(BaseModel):
    detail: str | list[dict[str, Any]] = Field(
        description="a bad knob value, in words; or FastAPI's list of {loc, msg, type} for a "
        "body or parameter of the wrong shape"
    )


def _errors(**codes: str) -> dict[int | str, dict[str, Any]]:
    """OpenAPI `responses` entries: status code -> its meaning, answered as ErrorOut (422:
    UnprocessableOut)."""
    return {
        int(code[1:]): {
            "model": UnprocessableOut if code == "_422" else ErrorOut,
            "description": why,
        }
        for code, why in codes.items()
    }


router = APIRouter(
    prefix="/v1",
    responses=_errors(
        _401="missing API key or session token (with an API key configured)",
        _403="wrong API key or token, or (with an API key configured) no such session",
        _413="request body over the server's max_body_bytes",
    ),
)
SESSION_ERRORS = _errors(_404="no such session (server without an API key)")


class Embedding(BaseModel):
    model: str
    dim: int


def _knobs_model() -> type[BaseModel]:
    """A pydantic model of the knobs, generated from app.config.Knobs (documented once)."""
    import dataclasses

    from pydantic import create_model

    from app.config import Knobs, knob_docs

    docs = knob_docs()
    fields = {
        f.name: (f.type, Field(getattr(Knobs(), f.name), description=docs.get(f.name)))
        for f in dataclasses.fields(Knobs)
    }
    return create_model("Knobs", **fields)


def _knob_changes_schema() -> dict[str, Any]:
    """JSON schema of a knob-changes body: known knobs only, each of its type and range.

    Validation itself stays in app.config.updated_knobs (one place, and it names the knob of
    a bad value); it also takes numbers as strings and lists as comma-separated strings,
    which is what the device's command-line flags send."""
    import dataclasses

    from app.config import KNOB_RANGES, Knobs, knob_docs

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
        else:
            lo, hi = KNOB_RANGES[f.name]
            kind = "integer" if isinstance(default, int) else "number"
            prop = {"type": kind, "minimum": lo, "maximum": hi}
            if default is None:
                prop = {"anyOf": [prop, {"type": "null"}]}
        properties[f.name] = {**prop, "description": docs.get(f.name, "")}
    return {"type": "object", "properties": properties, "additionalProperties": False}


KNOB_CHANGES_SCHEMA = _knob_changes_schema()


KnobsOut = _knobs_model()


class LatencySummary(BaseModel):
    p50: float | None
    p95: float | None


class SessionStats(BaseModel):
    session_id: str
    name: str
    mode: str
    perception: str = Field(description="Perception backend mapping the session's keyframes")
    created_at: float
    frames: int = Field(description="Valid frames received")
    keyframes: int = Field(description="Keyframes mapped")
    dropped_frames: int = Field(description="Keyframes superseded by newer ones before mapping")
    objects: int = Field(description="Confirmed objects")
    fps: float = Field(description="Frames per second over the last 60 frames")
    bytes_in: dict[str, int] = Field(
        description="Upstream payload bytes by kind (rgb, depth, detections)"
    )
    bytes_out: dict[str, int] = Field(description="Downstream update bytes")
    mapping_latency_ms: LatencySummary = Field(
        description="Server time per mapped keyframe: decode + perception + mapping + delta"
    )
    update_seq: int = Field(description="Sequence number of the newest map change")
    subscribers: int
    embedding: Embedding
    knobs: KnobsOut


class CreateSession(BaseModel):
    name: str | None = Field(None, max_length=200, description="Human-readable name")
    mode: Literal["semanticxr", "baseline"] = Field("semanticxr", description="System organisation")
    knobs: dict[str, Any] = Field(
        default_factory=dict,
        description="Knob overrides (see GET knobs)",
        json_schema_extra=KNOB_CHANGES_SCHEMA,
    )
    perception: str | None = Field(
        None,
        max_length=100,
        description="Perception backend: detections or one the server loaded with "
        "--perception (default: the first of those)",
    )


class CreatedSession(BaseModel):
    session_id: str
    token: str = Field(description="Bearer token for everything under this session; shown once")
    embedding: Embedding
    knobs: KnobsOut
    protocol: int = Field(
        protocol.PROTOCOL_VERSION, description="Wire protocol version of the server"
    )


class SessionSummary(BaseModel):
    session_id: str
    name: str
    mode: str
    objects: int
    frames: int
    keyframes: int
    fps: float
    update_seq: int


class ObjectOut(BaseModel):
    id: int
    version: int
    label: str
    bbox: list[float] = Field(description="[x0, y0, z0, x1, y1, z1] metres, world frame")
    centroid: list[float]
    n_obs: int
    points: list[list[float]] | None = Field(
        None, description="[[x, y, z], ...] at client resolution"
    )


class QueryResult(BaseModel):
    id: int
    label: str
    score: float = Field(description="Cosine similarity of the query and the object's embedding")
    bbox: list[float]
    centroid: list[float]
    points: list[list[float]] | None = None


class QueryAnswer(BaseModel):
    text: str
    results: list[QueryResult]
    latency_ms: float


def manager(request: Request) -> SessionManager:
    return request.app.state.manager


def session_for(request: Request, sid: str) -> Session:
    return authorize_session(manager(request), sid, bearer(request.headers))


def _object_record(obj: MapObject, session: Session, with_points: bool) -> protocol.ObjectRecord:
    points = client_points(obj, session.knobs.max_object_points_client) if with_points else None
    return protocol.ObjectRecord(
        id=obj.id,
        version=obj.version,
        label=obj.label,
        bbox=obj.bbox,
        centroid=obj.centroid,
        n_obs=obj.n_obs,
        points=points,
    )


@router.post(
    "/sessions",
    status_code=201,
    response_model=CreatedSession,
    dependencies=[Depends(require_api_key)],
    summary="Create a session",
    responses=_errors(
        _400="the body is not JSON",
        _422="an unknown knob, a knob value of the wrong type or out of range, or a "
        "perception backend the server did not load",
        _503="the server holds its maximum of sessions",
    ),
)
def create_session(body: CreateSession, request: Request) -> dict:
    try:
        session, token = manager(request).create(body.name, body.mode, body.knobs, body.perception)
    except (KnobError, UnknownBackendError) as exc:
        raise HTTPException(422, str(exc)) from None
    except OverflowError as exc:
        raise HTTPException(503, str(exc)) from None
    encoder = session.engine.encoder
    return protocol.SessionCreated(
        session_id=session.id,
        token=token,
        embedding=protocol.EmbeddingInfo(encoder.model_id, encoder.dim),
        knobs=knobs_to_dict(session.knobs),
    ).to_json()


@router.get(
    "/sessions",
    response_model=list[SessionSummary],
    dependencies=[Depends(require_api_key)],
    summary="List sessions",
)
def list_sessions(request: Request) -> list[dict]:
    sessions = list(manager(request).sessions.values())
    return [protocol.SessionSummary.from_stats(s.stats()).to_json() for s in sessions]


@router.get(
    "/sessions/{sid}",
    response_model=SessionStats,
    summary="Session statistics",
    responses=SESSION_ERRORS,
)
def get_session(sid: str, request: Request) -> dict:
    return protocol.SessionStats.from_stats(session_for(request, sid).stats()).to_json()


@router.get(
    "/sessions/{sid}/knobs",
    response_model=KnobsOut,
    summary="Knobs in force",
    responses=SESSION_ERRORS,
)
def get_knobs(sid: str, request: Request) -> dict:
    return knobs_to_dict(session_for(request, sid).knobs)


@router.patch(
    "/sessions/{sid}/knobs",
    response_model=KnobsOut,
    summary="Change knobs at run time",
    responses=SESSION_ERRORS
    | _errors(
        _400="the body is not JSON",
        _422="an unknown knob, or a knob value of the wrong type or out of range",
    ),
    description="Body: {knob: value, ...}. 422 names an unknown knob or a bad value.",
)
def patch_knobs(
    sid: str,
    request: Request,
    changes: Annotated[dict[str, Any], Body(json_schema_extra=KNOB_CHANGES_SCHEMA)],
) -> dict:
    session = session_for(request, sid)
    try:
        return knobs_to_dict(manager(request).set_knobs(session, changes))
    except KnobError as exc:
        raise HTTPException(422, str(exc)) from None


@router.get(
    "/sessions/{sid}/objects",
    response_model=list[ObjectOut],
    response_model_exclude_none=True,
    summary="Confirmed objects",
    responses=SESSION_ERRORS,
)
def list_objects(
    sid: str, request: Request, points: bool = Query(False, description="include points")
) -> list[dict]:
    session = session_for(request, sid)
    return [_object_record(o, session, points).to_json() for o in session.objects()]


@router.get(
    "/sessions/{sid}/query",
    response_model=QueryAnswer,
    response_model_exclude_none=True,
    summary="Natural-language query, best matches first",
    responses=SESSION_ERRORS,
)
def query(
    sid: str,
    request: Request,
    text: str = Query(
        ..., min_length=1, max_length=MAX_QUERY_CHARS, description="what to look for"
    ),
    k: int = Query(5, ge=1, description="how many results (at most the server's max_query_k)"),
    points: bool = Query(True, description="include each result's points"),
) -> dict:
    session = session_for(request, sid)
    max_k = manager(request).settings.max_query_k
    if k > max_k:
        raise HTTPException(422, f"k: {k} is over this server's limit of {max_k}")
    t0 = time.perf_counter()
    hits = session.query(text, k)
    results = []
    for hit in hits:
        record = _object_record(hit.object, session, points)
        results.append(
            protocol.QueryHitRecord(
                id=record.id,
                label=record.label,
                score=hit.score,
                bbox=record.bbox,
                centroid=record.centroid,
                points=record.points,
            )
        )
    latency_ms = (time.perf_counter() - t0) * 1e3
    manager(request).metrics.observe_ms("semanticxr_query_latency_ms", latency_ms)
    return protocol.QueryResult(text=text, results=results, latency_ms=latency_ms).to_json()


@router.delete(
    "/sessions/{sid}",
    status_code=204,
    summary="Delete a session and its map",
    responses=SESSION_ERRORS,
)
def delete_session(sid: str, request: Request) -> Response:
    session_for(request, sid)
    manager(request).delete(sid)
    return Response(status_code=204)
