"""/docs that render offline: Swagger UI served from the `swagger-ui-py` package's assets
(FastAPI's self-hosting recipe); in /openapi.json, the security schemes behind its Authorize
button (the server's API key and a session's token, both `Authorization: Bearer`) and the
links from a new session to every operation on it, which API fuzzers follow."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path
from typing import Any

from fastapi import FastAPI
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles

ASSETS_URL = "/docs-assets"
"""Where the Swagger UI bundle, stylesheet and icon are served."""

SESSION_PATH = "{sid}"
"""The path parameter of every operation on one session."""
SECURITY_SCHEMES = {
    "apiKey": {
        "type": "http",
        "scheme": "bearer",
        "description": "The server's API key (--api-key): creates and lists sessions, "
        "imports maps, reads /metrics, and opens every session. Needed only where the "
        "server was started with one: without it the server runs open.",
    },
    "sessionToken": {
        "type": "http",
        "scheme": "bearer",
        "description": "A session's token, from POST /v1/sessions or /v1/sessions/import "
        "(shown once): everything under /v1/sessions/{sid}. Needed only where the server "
        "has an API key.",
    },
}


def swagger_ui_assets() -> Path:
    """The Swagger UI dist inside the swagger-ui-py package (found without importing it)."""
    spec = importlib.util.find_spec("swagger_ui")
    if spec is None or spec.origin is None:
        raise RuntimeError("the swagger-ui-py package is missing (pip install swagger-ui-py)")
    return Path(spec.origin).parent / "static"


def add_security(schema: dict[str, Any]) -> dict[str, Any]:
    """The OpenAPI document with SECURITY_SCHEMES and each operation's requirement: a
    session's token or the API key under /v1/sessions/{sid}; the API key elsewhere in /v1
    and for /metrics; nothing for /healthz, nor for an operation that declares its own
    (`openapi_extra={"security": []}`: public, e.g. a text tower by its hash)."""
    schema.setdefault("components", {})["securitySchemes"] = SECURITY_SCHEMES
    for path, operations in schema.get("paths", {}).items():
        if SESSION_PATH in path:
            security = [{"sessionToken": []}, {"apiKey": []}]
        elif path.startswith("/v1/") or path == "/metrics":
            security = [{"apiKey": []}]
        else:
            continue
        for operation in operations.values():
            operation.setdefault("security", security)
    return schema


def add_session_links(schema: dict[str, Any]) -> dict[str, Any]:
    """Links in the 201 answer of every operation that creates a session (answers
    SessionCreated) to every operation under /v1/sessions/{sid} that needs no other path
    parameter (an object's history needs an object id), both found in `schema`'s
    paths (generated from the routes, so a new route gets its link): `sid` from the answer's
    session_id and, where the operation takes the session token (add_security), that token
    as the bearer credential."""
    targets = {
        _link_name(method, path): operation
        for path, operations in schema.get("paths", {}).items()
        if SESSION_PATH in path and re.findall(r"{(\w+)}", path) == ["sid"]  # a link gives sid only
        for method, operation in operations.items()
    }
    links = {
        name: {
            "operationId": operation["operationId"],
            "parameters": {
                "sid": "$response.body#/session_id",
                **(
                    {"header.Authorization": "Bearer {$response.body#/token}"}
                    if {"sessionToken": []} in operation.get("security", [])
                    else {}
                ),
            },
            "description": f"On the new session: {operation.get('summary', name)}",
        }
        for name, operation in sorted(targets.items())
    }
    for operations in schema.get("paths", {}).values():
        for operation in operations.values():
            created = operation.get("responses", {}).get("201", {})
            if _answers_session_created(created):
                created["links"] = links
    return schema


def _link_name(method: str, path: str) -> str:
    """`get`, `/v1/sessions/{sid}/knobs` -> `getKnobs`; `delete`, `/v1/sessions/{sid}` ->
    `deleteSession`."""
    tail = path.split(SESSION_PATH, 1)[1].strip("/")
    words = [word for word in re.split(r"[^A-Za-z0-9]+", tail) if word] or ["session"]
    return method.lower() + "".join(word.capitalize() for word in words)


def _answers_session_created(response: dict[str, Any]) -> bool:
    schema = response.get("content", {}).get("application/json", {}).get("schema", {})
    return schema.get("$ref", "").endswith("/SessionCreated")


def install_docs(app: FastAPI) -> None:
    """GET /docs (Swagger UI from local assets), and the security schemes and session links
    in /openapi.json;
    the app must be made with docs_url=None and redoc_url=None (their pages load a CDN)."""
    app.mount(ASSETS_URL, StaticFiles(directory=swagger_ui_assets()), name="swagger-ui")
    generate = app.openapi

    def openapi() -> dict[str, Any]:
        schema = generate()  # cached by FastAPI after the first call
        if "securitySchemes" not in schema.get("components", {}):
            add_session_links(add_security(schema))
        return schema

    app.openapi = openapi  # type: ignore[method-assign]

    @app.get("/docs", include_in_schema=False)
    def docs() -> HTMLResponse:
        return get_swagger_ui_html(
            openapi_url=app.openapi_url or "/openapi.json",
            title=f"{app.title} API",
            swagger_js_url=f"{ASSETS_URL}/swagger-ui-bundle.js",
            swagger_css_url=f"{ASSETS_URL}/swagger-ui.css",
            swagger_favicon_url=f"{ASSETS_URL}/favicon-32x32.png",
            swagger_ui_parameters={"persistAuthorization": True},
        )
