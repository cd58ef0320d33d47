"""Who may reach the server, and what its logs may say (origins, hosts and secrets; docs/faults.md).

- `HostOriginMiddleware`: a request whose `Host` is not one the server answers to gets 400
  naming `--allowed-hosts` (DNS rebinding: a page on any site that resolves its own name to
  127.0.0.1 must not reach the REST API); a WebSocket handshake from a browser page whose
  `Origin` is neither the server's own nor listed in `--allow-origin` is refused with 403
  (a page on any site could otherwise open a keyless server's sockets). Non-browser
  clients send no Origin and pass.
- `RedactCredentials`: a logging filter that blanks `token=` (and any credential-looking
  query parameter) in log records, so the access log never holds a session token or key.
"""

from __future__ import annotations

import copy
import logging
import re
from collections.abc import Sequence
from urllib.parse import urlsplit

import uvicorn.config
from starlette.types import ASGIApp, Receive, Scope, Send

from app.server.limits import send_json

LOOPBACK_HOSTS = ("localhost", "127.0.0.1", "::1")
"""The names a loopback-bound server answers to by default."""
WILDCARD_BINDS = ("0.0.0.0", "::", "")
"""Binds that listen on every interface: every Host passes unless --allowed-hosts is given."""


def default_allowed_hosts(bind_host: str) -> list[str] | None:
    """The Host names a server bound to `bind_host` answers to; None means any.

    docs/architecture.md, "Allowed hosts": a loopback bind answers to the loopback names; a
    wildcard bind answers to every Host; any other bind answers to its own address and the
    loopback names.
    """
    if bind_host in WILDCARD_BINDS:
        return None
    if bind_host in LOOPBACK_HOSTS:
        return list(LOOPBACK_HOSTS)
    return [bind_host, *LOOPBACK_HOSTS]


def split_host(host_header: str) -> str:
    """`Host` header -> lower-case host name without port ('[::1]:8000' -> '::1')."""
    host = host_header.strip().lower()
    if host.startswith("["):
        return host[1 : host.find("]")] if "]" in host else host
    return host.rsplit(":", 1)[0] if host.count(":") == 1 else host


def host_allowed(host: str, allowed: Sequence[str]) -> bool:
    """`allowed` entries are names, '*' (any) or '*.example.com' (any subdomain)."""
    for pattern in allowed:
        if pattern == "*" or host == pattern:
            return True
        if pattern.startswith("*.") and host.endswith(pattern[1:]):
            return True
    return False


class HostOriginMiddleware:
    """Pure ASGI middleware: Host checked on every request and handshake, Origin on
    WebSocket handshakes."""

    def __init__(
        self, app: ASGIApp, allowed_hosts: Sequence[str] | None, allowed_origins: Sequence[str]
    ):
        self.app = app
        self.allowed_hosts = None if allowed_hosts is None else [h.lower() for h in allowed_hosts]
        self.allowed_origins = {o.rstrip("/").lower() for o in allowed_origins}

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers = {k.decode("latin-1"): v.decode("latin-1") for k, v in scope["headers"]}
        host_header = headers.get("host", "")
        if self.allowed_hosts is not None and not host_allowed(
            split_host(host_header), self.allowed_hosts
        ):
            await _refuse(
                scope,
                send,
                400,
                f"Host {host_header!r} is not served here; start the server with "
                "--allowed-hosts to add it",
            )
            return
        origin = headers.get("origin")
        if (
            scope["type"] == "websocket"
            and origin
            and not self._origin_allowed(origin, host_header)
        ):
            await _refuse(
                scope,
                send,
                403,
                f"Origin {origin!r} may not open this socket; start the server with "
                "--allow-origin to add it",
            )
            return
        await self.app(scope, receive, send)

    def _origin_allowed(self, origin: str, host_header: str) -> bool:
        origin = origin.rstrip("/").lower()
        if origin in self.allowed_origins or "*" in self.allowed_origins:
            return True
        # The server's own pages: same host and port as the request's Host header.
        return urlsplit(origin).netloc == host_header.strip().lower()


async def _refuse(scope: Scope, send: Send, status: int, detail: str) -> None:
    if scope["type"] == "http":
        await send_json(send, "http.response", status, detail)
    elif "websocket.http.response" in scope.get("extensions", {}):
        await send_json(send, "websocket.http.response", status, detail)
    else:
        await send({"type": "websocket.close", "code": 1008})  # the client sees 403


_CREDENTIAL_QUERY = re.compile(r"(?i)([?&](?:token|api_key|apikey|key|access_token)=)[^&\s\"]*")
_AUTHORIZATION = re.compile(r"(?i)(authorization:\s*\w+\s+)\S+")


def redact(text: str) -> str:
    """`text` with credential query parameters and Authorization values blanked."""
    return _AUTHORIZATION.sub(r"\1[redacted]", _CREDENTIAL_QUERY.sub(r"\1[redacted]", text))


class RedactCredentials(logging.Filter):
    """Blanks credentials in a record's message and arguments (uvicorn's access log passes
    the request target as an argument)."""

    def filter(self, record: logging.LogRecord) -> bool:
        if isinstance(record.msg, str):
            record.msg = redact(record.msg)
        if isinstance(record.args, tuple):
            record.args = tuple(redact(a) if isinstance(a, str) else a for a in record.args)
        return True


def logging_config() -> dict:
    """uvicorn's own logging configuration, with credentials redacted from its loggers."""
    config = copy.deepcopy(uvicorn.config.LOGGING_CONFIG)
    config["filters"] = {"redact_credentials": {"()": RedactCredentials}}
    for name in ("uvicorn", "uvicorn.error", "uvicorn.access"):
        config["loggers"].setdefault(name, {})["filters"] = ["redact_credentials"]
    return config
