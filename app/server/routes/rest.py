"""REST: sessions, knobs, objects, queries (docs/protocol.md, "REST")."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Annotated, Any, Literal

import numpy as np
from fastapi import APIRouter, Body, Depends, HTTPException, Query, Request, Response
from fastapi import Path as FastApiPath
from fastapi.responses import StreamingResponse

from app import protocol
from app.answering.rerank import RERANK_POOL
from app.answering.things import RelationalHit
from app.answering.things import is_match as is_relational_match
from app.config import KnobError, knobs_to_dict
from app.errors import InputError
from app.mapping.export import export_change, export_json_chunks, exported_stay, ply_bytes
from app.mapping.object import Change, MapObject
from app.mapping.places import describe_places
from app.mapping.publish import client_points
from app.mapping.validation import MAX_WORLD_M
from app.perception import UnknownBackendError
from app.protocol.rest import MapExport
from app.semantics import TextEncoder
from app.semantics.static import is_static_model_id
from app.server.auth import (
    authorize_session,
    bearer,
    check_session_access,
    require_api_key,
    retry_later,
)
from app.server.routes.depends import Manager
from app.server.sessions import ResidentSessionsBusy, Session, SessionManager, StoredSessionsFull
from app.server.sessions.engines import embedding_info
from app.store import StoreUnavailableError

MAX_INT64 = 2**63 - 1
"""The largest id or seq a store keeps (a 64-bit integer): past it a parameter is a 422."""


def _errors(**codes: str) -> dict[int | str, dict[str, Any]]:
    """OpenAPI `responses` entries: status code -> its meaning, answered as ErrorBody (422:
    UnprocessableBody)."""
    return {
        int(code[1:]): {
            "model": protocol.UnprocessableBody if code == "_422" else protocol.ErrorBody,
            "description": why,
        }
        for code, why in codes.items()
    }


ROUTER_ERRORS = _errors(
    _401="missing API key or session token (with an API key configured)",
    _403="wrong API key or token, or (with an API key configured) no such session",
    _413="request body over the server's max_body_bytes",
)
"""What every /v1 call may answer."""
router = APIRouter(prefix="/v1", responses=ROUTER_ERRORS)
SESSION_ERRORS = _errors(
    _404="no such session (server without an API key)",
    _422="a query parameter of the wrong type or out of range",
    _503="the session is not in memory and there is no room to load it now: every session "
    "held in memory is in use (see Retry-After)",
)
CREATE_ERRORS = _errors(
    _409="the server stores its maximum of sessions (--max-sessions): delete some first",
    _503="no room in memory for another session now: every session held in memory is in use "
    "(see Retry-After)",
)


@contextmanager
def session_in_use(manager: SessionManager, request: Request, sid: str) -> Iterator[Session]:
    """The session the caller may use, loaded if need be and kept in memory until the block
    ends (HTTPException otherwise: 401/403/404, or 503 with Retry-After). Route functions
    are plain `def`s, so FastAPI runs them, and loads, in a worker thread."""
    session = authorize_session(manager, sid, bearer(request.headers))
    try:
        yield session
    finally:
        manager.release(session)


def created_or_refused(create) -> tuple[Session, str]:
    """`create()` (a creation or an import), its refusals as HTTP answers.

    409, not 507 or 503, when the store is full (StoredSessionsFull): the condition lasts
    until sessions are deleted, so "retry later" (503 + Retry-After) would be a lie, and it
    is the caller's to resolve by deleting sessions (a conflict with the server's state, a
    4xx); every 5xx but a documented 503 counts as a server bug in the API contract."""
    try:
        return create()
    except (KnobError, UnknownBackendError, InputError) as exc:
        raise HTTPException(422, str(exc)) from None
    except StoredSessionsFull as exc:
        raise HTTPException(409, str(exc)) from None
    except (ResidentSessionsBusy, StoreUnavailableError) as exc:
        raise retry_later(exc) from None


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
        state=obj.state,
        first_seen_t=obj.first_seen_t,
        last_seen_t=obj.last_seen_t,
    )


INCLUDE_DOC = "`removed`: removed objects too (the living map's history: where things were)"
"""What `include=` takes on objects and queries."""


def _places_of(
    session: Session, points: list, exclude: list[int]
) -> list[protocol.PlaceRecord | None]:
    """Where each point is, in words, against the session's present map (`exclude`: each
    point's own object), along the session's up."""
    if not points:
        return []
    places = describe_places(np.asarray(points, np.float64), session.objects(), session.up, exclude)
    return [
        None if p is None else protocol.PlaceRecord(relation=p.relation, id=p.id, label=p.label)
        for p in places
    ]


def _change_records(session: Session, changes: list[Change]) -> list[protocol.ChangeRecord]:
    """Changes as listed: each as exported, with where it happened (its `to`, else `from`)."""
    where = [c.to_xyz if c.to_xyz is not None else c.from_xyz for c in changes]
    located = [i for i, xyz in enumerate(where) if xyz is not None]
    places: list[protocol.PlaceRecord | None] = [None] * len(changes)
    described = _places_of(session, [where[i] for i in located], [changes[i].id for i in located])
    for i, place in zip(located, described, strict=True):
        places[i] = place
    return [
        protocol.ChangeRecord.model_validate({**export_change(c), "place": place})
        for c, place in zip(changes, places, strict=True)
    ]


def _finite(name: str, value: float | None) -> float | None:
    """422 naming the parameter for a NaN or infinite bound (FastAPI parses "nan")."""
    if value is not None and not math.isfinite(value):
        raise HTTPException(422, f"{name}: must be a finite number of seconds, got {value}")
    return value


def _created(session: Session, token: str) -> protocol.SessionCreated:
    """The 201 answer of a new session (created or imported): the only time its token shows."""
    return protocol.SessionCreated(
        session_id=session.id,
        token=token,
        embedding=embedding_info(session.engine.encoder, session.record),
        knobs=knobs_to_dict(session.knobs),
    )


@router.post(
    "/sessions",
    status_code=201,
    response_model=protocol.SessionCreated,
    dependencies=[Depends(require_api_key)],
    summary="Create a session",
    responses=CREATE_ERRORS
    | _errors(
        _400="the body is not JSON",
        _422="an unknown knob, a knob value of the wrong type or out of range, a "
        "perception backend the server did not load, an `up` that is not an axis, or a "
        "`text_tower` that is not minilm or static (static: detections sessions only)",
    ),
)
def create_session(body: protocol.CreateSession, manager: Manager) -> protocol.SessionCreated:
    """A static `text_tower` waits for the server's static tower, distilled on the first
    need (minutes, once), unless the server was started with --static-tower."""
    session, token = created_or_refused(
        lambda: manager.create(
            body.name, body.mode, body.knobs, body.perception, body.up, body.text_tower
        )
    )
    return _created(session, token)


@router.get(
    "/sessions",
    response_model=list[protocol.SessionSummary],
    dependencies=[Depends(require_api_key)],
    summary="List stored sessions, in memory or not (no map is loaded)",
)
def list_sessions(manager: Manager) -> list[protocol.SessionSummary]:
    return manager.list_sessions()


@router.get(
    "/sessions/{sid}",
    response_model=protocol.SessionStats,
    summary="Session statistics",
    responses=SESSION_ERRORS,
)
def get_session(sid: str, request: Request, manager: Manager) -> protocol.SessionStats:
    with session_in_use(manager, request, sid) as session:
        return session.stats()


@router.get(
    "/sessions/{sid}/knobs",
    response_model=protocol.KnobsBody,
    summary="Knobs in force",
    responses=SESSION_ERRORS,
)
def get_knobs(sid: str, request: Request, manager: Manager) -> dict:
    with session_in_use(manager, request, sid) as session:
        return knobs_to_dict(session.knobs)


@router.patch(
    "/sessions/{sid}/knobs",
    response_model=protocol.KnobsBody,
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
    manager: Manager,
    changes: Annotated[dict[str, Any], Body(json_schema_extra=protocol.KNOB_CHANGES_SCHEMA)],
) -> dict:
    with session_in_use(manager, request, sid) as session:
        try:
            return knobs_to_dict(manager.set_knobs(session, changes))
        except KnobError as exc:
            raise HTTPException(422, str(exc)) from None


@router.get(
    "/sessions/{sid}/objects",
    response_model=list[protocol.ObjectRecord],
    summary="Confirmed objects",
    responses=SESSION_ERRORS,
)
def list_objects(
    sid: str,
    request: Request,
    manager: Manager,
    points: bool = Query(False, description="include points"),
    include: Literal["removed"] | None = Query(None, description=INCLUDE_DOC),
) -> list[protocol.ObjectRecord]:
    with session_in_use(manager, request, sid) as session:
        objects = session.objects()
        if include == "removed":
            removed = manager.removed_objects(session)
            objects = sorted([*objects, *removed], key=lambda o: o.id)
        return [_object_record(o, session, points) for o in objects]


@router.get(
    "/sessions/{sid}/objects/{object_id}/history",
    response_model=protocol.ObjectHistory,
    summary="Where an object has been (its stays), present or removed",
    responses={
        **SESSION_ERRORS,
        **_errors(_404="no such session (server without an API key), or no such object"),
    },
)
def object_history(
    sid: str,
    request: Request,
    manager: Manager,
    object_id: int = FastApiPath(ge=-MAX_INT64 - 1, le=MAX_INT64, description="the object's id"),
) -> protocol.ObjectHistory:
    with session_in_use(manager, request, sid) as session:
        obj = manager.find_object(session, object_id)
    if obj is None:
        raise HTTPException(404, f"object {object_id} is not in this session's map or history")
    return protocol.ObjectHistory(
        id=obj.id,
        label=obj.label,
        state=obj.state,
        first_seen_t=obj.first_seen_t,
        last_seen_t=obj.last_seen_t,
        stays=[exported_stay(stay) for stay in obj.stays],
    )


@router.get(
    "/sessions/{sid}/changes",
    response_model=protocol.ChangeList,
    summary="What the map concluded about the world (added, moved, removed), oldest first",
    responses=SESSION_ERRORS,
)
def list_changes(
    sid: str,
    request: Request,
    manager: Manager,
    since_t: float | None = Query(None, description="from this frame `t` on (seconds)"),
    until_t: float | None = Query(None, description="up to this frame `t` (seconds)"),
    since_seq: int | None = Query(
        None,
        ge=0,
        le=MAX_INT64,
        description="committed after this update seq (t may go backwards)",
    ),
    kind: Literal["added", "moved", "removed"] | None = Query(None, description="one kind"),
    limit: int = Query(1000, ge=1, le=10_000, description="the newest this many"),
) -> protocol.ChangeList:
    _finite("since_t", since_t)
    _finite("until_t", until_t)
    with session_in_use(manager, request, sid) as session:
        changes = manager.changes(
            session,
            since_t=since_t,
            until_t=until_t,
            since_seq=since_seq,
            kinds=None if kind is None else [kind],
            limit=limit,
        )
        now_t = session.engine.last_t
        records = _change_records(session, changes)
    return protocol.ChangeList(changes=records, now_t=now_t)


MAX_FROM_CHARS = 100
"""Longest `from` a query may carry (three numbers)."""


QueryK = Annotated[
    int, Query(ge=1, description="how many results (at most the server's max_query_k)")
]
QueryPoints = Annotated[bool, Query(description="include each result's points")]
QueryInclude = Annotated[Literal["removed"] | None, Query(description=INCLUDE_DOC)]
QueryFrom = Annotated[
    str | None,
    Query(
        alias="from",
        max_length=MAX_FROM_CHARS,
        description="where the asker stands, 'x,y,z' in world metres, for questions seen "
        "from the asker ('the lamp closest to me', 'the chair on the left of the sofa'); "
        "default: the camera of the session's newest frame",
    ),
]
QueryRerank = Annotated[
    bool,
    Query(
        description="on a static-tower session: re-rank the static tower's best "
        f"{RERANK_POOL} with the tower it was distilled from (MiniLM), which then rates them "
        "too (`ranked_by` says which tower ranked the answer); no effect on other sessions",
    ),
]
"""The query parameters a typed and a spoken question share."""


def checked_query_options(manager: SessionManager, k: int, from_: str | None) -> np.ndarray | None:
    """422 for a k over the server's max_query_k or a bad `from`; the asker's position."""
    max_k = manager.settings.max_query_k
    if k > max_k:
        raise HTTPException(422, f"k: {k} is over this server's limit of {max_k}")
    return None if from_ is None else _position("from", from_)


@router.get(
    "/sessions/{sid}/query",
    response_model=protocol.QueryResult,
    summary="Natural-language query, best matches first",
    responses=SESSION_ERRORS,
)
def query(
    sid: str,
    request: Request,
    manager: Manager,
    text: str = Query(
        ..., min_length=1, max_length=protocol.MAX_QUERY_CHARS, description="what to look for"
    ),
    k: QueryK = 5,
    points: QueryPoints = True,
    include: QueryInclude = None,
    from_: QueryFrom = None,
    rerank: QueryRerank = False,
) -> protocol.QueryResult:
    asker = checked_query_options(manager, k, from_)
    with session_in_use(manager, request, sid) as session:
        teacher = manager.encoder if rerank else None
        return answer_query(manager, session, text, k, points, include, asker, teacher)


def answer_query(
    manager: SessionManager,
    session: Session,
    text: str,
    k: int,
    points: bool,
    include: str | None,
    asker: np.ndarray | None,
    teacher: TextEncoder | None = None,
) -> protocol.QueryResult:
    """The answer to `text` from a session in use: relational when the question says how
    things stand, plain otherwise (or with include=removed); `latency_ms` is its own.
    teacher: on a static-tower session, the tower it was distilled from re-ranks and rates
    (`Session.reranked_query`; relational questions are answered with it whole)."""
    t0 = time.perf_counter()
    if teacher is not None and not is_static_model_id(session.engine.encoder.model_id):
        teacher = None  # a session of the teacher itself: nothing to re-rank
    ranked_by = (teacher or session.engine.encoder).model_id
    # A question about how things stand is answered from the relation index; a plain one
    # (or one whose anchors the map lacks) as always, as is any with include=removed.
    related = session.relational_query(text, k, asker, teacher) if include is None else None
    if related is not None:
        result = _relational_result(session, text, *related, points)
        result.latency_ms = (time.perf_counter() - t0) * 1e3
        result.ranked_by = ranked_by
        manager.metrics.query_latency.observe(result.latency_ms / 1e3)
        return result
    removed = manager.removed_objects(session) if include == "removed" else None
    if teacher is not None:
        hits, rating = session.reranked_query(text, k, teacher, removed)
    else:
        hits, rating = session.rated_query(text, k, removed)
    now_t = session.engine.last_t
    places = _places_of(session, [h.object.centroid for h in hits], [h.object.id for h in hits])
    max_points = session.knobs.max_object_points_client
    results = [
        protocol.QueryHit(
            id=hit.object.id,
            label=hit.object.label,
            score=hit.score,
            relevance=relevance,
            bbox=hit.object.bbox,
            centroid=hit.object.centroid,
            points=client_points(hit.object, max_points) if points else None,
            state=hit.object.state,
            last_seen_t=hit.object.last_seen_t,
            place=place,
        )
        for hit, relevance, place in zip(hits, rating.relevance, places, strict=True)
    ]
    latency_ms = (time.perf_counter() - t0) * 1e3
    manager.metrics.query_latency.observe(latency_ms / 1e3)
    return protocol.QueryResult(
        text=text,
        match=rating.match,
        results=results,
        latency_ms=latency_ms,
        now_t=now_t,
        ranked_by=ranked_by,
    )


def _position(name: str, value: str) -> np.ndarray:
    """'x,y,z' as a float64 [3] point; 422 naming `name` unless it is three finite numbers
    within MAX_WORLD_M of the origin."""
    parts = value.split(",")
    try:
        point = np.array([float(p) for p in parts], np.float64)
    except ValueError:
        point = None
    if point is None or point.shape != (3,) or not np.isfinite(point).all():
        raise HTTPException(422, f"{name}: give three numbers x,y,z in metres, got {value!r}")
    if np.abs(point).max() > MAX_WORLD_M:
        raise HTTPException(422, f"{name}: over {MAX_WORLD_M:g} m from the origin")
    return point


def _relational_result(
    session: Session,
    text: str,
    hits: list[RelationalHit],
    objects: dict[int, MapObject],
    points: bool,
) -> protocol.QueryResult:
    """A relational answer: each hit with its relation; `match` when the best hit's score
    (target relevance x degrees x anchor relevances) reaches relational.MATCH_MIN_SCORE.
    `score` is the target phrase's raw cosine."""
    found = [objects[h.id] for h in hits]
    places = _places_of(session, [o.centroid for o in found], [o.id for o in found])
    max_points = session.knobs.max_object_points_client
    results = [
        protocol.QueryHit(
            id=obj.id,
            label=obj.label,
            score=hit.cosine,
            relevance=hit.relevance,
            bbox=obj.bbox,
            centroid=obj.centroid,
            points=client_points(obj, max_points) if points else None,
            state=obj.state,
            last_seen_t=obj.last_seen_t,
            place=place,
            relation=protocol.rest.HitRelation(
                kind=hit.relation.kind,
                anchors=[
                    protocol.rest.AnchorRecord(id=i, label=label)
                    for i, label in hit.relation.anchors
                ],
                degree=hit.relation.degree,
            ),
        )
        for hit, obj, place in zip(hits, found, places, strict=True)
    ]
    return protocol.QueryResult(
        text=text,
        match=is_relational_match(hits),
        results=results,
        latency_ms=0.0,
        now_t=session.engine.last_t,
    )


@router.delete(
    "/sessions/{sid}",
    status_code=204,
    summary="Delete a session and its map",
    responses=SESSION_ERRORS,
)
def delete_session(sid: str, request: Request, manager: Manager) -> Response:
    check_session_access(manager, sid, bearer(request.headers))  # no map is loaded
    manager.delete(sid)
    return Response(status_code=204)


@router.get(
    "/sessions/{sid}/export",
    summary="Export the map (JSON or binary PLY)",
    responses=SESSION_ERRORS
    | {
        200: {
            "description": "JSON: the session and its confirmed objects at full server "
            "resolution; PLY: their points with per-point object_id and a colour per label",
            "content": {
                "application/json": {"schema": {"$ref": "#/components/schemas/MapExport"}},
                "application/octet-stream": {},
            },
        }
    },
)
def export_map(
    sid: str,
    request: Request,
    manager: Manager,
    format: Literal["json", "ply"] = Query("json", description="json or ply"),
    embeddings: bool = Query(False, description="include each object's embedding (JSON)"),
) -> Response:
    with session_in_use(manager, request, sid) as session:
        # Taken under the map lock; points are replaced, never edited.
        objects, removed_objects, changes = manager.export_contents(session)
        header = {
            "format": protocol.rest.EXPORT_FORMAT,
            "version": protocol.rest.EXPORT_VERSION,
            "session": {
                "name": session.record.name,
                "mode": session.engine.mode,
                "knobs": knobs_to_dict(session.knobs),
                "embedding": embedding_info(session.engine.encoder, session.record).to_json(),
                "perception": session.record.perception,
            },
        }
        if session.record.text_tower != "minilm":  # minilm goes unsaid, as before the field
            header["session"]["text_tower"] = session.record.text_tower
        if session.record.up is not None:  # set or inferred; the default goes unsaid
            header["session"] |= {"up": session.up_axis, "up_source": session.up_source}
    filename = f"semanticxr-{sid}.{format}"
    disposition = {"Content-Disposition": f'attachment; filename="{filename}"'}
    if format == "ply":
        return Response(
            ply_bytes(objects), media_type="application/octet-stream", headers=disposition
        )
    return StreamingResponse(
        export_json_chunks(header, objects, removed_objects, changes, embeddings),
        media_type="application/json",
        headers=disposition,
    )


@router.post(
    "/sessions/import",
    status_code=201,
    response_model=protocol.SessionCreated,
    dependencies=[Depends(require_api_key)],
    summary="Create a session from a JSON export",
    responses=CREATE_ERRORS
    | _errors(
        _400="the body is not JSON",
        _413="the export is bigger than the server's max_body_bytes (start it with a bigger "
        "--max-body-bytes)",
        _422="not a semanticxr-map version 1, an embedding dimension other than the server's, "
        "a number that is not finite, a repeated object id, or a bad knob",
    ),
)
def import_map(body: MapExport, manager: Manager) -> protocol.SessionCreated:
    seen: set[int] = set()
    for i, obj in enumerate(body.objects):
        if obj.id in seen:
            raise HTTPException(422, f"objects[{i}].id: {obj.id} appears twice")
        seen.add(obj.id)
        if np.abs(np.asarray(obj.points)).max() > MAX_WORLD_M:
            raise HTTPException(422, f"objects[{i}].points: over {MAX_WORLD_M:g} m from the origin")
    session, token = created_or_refused(lambda: manager.import_session(body))
    return _created(session, token)
