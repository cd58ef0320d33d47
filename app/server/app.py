"""The FastAPI application: factory, lifespan, routers, limits."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from contextlib import asynccontextmanager

from fastapi import Depends, FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, PlainTextResponse, Response
from starlette.routing import Match

from app import __version__
from app.answering.label_knowledge import label_texts
from app.answering.relevance import rater_for
from app.mapping.engine import limit_numpy_threads
from app.semantics import TextEncoder, get_text_encoder
from app.server.auth import require_api_key
from app.server.docs import install_docs
from app.server.edges import HostOriginMiddleware
from app.server.limits import BodyLimitMiddleware, SocketLimitMiddleware, body_limits
from app.server.metrics import HttpMetricsMiddleware, Metrics, make_metrics
from app.server.routes import answering_data, pages, rest, speech, towers, ws
from app.server.routes.depends import Manager
from app.server.sessions import SessionManager
from app.server.settings import ServerSettings
from app.speech import RecogniserPool, parse_asr
from app.store import open_store, redact_url

log = logging.getLogger("semanticxr")


def warm_up_rating(encoder: TextEncoder) -> None:
    """Make the query rater (the tower's background embeddings are read from the package,
    ~0.1 s; a tower without them embeds the texts, ~20 s on a loaded machine) and read
    WordNet (~0.5 s) now, not in the first query or the first keyframe's delta."""
    rater_for(encoder)
    label_texts("chair")


ERROR_BODY_REF = "#/components/schemas/ErrorBody"
"""The one error body (app.protocol.ErrorBody), as the REST routes document it."""
HEALTH_RETRY_AFTER_S = 2
"""Retry-After (seconds) of a 503 from /healthz; the store is probed every second meanwhile."""


def create_app(
    settings: ServerSettings | None = None, encoder: TextEncoder | None = None
) -> FastAPI:
    """The service; state (store, sessions, encoder) lives from lifespan start to end."""
    settings = settings or ServerSettings.from_env()

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        limit_numpy_threads()
        store = open_store(settings.store_url)
        manager = SessionManager(settings, store, encoder or get_text_encoder(), make_metrics())
        restored = manager.restore()
        app.state.settings, app.state.manager = settings, manager
        # Recogniser processes start, and load, on the first spoken question.
        app.state.speech = RecogniserPool(
            parse_asr(settings.asr), settings.asr_workers, settings.asr_timeout_s
        )
        if settings.api_key is None and settings.https:  # served to the LAN, as a rule
            log.warning(
                "no API key set: anyone on your network can create sessions and read their "
                "maps; start the server with --api-key KEY to require one"
            )
        elif settings.api_key is None:
            log.warning(
                "no API key set: the server runs OPEN (anyone can create and read sessions)"
            )
        log.info("store %s; %d sessions restored", redact_url(settings.store_url), restored)
        storage_watch = asyncio.create_task(manager.watch_storage())
        # Embed the query rater's label vocabulary now (~1 s), not in the first query.
        rater_warm_up = asyncio.create_task(asyncio.to_thread(warm_up_rating, manager.encoder))
        try:
            yield
        finally:
            storage_watch.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await storage_watch
            with contextlib.suppress(Exception):  # a broken encoder fails its queries instead
                await rater_warm_up
            app.state.speech.close()
            manager.close()
            store.close()

    app = FastAPI(
        title="SemanticXR",
        version=__version__,
        description="Real-time, open-vocabulary 3D semantic mapping for XR devices (wire protocol v1).",
        lifespan=lifespan,
        docs_url=None,  # install_docs serves /docs from local assets: no CDN
        redoc_url=None,
    )
    install_docs(app)

    app.add_middleware(HttpMetricsMiddleware)  # innermost: it sees the matched route
    app.add_middleware(
        BodyLimitMiddleware, **body_limits(settings.max_body_bytes, settings.max_audio_bytes)
    )
    app.add_middleware(SocketLimitMiddleware, max_sockets=settings.max_connections)
    allowed_hosts = settings.allowed_host_list()
    if allowed_hosts is None and settings.allowed_hosts is None:
        log.warning(
            "bound to %s: every Host header is served; pass --allowed-hosts to restrict it",
            settings.host,
        )
    # Outermost: a request for a foreign Host is refused before anything reads it.
    app.add_middleware(
        HostOriginMiddleware,
        allowed_hosts=allowed_hosts,
        allowed_origins=settings.allowed_origin_list(),
    )

    @app.exception_handler(RequestValidationError)
    async def unprocessable(request: Request, exc: RequestValidationError) -> JSONResponse:
        """422 in the one error format, {"detail": "<where>: <what>; ..."}, as knob and
        setting errors answer (FastAPI's own is a list of {loc, msg, type})."""
        problems = [
            f"{'.'.join(str(part) for part in error['loc'] if part != 'body') or 'body'}: "
            f"{error['msg']}"
            for error in exc.errors()
        ]
        return JSONResponse({"detail": "; ".join(problems)[:2000]}, 422)

    @app.exception_handler(405)
    async def method_not_allowed(request: Request, exc: Exception) -> JSONResponse:
        """405 naming every method the path takes (Starlette's own lists only the first
        route that matched the path, e.g. GET but not DELETE for a session). A path the
        OpenAPI document names literally takes the methods it documents: GET
        /v1/sessions/import reaches GET /v1/sessions/{sid} only to find no such session."""
        documented = app.openapi()["paths"].get(request.url.path)
        allowed = [
            method
            for method in ("GET", "HEAD", "POST", "PUT", "PATCH", "DELETE")
            if (
                (method.lower() in documented or (method == "HEAD" and "get" in documented))
                if documented is not None
                else any(
                    route.matches({**request.scope, "method": method})[0] == Match.FULL
                    for route in app.router.routes
                )
            )
        ]
        return JSONResponse(
            {"detail": f"{request.method} is not allowed here; allowed: {', '.join(allowed)}"},
            405,
            headers={"Allow": ", ".join(allowed)},
        )

    @app.get(
        "/healthz",
        summary="Readiness: 200, or 503 with the reason while storage fails",
        responses={503: {"description": "Not ready (e.g. the store refuses writes)"}},
    )
    def healthz(manager: Manager) -> JSONResponse:
        reason = manager.storage.reason
        if reason is not None:
            return JSONResponse(
                {"status": "unavailable", "reason": reason, "version": __version__},
                503,
                headers={"Retry-After": str(HEALTH_RETRY_AFTER_S)},
            )
        return JSONResponse({"status": "ok", "version": __version__})

    @app.get(
        "/metrics",
        response_class=PlainTextResponse,
        summary="Prometheus metrics (needs the API key where the server has one)",
        dependencies=[Depends(require_api_key)],
        responses={  # JSON, not the text/plain of the metrics themselves
            code: {
                "description": why,
                "content": {"application/json": {"schema": {"$ref": ERROR_BODY_REF}}},
            }
            for code, why in (
                (401, "missing API key (with one configured)"),
                (403, "wrong API key"),
            )
        },
    )
    def metrics(manager: Manager) -> Response:
        sessions = list(manager.sessions.values())
        manager.metrics.sessions.set(len(sessions))
        manager.metrics.subscribers.set(sum(s.subscribers for s in sessions))
        return Response(manager.metrics.render(), media_type=Metrics.CONTENT_TYPE)

    app.include_router(rest.router)
    app.include_router(speech.router)
    app.include_router(towers.router)
    app.include_router(ws.router)
    app.include_router(pages.router)
    app.include_router(answering_data.router)
    return app
