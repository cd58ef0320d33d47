"""The browser pages the server serves itself: the session dashboard at "/", the real-device
WebXR page at "/xr", and their assets under "/static/" (plain files from the repository's
`static/` folder, ES modules with no build step; npm dependencies vendored under
`static/vendor/` by `scripts/vendor_js.sh`).

The pages are public (they hold no data); everything they show comes from the REST API,
which checks the API key or session token the user types in. Routes stay out of the
OpenAPI schema: they are not part of wire protocol v1.
"""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter, HTTPException
from fastapi.responses import FileResponse

# static/ sits next to app/ both in a checkout and in an installed wheel (pyproject ships it
# as data beside the packages), so one path works for editable and regular installs.
STATIC_DIR = Path(__file__).resolve().parents[3] / "static"

CONTENT_TYPES = {
    ".html": "text/html; charset=utf-8",
    ".js": "text/javascript; charset=utf-8",
    ".mjs": "text/javascript; charset=utf-8",
    ".css": "text/css; charset=utf-8",
    ".png": "image/png",
    ".svg": "image/svg+xml",
}
"""What may be served, by suffix; explicit so .js never depends on the host's mimetypes."""

# The pages only talk to this server; the CSP makes that a browser-enforced rule, so a
# label that slipped past escaping still could not load or send anything elsewhere.
SECURITY_HEADERS = {
    "Content-Security-Policy": (
        "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data:; "
        "connect-src 'self'; object-src 'none'; base-uri 'none'; frame-ancestors 'none'"
    ),
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    # Revalidate every load (FileResponse sends ETag/Last-Modified): a new server version's
    # page never runs against a stale app.js.
    "Cache-Control": "no-cache",
}

router = APIRouter(include_in_schema=False)


def _file_response(path: Path) -> FileResponse:
    content_type = CONTENT_TYPES.get(path.suffix)
    if content_type is None or not path.is_file():
        raise HTTPException(404, "not found")
    return FileResponse(path, media_type=content_type, headers=SECURITY_HEADERS)


@router.get("/")
def dashboard() -> FileResponse:
    """The session dashboard (static/index.html)."""
    return _file_response(STATIC_DIR / "index.html")


@router.get("/xr")
def xr_page() -> FileResponse:
    """The real-device page (static/xr/index.html): a WebXR immersive-ar client of wire
    protocol v1. `/xr#session=SID&token=TOKEN` opens a session (a fragment: the token never
    reaches the server's log)."""
    return _file_response(STATIC_DIR / "xr" / "index.html")


@router.get("/static/{name:path}")
def static_file(name: str) -> FileResponse:
    """A file of static/; nothing outside it (no "..", no symlinks out)."""
    root = STATIC_DIR.resolve()
    path = (root / name).resolve()
    if not path.is_relative_to(root):
        raise HTTPException(404, "not found")
    return _file_response(path)
