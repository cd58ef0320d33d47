"""The gateway of a cluster: one public port in front of the map shards.

A gateway holds no map. It checks what arrives (Host and Origin, body and message sizes,
open connections), routes each session to its shard (`routing.ShardDirectory`) and relays
the wire protocol v1 unchanged: REST requests and answers, stream frames and their acks,
update messages. The shards are SemanticXR servers themselves (`--shard-name`): they own
their sessions' engines, commit to the shared PostgreSQL store under a fenced claim, and
fan updates out. What crosses the seam is protocol messages, never a live session.

A device's socket survives its shard. The gateway remembers the frames it relayed that got
no reply yet; when the shard's socket ends abnormally (a kill), closes with 1012 (the
session moved) or the shard stops beating (a hang), the gateway routes the session again,
reconnects under the same stream id and resends them in order: the new owner answers a
keyframe its predecessor committed from the store (idempotent on session, stream, seq)
and maps the rest. An update subscriber resumes from the last seq it relayed, as any client
resumes. Requests not yet delivered (or idempotent ones) are retried on the new owner.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
import uuid
from collections.abc import Awaitable
from contextlib import asynccontextmanager

import httpx
import msgpack
from fastapi import FastAPI, Request, WebSocket
from fastapi.responses import JSONResponse, Response
from prometheus_client import CollectorRegistry, Counter, generate_latest
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidStatus

from app import __version__
from app.cluster.routing import NoLiveShard, ShardDirectory
from app.protocol import SIGHTINGS_SUBPROTOCOL
from app.server.edges import HostOriginMiddleware
from app.server.limits import BodyLimitMiddleware, SocketLimitMiddleware, body_limits
from app.server.routes.ws import (
    CLOSE_POLICY,
    CLOSE_SERVICE_RESTART,
    CLOSE_TRY_LATER,
    STREAM_HEADER,
)
from app.server.settings import ServerSettings
from app.store import Store, open_store, redact_url

log = logging.getLogger("semanticxr.gateway")

FORWARDED_HEADERS = ("authorization", "content-type", "accept", "accept-encoding")
"""Request headers a gateway passes to a shard (Host and Origin are the gateway's to check)."""
DROPPED_ANSWER_HEADERS = frozenset(
    {"content-length", "transfer-encoding", "connection", "keep-alive", "date", "server"}
)
RETRIED_METHODS = frozenset({"GET", "HEAD", "PUT", "PATCH", "DELETE", "OPTIONS"})
"""Requests sent again when their shard fails while answering (they are idempotent)."""
REQUEST_TIMEOUT_S = 120.0
"""Longest a shard may take to answer a request (an export of a large map)."""
LIVENESS_POLL_S = 0.25
"""How often a relay checks that its shard still beats, and a failover routes again."""
UNACKED_FRAMES = 64
"""Frames a stream relay keeps for resending; older ones are forgotten (frames are samples)."""
SHARD_MESSAGE_SLACK = 1024
"""Bytes a shard's reply may exceed the device's message limit by (they are small anyway)."""


def failover_deadline_s(settings: ServerSettings) -> float:
    """Longest a gateway looks for a shard to take a session over before giving up: past a
    dead owner's lease, with room for Ray to restart a shard."""
    return 3 * settings.shard_lease_s + 10.0


class _Metrics:
    def __init__(self) -> None:
        self.registry = CollectorRegistry()
        self.requests = Counter(
            "semanticxr_gateway_requests",
            "REST requests relayed to a map shard, by outcome",
            ["outcome"],
            registry=self.registry,
        )
        self.failovers = Counter(
            "semanticxr_gateway_failovers",
            "Sockets moved to another map shard (or the restarted one) after theirs failed",
            ["kind"],
            registry=self.registry,
        )
        self.resent = Counter(
            "semanticxr_gateway_frames_resent",
            "Frames sent again to a session's new shard (they had no reply from the old one)",
            registry=self.registry,
        )


class _Refused(Exception):
    """A shard refused a socket's handshake with this HTTP status (not a retryable one)."""

    def __init__(self, status: int, headers: dict[str, str], detail: str):
        super().__init__(detail)
        self.status, self.headers, self.detail = status, headers, detail


def _session_of(path: str) -> str | None:
    """The session id a /v1/sessions/{sid}... path names (None for other paths)."""
    parts = path.split("/")
    if len(parts) >= 4 and parts[1] == "v1" and parts[2] == "sessions" and parts[3] != "import":
        return parts[3] or None
    return None


def create_gateway_app(settings: ServerSettings, store: Store | None = None) -> FastAPI:
    """The gateway (`semanticxr gateway`, and `semanticxr serve --cluster` in front of its
    shards). `store`: the cluster's store (default: opened from settings.store_url)."""

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        own_store = store is None
        opened = open_store(settings.store_url) if own_store else store
        app.state.directory = ShardDirectory(opened, max_age_s=settings.shard_lease_s)
        app.state.http = httpx.AsyncClient(timeout=REQUEST_TIMEOUT_S)
        directory = asyncio.create_task(app.state.directory.run())
        log.info("gateway on store %s", redact_url(settings.store_url))
        try:
            yield
        finally:
            directory.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await directory
            await app.state.http.aclose()
            if own_store:
                opened.close()

    app = FastAPI(title="SemanticXR gateway", version=__version__, lifespan=lifespan)
    app.state.metrics = metrics = _Metrics()
    app.add_middleware(
        BodyLimitMiddleware, **body_limits(settings.max_body_bytes, settings.max_audio_bytes)
    )
    app.add_middleware(SocketLimitMiddleware, max_sockets=settings.max_connections)
    app.add_middleware(
        HostOriginMiddleware,
        allowed_hosts=settings.allowed_host_list(),
        allowed_origins=settings.allowed_origin_list(),
    )
    deadline_s = failover_deadline_s(settings)

    @app.get("/healthz", include_in_schema=False)
    async def healthz(request: Request) -> JSONResponse:
        """200 while the store answers (a read started after the request, in time) and at
        least one map shard beats; 503 with Retry-After otherwise (the reason says which)."""
        directory: ShardDirectory = request.app.state.directory
        answered = await directory.fresh_read()
        live = await directory.live()
        reason = (
            "storage unavailable: the cluster's store cannot be read (database down?)"
            if not (answered and directory.store_ok)
            else None
            if live
            else "no map shard is alive: they may be starting or restarting"
        )
        if reason is not None:
            return JSONResponse(
                {"status": "unavailable", "reason": reason}, 503, headers={"Retry-After": "2"}
            )
        return JSONResponse({"status": "ok", "shards": sorted(live)})

    @app.get("/gateway/metrics", include_in_schema=False)
    def gateway_metrics() -> Response:
        return Response(generate_latest(metrics.registry), media_type="text/plain; version=0.0.4")

    @app.api_route(
        "/{path:path}",
        methods=["GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS"],
        include_in_schema=False,
    )
    async def relay_request(request: Request, path: str) -> Response:
        return await _relay_request(request, deadline_s, metrics)

    @app.websocket("/v1/sessions/{sid}/stream")
    async def stream(ws: WebSocket, sid: str) -> None:
        await _StreamRelay(ws, sid, settings, metrics).run()

    @app.websocket("/v1/sessions/{sid}/updates")
    async def updates(ws: WebSocket, sid: str) -> None:
        await _UpdatesRelay(ws, sid, settings, metrics).run()

    return app


# ---------------------------------------------------------------------- REST
async def _relay_request(request: Request, deadline_s: float, metrics: _Metrics) -> Response:
    """Send the request to its session's shard (any shard for other paths) and answer what
    it answers; on a shard that is gone or no longer holds the session, route again."""
    directory: ShardDirectory = request.app.state.directory
    http: httpx.AsyncClient = request.app.state.http
    body = await request.body()
    sid = _session_of(request.url.path)
    headers = {k: v for k, v in request.headers.items() if k in FORWARDED_HEADERS}
    target = request.url.path + (f"?{request.url.query}" if request.url.query else "")
    give_up = time.monotonic() + deadline_s
    attempt = 0
    while True:
        attempt += 1
        try:
            name, base = await (directory.route(sid, attempt > 1) if sid else directory.any())
            answer = await _until_dead(
                directory,
                name,
                http.request(request.method, base + target, headers=headers, content=body),
            )
        except (NoLiveShard, httpx.ConnectError, httpx.ConnectTimeout, _ShardDied) as exc:
            sent = isinstance(exc, _ShardDied)
            if (sent and request.method not in RETRIED_METHODS) or time.monotonic() > give_up:
                metrics.requests.labels(outcome="unavailable").inc()
                return _unavailable(exc, sent)
            await asyncio.sleep(LIVENESS_POLL_S)
            continue
        except httpx.HTTPError as exc:  # the shard failed mid-answer
            if request.method in RETRIED_METHODS and time.monotonic() < give_up:
                await asyncio.sleep(LIVENESS_POLL_S)
                continue
            metrics.requests.labels(outcome="unavailable").inc()
            return _unavailable(exc, sent=True)
        held = answer.status_code == 503 and "x-semanticxr-owner" in answer.headers
        if held and time.monotonic() < give_up:  # another shard holds it: route there
            await asyncio.sleep(LIVENESS_POLL_S)
            continue
        metrics.requests.labels(outcome="relayed").inc()
        return Response(
            answer.content,
            answer.status_code,
            headers={
                k: v for k, v in answer.headers.items() if k.lower() not in DROPPED_ANSWER_HEADERS
            },
        )


class _ShardDied(Exception):
    """The shard stopped beating while a request or socket waited on it."""


async def _until_dead(directory: ShardDirectory, name: str, work: Awaitable):
    """`work`'s result, unless shard `name` stops beating first (then _ShardDied)."""
    task = asyncio.ensure_future(work)
    try:
        while True:
            done, _ = await asyncio.wait({task}, timeout=LIVENESS_POLL_S)
            if done:
                return task.result()
            if not await directory.is_live(name):
                raise _ShardDied(f"map shard {name} stopped beating")
    finally:
        if not task.done():
            task.cancel()
            with contextlib.suppress(BaseException):
                await task


def _unavailable(exc: BaseException, sent: bool) -> JSONResponse:
    detail = (
        f"the map shard failed while answering ({exc}); the request may or may not have taken "
        f"effect: check, then retry"
        if sent
        else f"no map shard can take this request now ({exc}); retry shortly"
    )
    return JSONResponse({"detail": detail}, 503, headers={"Retry-After": "2"})


# ---------------------------------------------------------------------- sockets
class _SocketRelay:
    """One client socket relayed to its session's shard, reconnected across shard failures."""

    path = ""

    def __init__(self, ws: WebSocket, sid: str, settings: ServerSettings, metrics: _Metrics):
        self.ws, self.sid, self.settings, self.metrics = ws, sid, settings, metrics
        self.directory: ShardDirectory = ws.app.state.directory
        self.shard: str | None = None
        self.upstream: ClientConnection | None = None
        self.deadline_s = failover_deadline_s(settings)

    def query(self) -> str:
        return self.ws.url.query

    def subprotocols(self) -> list[str]:
        return []

    def headers(self) -> dict[str, str]:
        return {k: v for k, v in self.ws.headers.items() if k == "authorization"}

    async def connect(self) -> ClientConnection:
        """A socket to the session's shard, routing again until one takes it (or the
        deadline passes: NoLiveShard / _Refused)."""
        give_up = time.monotonic() + self.deadline_s
        attempt = 0
        while True:
            attempt += 1
            try:
                self.shard, base = await self.directory.route(self.sid, fresh=attempt > 1)
                query = self.query()
                url = f"ws{base.removeprefix('http')}/v1/sessions/{self.sid}/{self.path}"
                return await connect(
                    url + (f"?{query}" if query else ""),
                    additional_headers=self.headers(),
                    subprotocols=self.subprotocols() or None,
                    max_size=self.settings.max_message_bytes + SHARD_MESSAGE_SLACK,
                    compression=None,
                    open_timeout=10,
                    close_timeout=1,
                    ping_interval=None,  # liveness comes from the shard's heartbeat
                )
            except InvalidStatus as exc:
                response = exc.response
                held = response.status_code == 503 and "x-semanticxr-owner" in response.headers
                if not held or time.monotonic() > give_up:
                    raise _Refused(
                        response.status_code,
                        dict(response.headers),
                        response.body.decode(errors="replace")[:200],
                    ) from None
            except (OSError, TimeoutError, NoLiveShard, ConnectionClosed, InvalidHandshake):
                if time.monotonic() > give_up:
                    raise NoLiveShard(self.directory.max_age_s) from None
            await asyncio.sleep(LIVENESS_POLL_S)

    async def refuse(self, exc: BaseException) -> None:
        """Answer the client's handshake as the shard (or the lack of one) did."""
        if isinstance(exc, _Refused) and exc.status != 503:
            await self.ws.close(code=CLOSE_POLICY, reason=exc.detail[:120])
            return
        detail = exc.detail if isinstance(exc, _Refused) else str(exc)
        if "websocket.http.response" in self.ws.scope.get("extensions", {}):
            await self.ws.send_denial_response(
                JSONResponse({"detail": detail}, 503, headers={"Retry-After": "2"})
            )
            return
        await self.ws.accept()
        await self.ws.close(code=CLOSE_TRY_LATER, reason=detail[:120])

    async def run(self) -> None:
        try:
            self.upstream = await self.connect()
        except (_Refused, NoLiveShard) as exc:
            await self.refuse(exc)
            return
        await self.ws.accept(subprotocol=self.upstream.subprotocol)
        client = asyncio.create_task(self.from_client())
        try:
            while True:
                down = asyncio.create_task(self.to_client(self.upstream))
                watch = asyncio.create_task(self.watch_shard())
                done, _ = await asyncio.wait(
                    {client, down, watch}, return_when=asyncio.FIRST_COMPLETED
                )
                for task in (down, watch):
                    task.cancel()
                if client in done:
                    break
                code = self.upstream.close_code
                if down in done and code not in (None, 1006, 1011, CLOSE_SERVICE_RESTART):
                    await self.close_client(code, self.upstream.close_reason or "")
                    break
                if not await self.fail_over():
                    break
        finally:
            client.cancel()
            with contextlib.suppress(BaseException):
                await client
            if self.upstream is not None:
                with contextlib.suppress(Exception):
                    await self.upstream.close()

    async def fail_over(self) -> bool:
        """Reconnect to the session's (new) shard; False (client closed 1013) if none takes
        it before the deadline."""
        old = self.upstream
        with contextlib.suppress(Exception):
            old.transport.abort()  # a hung shard never answers a close
        self.metrics.failovers.labels(kind=self.path).inc()
        log.warning(
            "session %s: map shard %s is gone; moving its %s socket",
            self.sid,
            self.shard,
            self.path,
        )
        try:
            upstream = await self.connect()
        except (_Refused, NoLiveShard) as exc:
            detail = exc.detail if isinstance(exc, _Refused) else str(exc)
            await self.close_client(CLOSE_TRY_LATER, f"no map shard took the session: {detail}")
            return False
        await self.reconnected(upstream)
        return True

    async def reconnected(self, upstream: ClientConnection) -> None:
        self.upstream = upstream

    async def close_client(self, code: int, reason: str) -> None:
        with contextlib.suppress(Exception):
            await self.ws.close(code=code, reason=reason[:120])

    async def watch_shard(self) -> None:
        """Returns when the shard stops beating (a hang: its socket may never close)."""
        while await self.directory.is_live(self.shard):
            await asyncio.sleep(LIVENESS_POLL_S)

    async def from_client(self) -> None:
        raise NotImplementedError

    async def to_client(self, upstream: ClientConnection) -> None:
        raise NotImplementedError


class _StreamRelay(_SocketRelay):
    """Frames in, one reply each out; frames without a reply are resent after a failover."""

    path = "stream"

    def __init__(self, *args: object):
        super().__init__(*args)
        self.stream_id = uuid.uuid4().hex
        self.unacked: dict[int, bytes] = {}
        self.lock = asyncio.Lock()
        """Held while a frame is sent and while the frames without a reply are resent, so
        each reaches the new shard once and in order."""

    def headers(self) -> dict[str, str]:
        return {**super().headers(), STREAM_HEADER: self.stream_id}

    def subprotocols(self) -> list[str]:
        offered = self.ws.scope.get("subprotocols", [])
        return [SIGHTINGS_SUBPROTOCOL] if SIGHTINGS_SUBPROTOCOL in offered else []

    async def from_client(self) -> None:
        while True:
            event = await self.ws.receive()
            if event["type"] == "websocket.disconnect":
                return
            data = event.get("bytes")
            seq = _seq_of(data) if data is not None else None
            async with self.lock:
                if seq is not None:
                    self.unacked[seq] = data
                    while len(self.unacked) > UNACKED_FRAMES:
                        self.unacked.pop(next(iter(self.unacked)))
                with contextlib.suppress(ConnectionClosed):  # resent once reconnected
                    await self.upstream.send(data if data is not None else event.get("text", ""))

    async def to_client(self, upstream: ClientConnection) -> None:
        async for reply in upstream:
            message = _unpack(reply)
            seq = message.get("seq")
            if message.get("code") == "session_moved":
                return  # not an answer: move now, and resend the frame to the new owner
            if isinstance(seq, int):
                self.unacked.pop(seq, None)
            await self.ws.send_bytes(reply if isinstance(reply, bytes) else reply.encode())

    async def reconnected(self, upstream: ClientConnection) -> None:
        async with self.lock:
            self.upstream = upstream
            for data in list(self.unacked.values()):
                self.metrics.resent.inc()
                await upstream.send(data)


class _UpdatesRelay(_SocketRelay):
    """Update messages out; after a failover the subscription resumes from the last seq."""

    path = "updates"

    def __init__(self, *args: object):
        super().__init__(*args)
        self.since: str | None = self.ws.query_params.get("since")

    def query(self) -> str:
        params = [(k, v) for k, v in self.ws.query_params.multi_items() if k != "since"]
        if self.since not in (None, ""):
            params.append(("since", str(self.since)))
        return str(httpx.QueryParams(params))

    async def from_client(self) -> None:
        while (await self.ws.receive())["type"] != "websocket.disconnect":
            pass  # subscribers have nothing to say

    async def to_client(self, upstream: ClientConnection) -> None:
        async for message in upstream:
            seq = _unpack(message).get("seq")
            await self.ws.send_bytes(message if isinstance(message, bytes) else message.encode())
            if isinstance(seq, int):
                self.since = str(seq)


def _unpack(data: bytes | str) -> dict:
    try:
        message = msgpack.unpackb(data) if isinstance(data, bytes) else {}
    except Exception:
        return {}
    return message if isinstance(message, dict) else {}


def _seq_of(data: bytes) -> int | None:
    seq = _unpack(data).get("seq")
    return seq if isinstance(seq, int) and not isinstance(seq, bool) else None


__all__ = ["create_gateway_app"]
