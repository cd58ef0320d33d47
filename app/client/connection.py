"""Where the server is and how to reach it: URLs, auth, TLS trust, WebSockets, reconnect
back-off."""

from __future__ import annotations

import asyncio
import contextlib
import os
import ssl
from collections.abc import Awaitable
from typing import TypeVar
from urllib.parse import urlsplit

import websockets
from websockets.asyncio.client import ClientConnection
from websockets.exceptions import WebSocketException

BACKOFF_FIRST_S = 0.2
"""First reconnect delay; doubles after each failed attempt."""
BACKOFF_MAX_S = 5.0
"""Reconnect delay ceiling."""
OPEN_TIMEOUT_S = 5.0
"""WebSocket opening handshake timeout."""

CONNECTION_ERRORS = (OSError, TimeoutError, EOFError, WebSocketException)
"""What opening or using a socket raises when the network or the server goes away
(ConnectionClosed and the handshake errors are WebSocketExceptions)."""

T = TypeVar("T")


def websocket_base_url(server_url: str) -> str:
    """ws:// or wss:// base of an http(s):// server URL (ws(s):// is accepted as is)."""
    parts = urlsplit(server_url)
    scheme = {"http": "ws", "https": "wss", "ws": "ws", "wss": "wss"}.get(parts.scheme)
    if scheme is None or not parts.netloc:
        raise ValueError(f"server URL must look like http://host:port, got {server_url!r}")
    return f"{scheme}://{parts.netloc}{parts.path.rstrip('/')}"


def http_base_url(server_url: str) -> str:
    """http:// or https:// base of a server URL (ws(s):// is mapped back)."""
    ws = websocket_base_url(server_url)
    return "https" + ws[3:] if ws.startswith("wss") else "http" + ws[2:]


def auth_headers(token: str | None) -> dict[str, str]:
    """`Authorization: Bearer` for a session token or API key (none when the server is open)."""
    return {"Authorization": f"Bearer {token}"} if token else {}


def trusting(ca_file: str | os.PathLike[str]) -> ssl.SSLContext:
    """An SSL context that verifies servers against the PEM certificates in `ca_file` (a
    `serve --https` server's DATA_DIR/tls/cert.pem, or a CA), built once and handed to every
    HTTP client and socket of a command. ValueError saying why the file cannot serve."""
    try:
        return ssl.create_default_context(cafile=os.fspath(ca_file))
    except FileNotFoundError:
        raise ValueError(f"no such file: {os.fspath(ca_file)}") from None
    except OSError as exc:  # unreadable, or not PEM (ssl.SSLError is an OSError)
        reason = getattr(exc, "reason", None) or exc.strerror or exc
        raise ValueError(f"cannot read certificates from {os.fspath(ca_file)}: {reason}") from None


def describe(exc: BaseException) -> str:
    """One line naming a connection error, for logs and status panels."""
    return f"{type(exc).__name__}: {exc}"


class Backoff:
    """Reconnect delays: `first_s`, doubling up to `max_s`; `reset()` after a success."""

    def __init__(self, first_s: float = BACKOFF_FIRST_S, max_s: float = BACKOFF_MAX_S):
        self.first_s, self.max_s = first_s, max_s
        self._next_s = first_s

    def next_delay(self) -> float:
        delay, self._next_s = self._next_s, min(self._next_s * 2, self.max_s)
        return delay

    def reset(self) -> None:
        self._next_s = self.first_s


async def open_websocket(
    url: str, token: str | None, *, ssl_context: ssl.SSLContext | None = None, **kwargs
) -> ClientConnection:
    """Open a WebSocket of the API; raises one of CONNECTION_ERRORS when it cannot.
    ssl_context: whom a wss:// server must prove to be (`trusting`); default: the system's
    CAs. A ws:// URL ignores it."""
    if ssl_context is not None and url.startswith("wss:"):
        kwargs["ssl"] = ssl_context
    return await websockets.connect(
        url,
        additional_headers=auth_headers(token),
        open_timeout=OPEN_TIMEOUT_S,
        compression=None,  # JPEG, zstd and float16 do not deflate; save the CPU
        max_size=None,  # a full snapshot of a large map is big, and the server is trusted
        **kwargs,
    )


async def until(stopped: asyncio.Event, awaitable: Awaitable[T]) -> T | None:
    """`awaitable`'s result, or None (and it is cancelled) if `stopped` is set first."""
    task = asyncio.ensure_future(awaitable)
    stopper = asyncio.ensure_future(stopped.wait())
    try:
        await asyncio.wait({task, stopper}, return_when=asyncio.FIRST_COMPLETED)
    finally:
        stopper.cancel()
        if not task.done():
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, *CONNECTION_ERRORS):
                await task
    if not task.done() or task.cancelled():
        return None
    return task.result()


async def sleep_unless(stopped: asyncio.Event, seconds: float) -> bool:
    """Sleep (a pacing or back-off timer, not synchronisation); False if `stopped` is set
    meanwhile (or was already)."""
    if seconds > 0:
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(stopped.wait(), seconds)
    return not stopped.is_set()
