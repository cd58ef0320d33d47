"""Limits on what the network may send: HTTP request bodies and open WebSockets.

The body limit is enforced on the bytes that arrive. A Content-Length over the limit is
refused before the body is read. A chunked body has no Content-Length, so the limit is also
counted chunk by chunk as the application reads: as soon as the body passes the limit the
client gets 413, the application sees the client disconnect, and nothing past the limit is
buffered.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass

from starlette.types import ASGIApp, Message, Receive, Scope, Send

SPEECH_PATH = re.compile(r"/v1/sessions/[^/]+/query/speech")
"""The spoken query's path: its body is audio, under --max-audio-bytes instead."""


@dataclass(frozen=True)
class PathLimit:
    """A body limit of its own for the paths `pattern` matches in full."""

    pattern: re.Pattern
    max_bytes: int
    flag: str
    """The setting's flag, named in the 413."""
    what: str = "request body"


class BodyLimitMiddleware:
    """Pure ASGI middleware: 413 for HTTP request bodies over `max_bytes`, or over the limit
    of the first of `path_limits` whose pattern matches the path."""

    def __init__(self, app: ASGIApp, max_bytes: int, path_limits: tuple[PathLimit, ...] = ()):
        self.app = app
        self.max_bytes = max_bytes
        self.path_limits = path_limits

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        limit = next(
            (p for p in self.path_limits if p.pattern.fullmatch(scope.get("path", ""))), None
        )
        max_bytes = self.max_bytes if limit is None else limit.max_bytes
        detail = (
            f"request body over {max_bytes} bytes"
            if limit is None
            else f"{limit.what} over {max_bytes} bytes ({limit.flag})"
        )
        length = dict(scope["headers"]).get(b"content-length")
        if length is not None and (not length.isdigit() or int(length) > max_bytes):
            await send_json(send, "http.response", 413, detail)
            return

        received = 0
        started = refused = False

        async def counted_receive() -> Message:
            nonlocal received, refused
            if refused:
                return {"type": "http.disconnect"}
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > max_bytes:
                    refused = True
                    if not started:
                        await send_json(send, "http.response", 413, detail)
                    return {"type": "http.disconnect"}  # the app stops reading here
            return message

        async def guarded_send(message: Message) -> None:
            nonlocal started
            if refused:
                return  # the 413 went out; whatever the app answers to the disconnect does not
            started = started or message["type"] == "http.response.start"
            await send(message)

        await self.app(scope, counted_receive, guarded_send)


def body_limits(max_body_bytes: int, max_audio_bytes: int) -> dict:
    """The BodyLimitMiddleware options of a server or gateway: REST bodies under
    --max-body-bytes, spoken questions under --max-audio-bytes."""
    audio = PathLimit(SPEECH_PATH, max_audio_bytes, "--max-audio-bytes", "audio")
    return {"max_bytes": max_body_bytes, "path_limits": (audio,)}


SOCKETS_FULL_RETRY_AFTER_S = 1
"""Retry-After (seconds) of a handshake refused at max_connections: sockets come and go."""


class SocketLimitMiddleware:
    """Pure ASGI middleware: at most `max_sockets` WebSockets open at once; a handshake
    beyond it is answered HTTP 503. (uvicorn's `limit_concurrency` answers 503 to HTTP
    requests but lets WebSocket upgrades through.)"""

    def __init__(self, app: ASGIApp, max_sockets: int):
        self.app = app
        self.max_sockets = max_sockets
        self.open = 0

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "websocket":
            await self.app(scope, receive, send)
            return
        if self.open >= self.max_sockets:
            await self._refuse(scope, send)
            return
        self.open += 1
        try:
            await self.app(scope, receive, send)
        finally:
            self.open -= 1

    async def _refuse(self, scope: Scope, send: Send) -> None:
        if "websocket.http.response" not in scope.get("extensions", {}):
            await send({"type": "websocket.close", "code": 1013})  # the client sees 403
            return
        await send_json(
            send,
            "websocket.http.response",
            503,
            f"over {self.max_sockets} open connections",
            retry_after_s=SOCKETS_FULL_RETRY_AFTER_S,
        )


async def send_json(
    send: Send, kind: str, status: int, detail: str, retry_after_s: int | None = None
) -> None:
    """A whole JSON answer {"detail": ...}; kind: "http.response" or, to refuse a WebSocket
    handshake, "websocket.http.response". The connection closes after it. retry_after_s:
    a Retry-After header (every 503 carries one: docs/architecture.md "Rules the code keeps")."""
    body = json.dumps({"detail": detail}).encode()
    headers = [
        (b"content-type", b"application/json"),
        (b"content-length", str(len(body)).encode()),
        (b"connection", b"close"),
    ]
    if retry_after_s is not None:
        headers.append((b"retry-after", str(retry_after_s).encode()))
    await send({"type": f"{kind}.start", "status": status, "headers": headers})
    await send({"type": f"{kind}.body", "body": body})
