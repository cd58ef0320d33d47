"""`GET /v1/text-towers/{sha256}`: a static text tower's file by its SHA-256, for the devices
and the page of the sessions embedding with it (`embedding.sha256`). Public: the file is
named by its content and holds no user data, so it is cached for good (`immutable`)."""

from __future__ import annotations

from fastapi import APIRouter, HTTPException, Request
from fastapi.responses import Response

from app.protocol.rest import ErrorBody, UnprocessableBody
from app.server.routes.depends import Manager
from app.store.rows import is_sha256

TOWER_MEDIA_TYPE = "application/octet-stream"
CACHE_FOREVER = "public, max-age=31536000, immutable"
"""A tower's bytes never change under its hash."""

router = APIRouter(prefix="/v1")


@router.get(
    "/text-towers/{sha256}",
    summary="A static text tower's file, by its SHA-256 (public, cacheable for good)",
    response_class=Response,
    openapi_extra={"security": []},
    responses={
        200: {
            "description": "The tower file (msgpack, app/semantics/static.py), gzipped "
            "(Content-Encoding: gzip) when Accept-Encoding takes gzip; ETag is the quoted "
            "SHA-256, with '.gz' for the gzipped form",
            "content": {TOWER_MEDIA_TYPE: {"schema": {"type": "string", "format": "binary"}}},
        },
        304: {"description": "If-None-Match names this tower: the copy held is current"},
        404: {"model": ErrorBody, "description": "this server holds no tower of that hash"},
        422: {
            "model": UnprocessableBody,
            "description": "sha256 is not 64 lowercase hex digits",
        },
    },
)
def text_tower(sha256: str, request: Request, manager: Manager) -> Response:
    if not is_sha256(sha256):
        raise HTTPException(
            422,
            f"sha256: must be a tower file's SHA-256, 64 lowercase hex digits; got {sha256[:80]!r}",
        )
    towers = manager.engines.towers
    gzipped = _accepts_gzip(request.headers.get("accept-encoding", ""))
    data = towers.gzipped_bytes(sha256) if gzipped else towers.file_bytes(sha256)
    if data is None:
        raise HTTPException(404, f"this server holds no static text tower {sha256}")
    # each encoding its own strong ETag; either held copy is current (the bytes never change)
    etag = f'"{sha256}.gz"' if gzipped else f'"{sha256}"'
    headers = {"ETag": etag, "Cache-Control": CACHE_FOREVER, "Vary": "Accept-Encoding"}
    held = {
        t.strip().removeprefix("W/") for t in request.headers.get("if-none-match", "").split(",")
    }
    if held & {f'"{sha256}"', f'"{sha256}.gz"'}:
        return Response(status_code=304, headers=headers)
    if gzipped:
        headers["Content-Encoding"] = "gzip"
    return Response(data, media_type=TOWER_MEDIA_TYPE, headers=headers)


def _accepts_gzip(accept_encoding: str) -> bool:
    """Whether an Accept-Encoding header takes gzip (not refused with q=0)."""
    for item in accept_encoding.split(","):
        coding, _, params = item.strip().partition(";")
        if coding.strip().lower() in ("gzip", "x-gzip"):
            q = params.strip().removeprefix("q=").strip()
            try:
                return not params or float(q) > 0
            except ValueError:
                return False
    return False
