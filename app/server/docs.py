"""/docs that render offline: Swagger UI served from the `swagger-ui-py` package's assets
(FastAPI's self-hosting recipe), and the OpenAPI security schemes behind its Authorize
button: the server's API key and a session's token, both `Authorization: Bearer`."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Any

from fastapi import FastAPI
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles

ASSETS_URL = "/docs-assets"
"""Where the Swagger UI bundle, stylesheet and icon are served."""

SECURITY_SCHEMES = {
    "apiKey": {
        "type": "http",
        "scheme": "bearer",
        "description": "The server's API key (--api-key): creates and lists sessions, "
        "imports maps, reads /metrics, and opens every session.",
    },
    "sessionToken": {
        "type": "http",
        "scheme": "bearer",
        "description": "A session's token, from POST /v1/sessions (shown once): everything "
        "under /v1/sessions/{sid}.",
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
    and for /metrics; nothing for /healthz."""
    schema.setdefault("components", {})["securitySchemes"] = SECURITY_SCHEMES
    for path, operations in schema.get("paths", {}).items():
        if "{sid}" in path:
            security = [{"sessionToken": []}, {"apiKey": []}]
        elif path.startswith("/v1/") or path == "/metrics":
            security = [{"apiKey": []}]
        else:
            continue
        for operation in operations.values():
            operation["security"] = security
    return schema


def install_docs(app: FastAPI) -> None:
    """GET /docs (Swagger UI from local assets) and the security schemes in /openapi.json;
    the app must be made with docs_url=None and redoc_url=None (their pages load a CDN)."""
    app.mount(ASSETS_URL, StaticFiles(directory=swagger_ui_assets()), name="swagger-ui")
    generate = app.openapi

    def openapi() -> dict[str, Any]:
        schema = generate()  # cached by FastAPI after the first call
        if "securitySchemes" not in schema.get("components", {}):
            add_security(schema)
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
