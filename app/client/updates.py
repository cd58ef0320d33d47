"""The one resumable subscriber of a session's map updates (`/v1/sessions/{sid}/updates`).

Kept up with exponential back-off (0.2 s doubling to 5 s) until `stop()` or cancellation.
After a disconnect it resumes with `?since=<the last applied seq>` (the server sends what
changed since, so no update is lost); after a message its user could not apply it resyncs
from a full snapshot (no `since`). What a message means is the user's business: each raw
message goes to `apply`, which applies it whole or not at all and says what was wrong.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import ssl
from collections.abc import Callable
from dataclasses import dataclass

from websockets.asyncio.client import ClientConnection

from app.client.connection import (
    CONNECTION_ERRORS,
    Backoff,
    describe,
    open_websocket,
    sleep_unless,
    until,
    websocket_base_url,
)

log = logging.getLogger(__name__)

PING_INTERVAL_S = 1.0
"""Ping period on the updates socket, when RTT samples are asked for."""
PONG_TIMEOUT_S = 15.0
"""A ping unanswered this long gives no sample (websockets' keepalive judges the link)."""


@dataclass(frozen=True)
class Disconnect:
    """Why the updates socket is down (or could not be opened)."""

    reason: str
    """For a human."""
    bad_update: str | None = None
    """Set when the subscriber closed the socket itself to resync from a full snapshot:
    what was wrong with the message `apply` refused."""
    repeated: bool = False
    """A failed reconnect attempt in an outage already reported (say "lost" once)."""


class UpdatesSubscriber:
    """Follows one session's updates until `stop()` (or its `run` task is cancelled).

    apply(raw) -> None if the message was applied, else what was wrong with it (the
    subscriber then resyncs). applied_seq() -> the seq of the last applied message (where a
    reconnect resumes). start_from_snapshot: whether the first connection asks for a full
    snapshot (False: it resumes from `applied_seq()`, for a user that kept its map).
    apply_in_thread: run `apply` in a worker thread (a slow apply must not starve the
    socket's keepalive). on_connected(since, reconnect): a socket is up; `since` is what it
    asked for (None: a full snapshot), `reconnect` whether one was up before.
    on_disconnected(Disconnect). on_rtt_ms: if given, the socket is pinged every
    PING_INTERVAL_S and each ping -> pong time goes there. ssl_context: whom a wss://
    server must prove to be (default: the system's CAs).
    """

    def __init__(
        self,
        server_url: str,
        session_id: str,
        token: str | None,
        *,
        apply: Callable[[bytes | str], str | None],
        applied_seq: Callable[[], int],
        start_from_snapshot: bool = True,
        apply_in_thread: bool = False,
        on_connected: Callable[[int | None, bool], None] | None = None,
        on_disconnected: Callable[[Disconnect], None] | None = None,
        on_rtt_ms: Callable[[float], None] | None = None,
        ssl_context: ssl.SSLContext | None = None,
    ):
        self.url = f"{websocket_base_url(server_url)}/v1/sessions/{session_id}/updates"
        self.token = token
        self.ssl_context = ssl_context
        self._apply = apply
        self._applied_seq = applied_seq
        self._start_from_snapshot = start_from_snapshot
        self._apply_in_thread = apply_in_thread
        self._on_connected = on_connected or (lambda since, reconnect: None)
        self._on_disconnected = on_disconnected or (lambda event: None)
        self._on_rtt_ms = on_rtt_ms
        self._stopped = asyncio.Event()
        self._ws: ClientConnection | None = None

    async def run(self) -> None:
        """Follow the updates until `stop()`; connection problems are reported, never raised."""
        backoff = Backoff()
        resync = self._start_from_snapshot
        ever_up = False  # the first connection is not a re-connection
        outage_told = False  # say "lost" once per outage, not once per failed attempt
        while not self._stopped.is_set():
            since = None if resync else self._applied_seq()
            url = self.url if since is None else f"{self.url}?since={since}"
            try:
                opening = open_websocket(url, self.token, ssl_context=self.ssl_context)
                ws = await until(self._stopped, opening)
            except CONNECTION_ERRORS as exc:
                self._on_disconnected(Disconnect(describe(exc), repeated=outage_told))
                outage_told = True
            else:
                if ws is None:  # stopped while connecting
                    break
                self._ws = ws
                self._on_connected(since, ever_up)
                ever_up, outage_told = True, False
                ended, applied = await self._follow(ws, backoff)
                resync = ended.bad_update is not None or (resync and not applied)
                self._on_disconnected(ended)
                outage_told = ended.bad_update is None
            if not await sleep_unless(self._stopped, backoff.next_delay()):
                break

    async def _follow(self, ws: ClientConnection, backoff: Backoff) -> tuple[Disconnect, bool]:
        """Apply messages until the socket ends: why it ended, and whether any message was
        applied (then the next connection resumes from it)."""
        pinger = asyncio.create_task(self._ping_loop(ws)) if self._on_rtt_ms else None
        reason, applied = "closed by the server", False
        try:
            while (raw := await until(self._stopped, ws.recv())) is not None:
                if self._apply_in_thread:
                    problem = await asyncio.to_thread(self._apply, raw)
                else:
                    problem = self._apply(raw)
                if problem is not None:
                    reason = f"bad update ({problem}); resyncing with a full snapshot"
                    return Disconnect(reason, bad_update=problem), applied
                applied = True
                backoff.reset()
        except CONNECTION_ERRORS as exc:
            reason = describe(exc)
        finally:
            if pinger is not None:
                pinger.cancel()
            self._ws = None
            with contextlib.suppress(Exception):
                await ws.close()
        return Disconnect(reason), applied

    async def _ping_loop(self, ws: ClientConnection) -> None:
        """RTT samples from ping -> pong while the socket is up (websockets' own keepalive
        pings, every 20 s, only detect dead links)."""
        assert self._on_rtt_ms is not None
        while True:
            await asyncio.sleep(PING_INTERVAL_S)  # a sampling period, not synchronisation
            try:
                pong = await ws.ping()
                latency_s = await asyncio.wait_for(pong, PONG_TIMEOUT_S)
            except TimeoutError:
                continue  # no sample; websockets' keepalive decides whether the link is dead
            except CONNECTION_ERRORS:
                return
            self._on_rtt_ms(latency_s * 1e3)

    async def stop(self) -> None:
        """End `run` soon (final: a stopped subscriber does not start again)."""
        self._stopped.set()
        ws = self._ws
        if ws is not None:
            with contextlib.suppress(Exception):
                await ws.close()

    @property
    def stopped(self) -> bool:
        return self._stopped.is_set()
