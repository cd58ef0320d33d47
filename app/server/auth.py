"""Authentication: an API key for the session list, a token per session for the rest.

With no API key configured the server runs open (local development) and says so at start.
A wrong token and an unknown session look the same from outside (403), so a token never
reveals whether a session exists.
"""

from __future__ import annotations

import hmac

from fastapi import HTTPException, Request

from app.server.sessions import Session, SessionManager


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


def authorize_session(manager: SessionManager, sid: str, token: str | None) -> Session:
    """The session if the caller may use it; raises HTTPException otherwise."""
    key = manager.settings.api_key
    session = manager.sessions.get(sid)
    if key is None:
        if session is None:
            raise HTTPException(404, f"no session {sid!r}")
        return session
    if token is None:
        raise HTTPException(
            401,
            "missing session token (Authorization: Bearer <token>)",
            headers={"WWW-Authenticate": "Bearer"},
        )
    if session is None or not (
        session.check_token(token) or hmac.compare_digest(token.encode(), key.encode())
    ):
        raise HTTPException(403, "wrong token for this session")
    return session
