"""WebSockets: frame ingest (device -> server) and map updates (server -> subscribers)."""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import time
from dataclasses import dataclass

import msgpack
from fastapi import APIRouter, HTTPException, WebSocket, WebSocketDisconnect
from fastapi.responses import JSONResponse

from app.errors import InputError
from app.perception.base import FrameDetections
from app.protocol import (
    SIGHTINGS_SUBPROTOCOL,
    Ack,
    ErrorReply,
    FrameBudget,
    FrameInput,
    LimitError,
    parse_frame,
    parse_sighting,
    unpack_frame_message,
)
from app.protocol.delta import SINCE_PARAM, delta_seq, has_news
from app.protocol.frame import TYPE_FIELD, part_sizes, stream_message_seq
from app.protocol.rest import UPDATES_BYTES
from app.protocol.sighting import is_sighting
from app.server.auth import authorize_session, bearer
from app.server.routes.depends import Manager
from app.server.sessions import Session, SessionManager

log = logging.getLogger(__name__)
router = APIRouter(prefix="/v1")
SEND_TIMEOUT_S = 30.0
"""Longest a reply to a device may wait for room in its socket's write buffer."""
SUBSCRIBER_QUEUE_UPDATES = 8
"""Publications an update subscriber may fall behind (while one message waits to go out)
before it is closed as too slow (1013); its backlog is a count, coalesced when it catches up."""
SUBSCRIBER_STALL_S = 10.0
"""Longest one update may wait to go out to a subscriber before it is closed as too slow: well
before the ping timeout (20 s + 20 s) would close it silently."""
CLOSE_POLICY, CLOSE_TOO_BIG, CLOSE_TRY_LATER, CLOSE_GOING_AWAY = 1008, 1009, 1013, 1001
CLOSE_SERVICE_RESTART = 1012
"""The session moved to another map shard: reconnect (through a gateway) and resume."""
STREAM_HEADER = "x-semanticxr-stream"
"""A stream id the client (a gateway) keeps across reconnections: a keyframe resent under
the same (stream, seq) is answered from the store, not mapped twice. Without it, every
socket is a stream of its own."""
STREAM_ID_CHARS = frozenset("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789-_")
MAX_STREAM_ID = 64


async def _authorize(ws: WebSocket, manager: SessionManager, sid: str) -> Session | None:
    """The session in use for this socket (release it when the socket ends), loaded in a
    thread if need be; None once the handshake was refused: HTTP 403 for a caller who may
    not use it (nothing about the session revealed), 503 with Retry-After when there is no
    room to load it now, 409 naming the text tower a static session needs and the server
    lacks (the caller may use the session: REST gives the same answer)."""
    try:
        return await manager.in_thread(
            authorize_session, manager, sid, bearer(ws.headers, ws.query_params)
        )
    except HTTPException as exc:
        if exc.status_code in _SAID_IN_HTTP:
            await _refuse_with_reason(ws, exc)
        else:
            # Before accept(): the client sees an HTTP 403 and nothing about the session.
            await ws.close(code=CLOSE_POLICY, reason=str(exc.detail)[:120])
        return None


_SAID_IN_HTTP = {503: CLOSE_TRY_LATER, 409: CLOSE_POLICY}
"""Refusals a session's user is told as REST tells them, and the close code that says it
where a handshake cannot get an HTTP answer."""


async def _refuse_with_reason(ws: WebSocket, exc: HTTPException) -> None:
    """Refuse a handshake as REST answers: the status (503 with Retry-After: try again
    later; 409: not until the server changes) and the reason; where the server cannot send
    an HTTP answer to a handshake, accept and close with `_SAID_IN_HTTP`'s code and the
    reason."""
    if "websocket.http.response" in ws.scope.get("extensions", {}):
        answer = JSONResponse({"detail": exc.detail}, exc.status_code, headers=exc.headers)
        await ws.send_denial_response(answer)
        return
    await ws.accept()
    await ws.close(code=_SAID_IN_HTTP[exc.status_code], reason=str(exc.detail)[:120])


@dataclass
class _Decoded:
    frame: FrameInput
    sent: FrameDetections | None
    """The detections the device sent, validated (None if none)."""
    decode_ms: float
    """What unpacking, decoding and validating took (part of a keyframe's mapping latency)."""
    payload_bytes: dict[str, int]
    sighting: bool = False
    """A `sighting` (the sightings extension), not a `frame`."""
    mapped: bool = True
    """Decoded for mapping (a keyframe): its RGB stream and depth patches in full."""


class _Refused(Exception):
    """A message refused while decoding: the reply it gets."""

    def __init__(self, reply: ErrorReply, is_frame: bool):
        super().__init__(reply.message)
        self.reply = reply
        self.is_frame = is_frame
        """False for a message that is not even msgpack within the limits (no seq known)."""


def _decode_and_validate(
    data: bytes,
    session: Session,
    budget: FrameBudget,
    sightings: bool = False,
    keyframe_next: bool = True,
) -> _Decoded:
    """In a decode thread, once per message, never on the event loop: unpack it within the
    protocol's limits, check it against the server's budget before any pixel is decoded,
    decode and validate it, so everything the engine would refuse is refused here, keyframe
    or not. Perception runs later, on keyframes only. `sightings`: the socket negotiated the
    sightings extension, so a `sighting` message is welcome (and every `frame` is a
    keyframe). keyframe_next: without the extension, whether the next valid frame is the
    selector's keyframe; a frame that will not be mapped skips what only mapping reads
    (`parse_frame(mapped=False)`). Raises _Refused with the reply."""
    t0 = time.perf_counter()
    try:
        message = unpack_frame_message(data)
    except InputError as exc:
        raise _Refused(ErrorReply(None, "bad_message", str(exc)), is_frame=False) from None
    seq = stream_message_seq(message)
    engine = session.engine
    sighting = is_sighting(message)
    try:
        if sighting and not sightings:
            raise InputError(
                TYPE_FIELD,
                "a 'sighting' needs the stream socket opened with the WebSocket subprotocol "
                f"{SIGHTINGS_SUBPROTOCOL!r} (the sightings extension); send frames whole here",
            )
        if sighting:
            frame = parse_sighting(message, budget=budget)
            sent = engine.validate_sighting(frame)
        else:
            mapped = sightings or keyframe_next
            frame = parse_frame(
                message, rgb_pixels=engine.backend.needs_rgb, budget=budget, mapped=mapped
            )
            sent = engine.validate_frame(frame)
    except LimitError as exc:
        raise _Refused(ErrorReply(seq, "over_limit", str(exc)), is_frame=True) from None
    except InputError as exc:
        raise _Refused(ErrorReply(seq, "bad_frame", str(exc)), is_frame=True) from None
    return _Decoded(
        frame,
        sent,
        (time.perf_counter() - t0) * 1e3,
        part_sizes(message),
        sighting,
        mapped=not sighting and (sightings or keyframe_next),
    )


@router.websocket("/sessions/{sid}/stream")
async def stream(ws: WebSocket, sid: str, manager: Manager) -> None:
    """Frames in, exactly one ack or error out per frame.

    A device offering the WebSocket subprotocol SIGHTINGS_SUBPROTOCOL gets it selected: it
    then picks the keyframes (every `frame` it sends is mapped) and sends `sighting`s between
    them (app/protocol/sighting.py). Otherwise the server picks the keyframes among the
    frames it receives (app.keyframes)."""
    session = await _authorize(ws, manager, sid)
    if session is None:
        return
    try:
        await _stream_frames(ws, manager, session)
    finally:
        manager.release(session)


def _stream_id(ws: WebSocket) -> str | None:
    """The socket's stream id: the client's `x-semanticxr-stream` header, or None (a socket
    of its own); InputError naming the header when it is not 1-64 of [A-Za-z0-9_-]."""
    given = ws.headers.get(STREAM_HEADER)
    if given is None:
        return None
    if not 0 < len(given) <= MAX_STREAM_ID or not set(given) <= STREAM_ID_CHARS:
        raise InputError(STREAM_HEADER, f"1-{MAX_STREAM_ID} characters of [A-Za-z0-9_-]")
    return given


async def _stream_frames(ws: WebSocket, manager: SessionManager, session: Session) -> None:
    settings = manager.settings
    try:
        stream_id = _stream_id(ws)
    except InputError as exc:
        await ws.close(code=CLOSE_POLICY, reason=str(exc)[:120])
        return
    sightings = SIGHTINGS_SUBPROTOCOL in ws.scope.get("subprotocols", [])
    await ws.accept(subprotocol=SIGHTINGS_SUBPROTOCOL if sightings else None)
    send_lock = asyncio.Lock()

    async def reply(message: dict) -> None:
        async with send_lock:
            with contextlib.suppress(Exception):  # the client may be gone; the map is not affected
                await asyncio.wait_for(ws.send_bytes(msgpack.packb(message)), SEND_TIMEOUT_S)

    loop = asyncio.get_running_loop()

    def close_now() -> None:
        """The session closed (deleted, maybe from a request's thread, or moved) while this
        loop may be waiting for a frame: close the socket now, on the loop."""
        loop.call_soon_threadsafe(
            lambda: closing.append(asyncio.ensure_future(_close_if_gone(ws, session)))
        )

    closing: list[asyncio.Future] = []
    session.on_close.add(close_now)
    session.streams += 1
    bad_in_a_row = 0
    try:
        while not session.closed:
            event = await ws.receive()
            if event["type"] == "websocket.disconnect":
                break
            data = event.get("bytes")
            if data is None:
                manager.metrics.frames.labels(outcome="bad").inc()
                await reply(
                    ErrorReply(
                        None, "bad_message", "frames must be binary msgpack messages, got text"
                    ).pack()
                )
                bad_in_a_row += 1
            elif len(data) > settings.max_message_bytes:
                await reply(
                    ErrorReply(
                        None,
                        "too_big",
                        f"message of {len(data)} bytes exceeds {settings.max_message_bytes}",
                    ).pack()
                )
                await ws.close(code=CLOSE_TOO_BIG, reason="message too big")
                return
            else:
                decode = functools.partial(
                    _decode_and_validate, data, session, manager.frame_budget, sightings
                )
                try:
                    decoded = await manager.decode(
                        functools.partial(decode, keyframe_next=manager.keyframe_next(session))
                    )
                    picked = (not decoded.sighting) if sightings else None
                    keyframe = manager.count_frame(session, decoded.payload_bytes, picked)
                    if keyframe and not decoded.mapped:  # another socket's frame came first
                        decoded = await manager.decode(decode)
                except _Refused as refused:
                    if refused.is_frame:
                        manager.metrics.frames.labels(outcome="bad").inc()
                    await reply(refused.reply.pack())
                    bad_in_a_row += 1
                else:
                    bad_in_a_row = 0
                    manager.metrics.frames.labels(outcome="ok").inc()
                    frame = decoded.frame
                    if keyframe:
                        await manager.submit_keyframe(
                            session, frame, reply, decoded.sent, decoded.decode_ms, stream_id
                        )
                    else:
                        # Acked first: a sighting changes nothing the device waits for, and
                        # its ack time is an RTT sample (the SQ/LQ switch).
                        await reply(Ack(frame.seq, keyframe=False).pack())
                        await manager.sight(session, frame, decoded.sent)
            if bad_in_a_row >= settings.max_bad_frames:
                await ws.close(code=CLOSE_POLICY, reason=f"{bad_in_a_row} bad messages in a row")
                return
    except WebSocketDisconnect:
        return
    finally:
        session.on_close.discard(close_now)
        await manager.settle(session)  # the device stopped: its map settles once
        session.flush()  # the device stopped: its last changes go out now
        session.streams -= 1  # settled and published: a device waiting on `streams` goes on
        manager.save_counters_soon(session)  # and its frame count is saved
    if not closing:
        await _close_if_gone(ws, session)


async def _close_if_gone(ws: WebSocket, session: Session) -> None:
    """Close the socket of a session deleted (1001) or moved to another map shard (1012)."""
    if session.moved:
        with contextlib.suppress(Exception):
            await ws.close(code=CLOSE_SERVICE_RESTART, reason="session moved to another shard")
    elif session.closed:
        with contextlib.suppress(Exception):
            await ws.close(code=CLOSE_GOING_AWAY, reason="session deleted")


@router.websocket("/sessions/{sid}/updates")
async def updates(ws: WebSocket, sid: str, manager: Manager) -> None:
    """Per-object deltas since `since`, then one per publication, coalesced per object.

    One message is in flight at a time; publications meanwhile wait as a count (the next
    delta coalesces them). A subscriber more than SUBSCRIBER_QUEUE_UPDATES publications
    behind, or whose send has not gone out within SUBSCRIBER_STALL_S, is closed with 1013:
    it resumes with `since` = the last seq it applied."""
    session = await _authorize(ws, manager, sid)
    if session is None:
        return
    try:
        await _follow_updates(ws, manager, session)
    finally:
        manager.release(session)


async def _follow_updates(ws: WebSocket, manager: SessionManager, session: Session) -> None:
    raw_since = ws.query_params.get(SINCE_PARAM)
    try:
        since = None if raw_since in (None, "") else int(raw_since)
    except ValueError:
        await ws.close(code=CLOSE_POLICY, reason="since must be an integer")
        return
    if session.subscribers >= manager.settings.max_subscribers:
        await ws.close(code=CLOSE_TRY_LATER, reason="too many subscribers")
        return
    await ws.accept()
    session.subscribers += 1
    gone = asyncio.Event()

    async def watch_disconnect() -> None:
        with contextlib.suppress(Exception):
            while (await ws.receive())["type"] != "websocket.disconnect":
                pass  # subscribers have nothing to say; ignore whatever they send
        gone.set()

    async def send(data: bytes) -> None:
        await ws.send_bytes(data)  # waits while the socket's write buffer is over its limit
        session.bytes_out[UPDATES_BYTES] += len(data)
        manager.metrics.downstream_bytes.labels(kind=UPDATES_BYTES).inc(len(data))

    watcher = asyncio.create_task(watch_disconnect())
    sending: asyncio.Task | None = None
    sending_since = 0.0
    behind = 0
    """Publications since the message in flight was handed to the socket."""
    too_slow: str | None = None
    try:
        first = True
        while not session.closed and not gone.is_set():
            published = session.wait_published()  # taken before building: no publication is missed
            if sending is not None and sending.done():
                sending.result()  # a failed send (client gone) ends the subscription
                sending = None
            if sending is None:
                message = await asyncio.to_thread(session.build_delta, since)
                if first or has_news(message):
                    sending = asyncio.create_task(send(msgpack.packb(message)))
                    sending_since = time.monotonic()
                    first = False
                since, behind = delta_seq(message), 0
            waiter = asyncio.create_task(published.wait())
            waiting = {waiter, watcher} | ({sending} if sending is not None else set())
            stall_left = (
                None if sending is None else sending_since + SUBSCRIBER_STALL_S - time.monotonic()
            )
            await asyncio.wait(
                waiting,
                timeout=None if stall_left is None else max(stall_left, 0.0),
                return_when=asyncio.FIRST_COMPLETED,
            )
            published_now = waiter.done()
            waiter.cancel()
            if sending is None or sending.done():
                continue
            behind += published_now
            if behind > SUBSCRIBER_QUEUE_UPDATES:
                too_slow = f"{behind} updates unsent"
            elif time.monotonic() - sending_since >= SUBSCRIBER_STALL_S:
                too_slow = f"an update unsent for {SUBSCRIBER_STALL_S:g} s"
            if too_slow is not None:
                break
    except (WebSocketDisconnect, RuntimeError, OSError):  # the client went away
        pass
    finally:
        session.subscribers -= 1
        watcher.cancel()
        if sending is not None and not sending.done():
            sending.cancel()  # not written yet: it waits for room in the write buffer
    if too_slow is not None:
        manager.metrics.slow_subscribers_closed.inc()
        log.warning(
            "session %s: closed an update subscriber that cannot keep up (%s); "
            "it may resume with ?since=<its last seq>",
            session.id,
            too_slow,
        )
        # The close frame goes out once the client reads what is buffered (or the socket
        # dies); waiting for that costs this coroutine only.
        with contextlib.suppress(Exception):
            await ws.close(code=CLOSE_TRY_LATER, reason=f"too slow: {too_slow}; resume with since")
    else:
        await _close_if_gone(ws, session)
