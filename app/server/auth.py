"""Authentication: an API key for the session list, a token per session for the rest.

With no API key configured the server runs open (local development) and says so at start.
A wrong token and an unknown session look the same from outside (403), so a token never
reveals whether a session exists. Access is checked on the session's stored record, before
its map is loaded: a caller who may not use a session never costs a load.
"""

from __future__ import annotations

import hmac

from fastapi import HTTPException, Request

from app.server.sessions import (
    STORAGE_RETRY_AFTER_S,
    ResidentSessionsBusy,
    Session,
    SessionManager,
    token_matches,
)
from app.server.towers import MissingTowerError
from app.store import SessionHeld, StoreUnavailableError


def bearer(request_headers, query_params=None) -> str | None:
    """The credential of `Authorization: Bearer <credential>`; else, where `query_params` is
    given (WebSocket handshakes only: browsers cannot set headers on them), `?token=`.
    REST takes the header only, so credentials never sit in URLs that proxies log."""
    header = request_headers.get("authorization", "")
    if header.lower().startswith("bearer "):
        return header[7:].strip()
    return None if query_params is None else query_params.get("token")


def require_api_key(request: Request) -> None:
    key = request.app.state.settings.api_key
    if key is None:
        return
    token = bearer(request.headers)
    if token is None:
        raise HTTPException(
            401,
            "missing API key (Authorization: Bearer <key>)",
            headers={"WWW-Authenticate": "Bearer"},
        )
    if not hmac.compare_digest(token.encode(), key.encode()):
        raise HTTPException(403, "wrong API key")


def check_session_access(manager: SessionManager, sid: str, token: str | None) -> None:
    """Raise HTTPException unless the caller may use session `sid` (its record is read, not
    its map): 503 with Retry-After when it is not resident and the store cannot be read."""
    key = manager.settings.api_key
    try:
        record = manager.record(sid)
    except StoreUnavailableError as exc:  # not resident, and the store cannot say
        raise retry_later(exc) from None
    if key is None:
        if record is None:
            raise HTTPException(404, f"no session {sid!r}")
        return
    if token is None:
        raise HTTPException(
            401,
            "missing session token (Authorization: Bearer <token>)",
            headers={"WWW-Authenticate": "Bearer"},
        )
    if record is None or not (
        token_matches(record, token) or hmac.compare_digest(token.encode(), key.encode())
    ):
        raise HTTPException(403, "wrong token for this session")


def authorize_session(manager: SessionManager, sid: str, token: str | None) -> Session:
    """The session, if the caller may use it, loaded if need be and in use until
    `manager.release(session)` (call from a thread: loading reads the store). Raises
    HTTPException otherwise: as `check_session_access`, or 503 with Retry-After when there
    is no room to load it now (`retry_later`)."""
    check_session_access(manager, sid, token)
    try:
        return manager.acquire(sid)
    except KeyError:  # deleted since the check: as if it never was
        check_session_access(manager, sid, token)
        raise
    except (ResidentSessionsBusy, StoreUnavailableError, SessionHeld) as exc:
        raise retry_later(exc) from None
    except MissingTowerError as exc:  # lasts until the server holds the tower again
        raise HTTPException(409, str(exc)) from None


def retry_later(exc: ResidentSessionsBusy | StoreUnavailableError | SessionHeld) -> HTTPException:
    """503 with Retry-After for a session that cannot be loaded or created now: every
    resident session is busy, the store cannot save the one that would make room, or (on a
    map shard) another live shard holds it (`X-SemanticXR-Owner` names that shard: a gateway
    routes there)."""
    if isinstance(exc, SessionHeld):
        return HTTPException(
            503,
            f"map shard {exc.owner} holds this session; ask that shard (a gateway routes "
            f"there by itself)",
            headers={"Retry-After": "1", "X-SemanticXR-Owner": exc.owner},
        )
    if isinstance(exc, ResidentSessionsBusy):
        return HTTPException(503, str(exc), headers={"Retry-After": str(exc.retry_after_s)})
    return HTTPException(
        503,
        "the server cannot save changes now (storage unavailable), so it cannot make room "
        "for this session in memory; retry later",
        headers={"Retry-After": str(STORAGE_RETRY_AFTER_S)},
    )
