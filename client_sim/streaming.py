"""The device's connection to the server: frames up, map updates down (wire protocol v1).

Two WebSockets, each kept up on its own with exponential backoff (0.2 s doubling to 5 s,
forever until `stop()`):

- `/v1/sessions/{sid}/stream` (`DeviceClient.stream`): encoded frames up, acks down. At most
  `max_in_flight` frames wait for their ack. Frames are samples, not a log: a frame due
  while the link is down is skipped (counted in `dropped`), never queued or resent. The
  device offers the sightings extension (app/protocol/sighting.py); where the server
  selects it, the device picks the keyframes (`app.keyframes`, the server's own selector,
  and a frame showing a place the newest keyframe's ack says the map doubts:
  `client_sim.keyframe_pick`) and sends only those whole, and between them a `sighting` of
  each frame's detections (a frame without detections then has nothing to send). Otherwise
  every frame goes whole.
- `/v1/sessions/{sid}/updates` (`DeviceClient.follow_updates`, an
  `app.client.UpdatesSubscriber`): deltas down, applied to the `LocalMap`. After a
  disconnect it resumes from `local_map.seq` (the server sends what changed since, so no
  update is lost); after a malformed message it resyncs from a full snapshot (no `since`).
  The local map validates a delta before changing anything, so a bad message never leaves
  it half-applied.

Round-trip time (the input of the SQ/LQ switch, client_sim/querying.py) is an EWMA
(alpha 0.2) of two kinds of samples: frame send -> ack (minus the server's mapping time for
keyframes, whose ack waits for the map) and WebSocket ping -> pong on the updates socket,
so a device that only follows updates still knows its RTT.

Not thread-safe: one asyncio loop runs the client, its local map and its queries.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import math
import ssl
import time
from collections import deque
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, TypeVar

import msgpack
import numpy as np
from websockets.asyncio.client import ClientConnection

from app.client import (
    CONNECTION_ERRORS,
    Backoff,
    Disconnect,
    SessionApi,
    UpdatesSubscriber,
    create_session,
    http_base_url,
    open_websocket,
    websocket_base_url,
)
from app.client.connection import describe, sleep_unless, until
from app.config import Knobs
from app.protocol import (
    SIGHTINGS_SUBPROTOCOL,
    ErrorReply,
    InputError,
    SessionStats,
    unpack_reply,
    unpack_update,
)
from client_sim.encoder import EncodedFrame, FrameEncoder, session_encoder_options
from client_sim.keyframe_pick import KeyframePick
from client_sim.local_map import DeltaError, LocalMap
from client_sim.sources.base import FrameSource

log = logging.getLogger(__name__)

RTT_EWMA_ALPHA = 0.2
"""Weight of a new RTT sample in the smoothed RTT."""
ACK_TIMEOUT_S = 15.0
"""A full window with no ack for this long: the connection is treated as dead and reopened."""
DRAIN_TIMEOUT_S = 30.0
"""At the end of `stream()`, how long to wait for the acks of frames in flight."""
STORAGE_BACKOFF_FIRST_S = 1.0
STORAGE_BACKOFF_MAX_S = 10.0
"""After a `storage_unavailable` error the device sends nothing for 1 s, doubling up to 10 s
while the errors go on (the server cannot save; its frames would only be refused)."""
DEFAULT_EMBEDDING_DIM = 384
"""all-MiniLM-L6-v2, the default text encoder's dimension (sessions announce theirs)."""


T = TypeVar("T")


class DeviceError(RuntimeError):
    """The device cannot work with this session (e.g. its text encoder is another model).
    A failed REST call raises app.client.ApiError."""


@dataclass
class DeviceStats:
    """Counters of one device (shared by `stream` and `follow_updates`)."""

    frames_sent: int = 0
    """Frames written to the stream socket (whole frames and sightings)."""
    sightings_sent: int = 0
    """Of `frames_sent`, sightings (the sightings extension: frames between keyframes)."""
    doubt_keyframes: int = 0
    """Of the frames sent whole with the sightings extension, those picked for showing a
    place the map doubts (not the shared selector's keyframes)."""
    acks: int = 0
    """Acks received (keyframes and others, including keyframes the server superseded)."""
    errors: int = 0
    """Server `error` replies and malformed replies (logged, never fatal)."""
    keyframes_acked: int = 0
    """Acks with keyframe = true (the frame was mapped)."""
    dropped: int = 0
    """Frames due while the stream socket was down (or the device backed off): skipped,
    never sent."""
    storage_backoff_skipped: int = 0
    """Of `dropped`, frames skipped while backing off after the server answered
    `storage_unavailable` (it could not save the map)."""
    bytes_up_by_kind: dict[str, int] = field(
        default_factory=lambda: {"rgb": 0, "depth": 0, "detections": 0, "pose": 0, "total": 0}
    )
    """Payload bytes sent per part of a frame; "total" is whole packed messages."""
    bytes_down: int = 0
    """Bytes received on both sockets (acks and deltas)."""
    rtt_ms_smoothed: float | None = None
    """EWMA of the RTT samples; None until the first sample (and after an outage)."""
    reconnects: int = 0
    """Successful re-connections of either socket after a loss."""
    last_error: str | None = None
    """The most recent problem, for a human."""
    resyncs: int = 0
    """Full-snapshot resyncs after a malformed update."""
    lost_in_flight: int = 0
    """Frames sent whose ack never came because the connection dropped."""
    superseded: int = 0
    """Keyframes the server acknowledged as dropped (a newer keyframe replaced them)."""
    deltas_applied: int = 0
    """Update messages applied to the local map."""
    full_snapshots: int = 0
    """Of those, full snapshots."""
    server_seq: int = 0
    """Newest map seq announced in acks (`update_seq`, an ack extension); 0 if none."""

    def copy(self) -> DeviceStats:
        return dataclasses.replace(self, bytes_up_by_kind=dict(self.bytes_up_by_kind))


def make_local_map(knobs: Knobs, embedding_dim: int = DEFAULT_EMBEDDING_DIM) -> LocalMap:
    """The local map a session's knobs ask for (point cap, budget, priorities)."""
    return LocalMap(
        dim=embedding_dim,
        max_points_per_object=knobs.max_object_points_client,
        budget_mb=knobs.local_map_budget_mb,
        priority_classes=knobs.priority_class,
        distance_threshold_m=knobs.distance_threshold_m,
    )


class DeviceClient:
    """A device's two sockets to one session, its local map and its counters.

    server_url: http(s)://host:port of the server. token: the session token (or the API key).
    knobs: the session's knobs (depth ratio for the encoder; point cap and budget for a
    default local map). encoder_options: FrameEncoder keyword arguments besides the depth
    ratio (jpeg_quality, depth_codec, depth_scale_m, ...); unset ones keep FrameEncoder's
    defaults. send_every: send only every n-th source frame. sightings: offer the sightings
    extension on the stream socket (keyframes whole, sightings between them, where the
    server selects it); False: every frame whole. local_map: where deltas go (default:
    `make_local_map(knobs, embedding_dim)`). on_log: receives one human-readable line per
    event worth telling (reconnects, server errors, resyncs); default: this module's logger.
    ssl_context: whom a wss:// server must prove to be (`app.client.trusting`; default: the
    system's CAs), for both sockets.
    """

    def __init__(
        self,
        server_url: str,
        session_id: str,
        token: str | None = None,
        *,
        knobs: Knobs | None = None,
        encoder_options: Mapping[str, Any] | None = None,
        send_every: int = 1,
        sightings: bool = True,
        local_map: LocalMap | None = None,
        on_log: Callable[[str], None] | None = None,
        embedding_dim: int = DEFAULT_EMBEDDING_DIM,
        ssl_context: ssl.SSLContext | None = None,
    ):
        if isinstance(send_every, bool) or not isinstance(send_every, int) or send_every < 1:
            raise ValueError(f"send_every must be a positive integer, got {send_every!r}")
        self.http_url = http_base_url(server_url)
        self.ws_url = websocket_base_url(server_url)
        self.session_id = session_id
        self.token = token
        self.ssl_context = ssl_context
        self.knobs = knobs or Knobs()
        self.encoder_options = dict(encoder_options or {})
        FrameEncoder(
            self.knobs.depth_downsampling_ratio,
            **session_encoder_options(self.knobs, self.encoder_options),
        )  # fail early
        self.send_every = send_every
        self.sightings = bool(sightings)
        self.local_map = (
            local_map if local_map is not None else make_local_map(self.knobs, embedding_dim)
        )
        self.stats = DeviceStats()
        self.subscriptions: deque[int | None] = deque(maxlen=1000)
        """`since` of each updates connection opened, oldest first (None = full snapshot)."""
        self._on_log = on_log or log.info
        self._stopped = asyncio.Event()
        self._stream_up = False
        self._updates_up = False
        self._outage = False  # a socket dropped and has not come back yet
        self._map_changed = asyncio.Event()  # replaced after each set: one event per change
        self._links: set[_StreamLink] = set()
        self._updates: UpdatesSubscriber | None = None
        self._next_seq = 0  # frame seq across stream() calls: unique per device
        self._pick = KeyframePick(
            self.knobs.keyframe_interval,
            self.knobs.absence_min_depth_m,
            self.knobs.absence_max_depth_m,
        )
        """Which frames go whole with the sightings extension; its doubted places come
        with keyframe acks."""

    # --- session set-up (REST) ------------------------------------------------------------

    @classmethod
    async def create_session(
        cls,
        server_url: str,
        *,
        name: str | None = None,
        mode: str = "semanticxr",
        knobs: dict | None = None,
        api_key: str | None = None,
        ssl_context: ssl.SSLContext | None = None,
    ) -> tuple[str, str, dict]:
        """POST /v1/sessions -> (session_id, token, the whole answer incl. embedding, knobs)."""
        return await create_session(
            server_url, name=name, mode=mode, knobs=knobs, api_key=api_key, ssl_context=ssl_context
        )

    @staticmethod
    async def fetch_session(
        server_url: str,
        session_id: str,
        token: str | None,
        *,
        ssl_context: ssl.SSLContext | None = None,
    ) -> SessionStats:
        """GET /v1/sessions/{sid}: stats, knobs in force, embedding model and dimension."""
        async with SessionApi(server_url, session_id, token, ssl_context=ssl_context) as api:
            return await api.fetch()

    @staticmethod
    async def patch_knobs(
        server_url: str,
        session_id: str,
        token: str | None,
        changes: dict,
        *,
        ssl_context: ssl.SSLContext | None = None,
    ) -> dict:
        """PATCH /v1/sessions/{sid}/knobs -> the knobs now in force."""
        async with SessionApi(server_url, session_id, token, ssl_context=ssl_context) as api:
            return await api.patch_knobs(changes)

    # --- state ----------------------------------------------------------------------------

    @property
    def connected(self) -> bool:
        """True while the stream or the updates socket is up."""
        return self._stream_up or self._updates_up

    @property
    def rtt_ms(self) -> float | None:
        """Smoothed RTT in ms while connected; `math.inf` during an outage (a socket dropped
        and none is back yet); None when unknown (no sample yet, or no socket running)."""
        if self.connected:
            return self.stats.rtt_ms_smoothed
        return math.inf if self._outage else None

    @property
    def stopped(self) -> bool:
        return self._stopped.is_set()

    async def wait_synced(self, seq: int, timeout_s: float = 10.0) -> bool:
        """Wait until the local map has applied seq `seq` (or later); False on timeout."""
        deadline = time.monotonic() + timeout_s
        while self.local_map.seq < seq:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return False
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._map_changed.wait(), remaining)
        return True

    async def stop(self) -> None:
        """Stop streaming and following updates; `stream` and `follow_updates` return soon.

        Final: a stopped client does not start again (make a new one, with the same local map
        to resume from its seq)."""
        self._stopped.set()
        for link in list(self._links):
            await link.notify()
        if self._updates is not None:
            await self._updates.stop()

    # --- helpers --------------------------------------------------------------------------

    def _log(self, message: str) -> None:
        try:
            self._on_log(message)
        except Exception:  # a broken log sink must not take the device down
            log.exception("on_log failed")

    def _problem(self, message: str) -> None:
        self.stats.last_error = message
        self._log(message)

    def _observe_rtt(self, sample_ms: float) -> None:
        smoothed = self.stats.rtt_ms_smoothed
        sample_ms = max(0.0, sample_ms)
        self.stats.rtt_ms_smoothed = (
            sample_ms if smoothed is None else smoothed + RTT_EWMA_ALPHA * (sample_ms - smoothed)
        )

    def _socket_up(self, which: str, reconnect: bool) -> None:
        if which == "stream":
            self._stream_up = True
        else:
            self._updates_up = True
        if reconnect:
            self.stats.reconnects += 1
            self._log(f"{which} socket reconnected")
        self._outage = False

    def _socket_down(self, which: str, reason: str, expected: bool) -> None:
        if which == "stream":
            self._stream_up = False
        else:
            self._updates_up = False
        if not expected and not self._stopped.is_set():
            # The link is gone: the old RTT says nothing about the link that comes back.
            self._outage = True
            self.stats.rtt_ms_smoothed = None
            self._problem(f"{which} socket lost ({reason}); reconnecting")

    async def _until_stopped(self, awaitable: Awaitable[T]) -> T | None:
        """`awaitable`'s result, or None (and it is cancelled) if `stop()` comes first."""
        return await until(self._stopped, awaitable)

    async def _sleep(self, seconds: float) -> bool:
        """Sleep (a pacing or backoff timer, not synchronisation); False if stopped meanwhile."""
        return await sleep_unless(self._stopped, seconds)

    async def _open(self, path: str, **kwargs: Any) -> ClientConnection | None:
        """Open a WebSocket to `path` (None if stopped first); raises the connection errors."""
        return await self._until_stopped(
            open_websocket(
                f"{self.ws_url}{path}", self.token, ssl_context=self.ssl_context, **kwargs
            )
        )

    # --- frames up ------------------------------------------------------------------------

    async def stream(
        self,
        source: FrameSource,
        fps: float | None = 5.0,
        limit: int | None = None,
        max_in_flight: int = 4,
        start: int = 0,
    ) -> DeviceStats:
        """Play `source` to the server; returns the counters when done (or stopped).

        fps: the source's frame rate (frame i is captured at (i - start) / fps s after the
        start);
        every `send_every`-th frame is sent when it is captured, and skipped (`dropped`) if
        the link is down at that moment. None: no clock, frames go as fast as acks allow,
        and while the link is down the device waits for it (no frame is captured meanwhile).
        limit: play only source frames start .. limit - 1 (None: to the source's end).
        start: the first source frame to play, e.g. where an earlier `stream()` of the same
        walk stopped, so a device continues its walk instead of replaying it.
        max_in_flight: most frames sent and not yet answered.

        Server errors and lost connections are counted and logged, never raised; an error of
        the source itself (an unreadable file) is raised, since no later frame would fare
        better.
        """
        if fps is not None and not (math.isfinite(fps) and fps > 0):
            raise ValueError(f"fps must be a positive number or None, got {fps!r}")
        if max_in_flight < 1:
            raise ValueError(f"max_in_flight must be >= 1, got {max_in_flight!r}")
        if isinstance(start, bool) or not isinstance(start, int) or start < 0:
            raise ValueError(f"start must be a non-negative integer, got {start!r}")
        encoder = FrameEncoder(
            self.knobs.depth_downsampling_ratio,
            **session_encoder_options(self.knobs, self.encoder_options),
        )
        n_frames = len(source) if limit is None else min(len(source), max(0, limit))
        link = _StreamLink(self, max_in_flight)
        self._links.add(link)
        runner = asyncio.create_task(link.run())
        loop = asyncio.get_running_loop()
        try:
            # The clock starts once the link has had its chance: frame 0 is not lost to the
            # connection handshake.
            await self._until_stopped(link.attempted.wait())
            start_s = loop.time()
            for index in range(start, n_frames, self.send_every):
                if fps is not None:
                    if not await self._sleep(start_s + (index - start) / fps - loop.time()):
                        break
                    if not await link.wait_for_slot(wait_for_link=False):
                        self.stats.dropped += 1
                        continue
                elif not await link.wait_for_slot(wait_for_link=True):
                    break  # stopped
                seq, self._next_seq = self._next_seq, self._next_seq + 1
                # With the extension, a frame the device's pick does not take is sighted.
                pick = self._pick if link.sightings else None
                encoded, position = await asyncio.to_thread(
                    self._capture, source, index, seq, encoder, pick
                )
                if encoded is None:
                    continue  # a sighting without detections: nothing to send
                if not await link.send(encoded):
                    if self.stopped:
                        break
                    self.stats.dropped += 1  # the link went down while the frame was encoded
                    continue
                # Eviction prefers nearby objects: the device's own position is the user's.
                self.local_map.set_user_position(position)
            await link.drain(DRAIN_TIMEOUT_S)
        finally:
            await link.close()
            runner.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await runner
            self._links.discard(link)
        return self.stats.copy()

    def _capture(
        self,
        source: FrameSource,
        index: int,
        seq: int,
        encoder: FrameEncoder,
        pick: KeyframePick | None,
    ) -> tuple[EncodedFrame | None, list[float]]:
        """In a worker thread: read (render) frame `index` and encode it as frame `seq`, whole
        or, where `pick` (the sightings extension) does not take it, as a sighting (None: a
        sighting of a frame without detections); slow (rendering, JPEG, zstd): off the loop
        so acks and deltas keep flowing."""
        frame = source.frame(index)
        position = [float(v) for v in frame.pose[:3, 3]]
        whole = pick is None
        if pick is not None:
            height, width = frame.rgb.shape[:2]
            picks_before = pick.doubt_picks
            whole = pick.pick(
                seq, frame.t, frame.pose, frame.intrinsics, (width, height), frame.depth_m
            )
            self.stats.doubt_keyframes += pick.doubt_picks - picks_before
        if whole:
            return encoder.encode_source_frame(frame, seq), position
        if frame.instance_ids is None:
            return None, position
        return encoder.encode_source_frame_as_sighting(frame, seq), position

    # --- map updates down -----------------------------------------------------------------

    async def follow_updates(self) -> None:
        """Apply the session's deltas to the local map until `stop()`.

        Resumes from `local_map.seq` after a disconnect; resyncs from a full snapshot after a
        malformed message. Starts from a full snapshot when the local map is new. Pings the
        socket for RTT samples.
        """
        if self._stopped.is_set():
            return
        self._updates = UpdatesSubscriber(
            self.ws_url,
            self.session_id,
            self.token,
            apply=self._receive_update,
            applied_seq=lambda: self.local_map.seq,
            start_from_snapshot=self.local_map.seq == 0 and len(self.local_map) == 0,
            on_connected=self._updates_connected,
            on_disconnected=self._updates_disconnected,
            on_rtt_ms=self._observe_rtt,
            ssl_context=self.ssl_context,
        )
        await self._updates.run()

    def _updates_connected(self, since: int | None, reconnect: bool) -> None:
        self.subscriptions.append(since)
        self._socket_up("updates", reconnect=reconnect and since is not None)

    def _updates_disconnected(self, event: Disconnect) -> None:
        if event.bad_update is not None:
            self.stats.resyncs += 1
            self._problem(event.reason)
        if not event.repeated:
            self._socket_down("updates", event.reason, expected=event.bad_update is not None)

    def _receive_update(self, raw: bytes | str) -> str | None:
        self.stats.bytes_down += len(raw)
        return self._apply_update(raw)

    def _apply_update(self, raw: bytes | str) -> str | None:
        """Apply one updates-socket message; what was wrong with it, or None if applied."""
        message = unpack_update(raw)
        if isinstance(message, str):
            return message
        try:
            self.local_map.apply_delta(message)
        except DeltaError as exc:
            return str(exc)
        except Exception as exc:
            # apply_delta validates before it writes, so this is a bug, not a bad message;
            # a full snapshot replaces whatever the map holds, so resyncing is still safe.
            log.exception("applying an update failed")
            return f"{type(exc).__name__}: {exc}"
        self.stats.deltas_applied += 1
        self.stats.full_snapshots += bool(message["full"])
        event, self._map_changed = self._map_changed, asyncio.Event()
        event.set()
        return None


class _StreamLink:
    """The stream socket of one `stream()` call: kept up, with its window of un-acked frames."""

    def __init__(self, client: DeviceClient, max_in_flight: int):
        self.client = client
        self.stats = client.stats
        self.max_in_flight = max_in_flight
        self.ws: ClientConnection | None = None
        self.in_flight: dict[int, float] = {}  # frame seq -> send time (perf_counter s)
        self.changed = asyncio.Condition()
        self.closing = False
        self.attempted = asyncio.Event()
        """Set once the first connection attempt has succeeded or failed."""
        self.storage_backoff = Backoff(STORAGE_BACKOFF_FIRST_S, STORAGE_BACKOFF_MAX_S)
        self.storage_failing = False
        """The server answered storage_unavailable and has not acked a keyframe since."""
        self.hold_until_s = 0.0
        """time.monotonic() before which nothing is sent (a storage back-off)."""
        self.sightings = False
        """The server selected the sightings extension on the socket now up."""

    async def notify(self) -> None:
        async with self.changed:
            self.changed.notify_all()

    def _done(self) -> bool:
        return self.closing or self.client.stopped

    async def run(self) -> None:
        """Keep the socket up until closed; read replies while it is."""
        client = self.client
        backoff = Backoff()
        ever_up = down_told = False
        path = f"/v1/sessions/{client.session_id}/stream"
        offer = {"subprotocols": [SIGHTINGS_SUBPROTOCOL]} if client.sightings else {}
        while not self._done():
            try:
                ws = await client._open(path, **offer)
            except CONNECTION_ERRORS as exc:
                if not down_told:
                    client._socket_down("stream", describe(exc), expected=False)
                    down_told = True
            else:
                if ws is None:  # stopped while connecting
                    break
                self.ws = ws
                self.sightings = ws.subprotocol == SIGHTINGS_SUBPROTOCOL
                client._socket_up("stream", reconnect=ever_up)
                ever_up, down_told = True, False
                backoff.reset()
                reason = "closed by the server"
                self.attempted.set()
                await self.notify()
                try:
                    async for raw in ws:
                        self.stats.bytes_down += len(raw)
                        self._on_reply(raw)
                        await self.notify()
                except CONNECTION_ERRORS as exc:
                    reason = describe(exc)
                finally:
                    self.ws = None
                    self.sightings = False
                    # Sent frames whose ack can no longer come; they are not resent.
                    self.stats.lost_in_flight += len(self.in_flight)
                    self.in_flight.clear()
                    client._socket_down("stream", reason, expected=self._done())
                    down_told = not self._done()
                    await self.notify()
            self.attempted.set()
            if self._done() or not await client._sleep(backoff.next_delay()):
                break
        self.attempted.set()

    def _on_reply(self, raw: bytes | str) -> None:
        """Count one ack or error; feed the RTT from acks."""
        received_s = time.perf_counter()
        try:
            reply = unpack_reply(raw)
        except InputError:
            self.stats.errors += 1
            self.client._problem("malformed reply on the stream socket")
            return
        seq = reply.seq
        if seq is None and self.in_flight:
            # Every frame gets exactly one reply; an error without a seq answers the oldest.
            sent_s = self.in_flight.pop(next(iter(self.in_flight)))
        else:
            sent_s = self.in_flight.pop(seq, None) if seq is not None else None
        if isinstance(reply, ErrorReply):
            self.stats.errors += 1
            if reply.code == "storage_unavailable":
                self._storage_refused(reply)
            else:
                self.client._problem(f"server error for frame {seq}: {reply.code}: {reply.message}")
            return
        self.stats.acks += 1
        if reply.dropped:
            self.stats.superseded += 1
        elif reply.keyframe:
            self.stats.keyframes_acked += 1
            if reply.doubted is not None:
                self.client._pick.doubted = np.asarray(reply.doubted, np.float64).reshape(-1, 5)
            if self.storage_failing:
                self.storage_failing = False
                self.storage_backoff.reset()
                self.client._log("the server saves the map again; streaming resumes")
        if reply.update_seq is not None:
            self.stats.server_seq = max(self.stats.server_seq, reply.update_seq)
        if sent_s is not None and not reply.dropped:
            # A keyframe's ack waits for its mapping: take that server time out of the sample.
            # (A superseded keyframe waited in a queue for an unknown time: no sample.)
            map_ms = reply.map_ms if reply.keyframe else 0.0
            self.client._observe_rtt((received_s - sent_s) * 1e3 - map_ms)

    def _storage_refused(self, reply: ErrorReply) -> None:
        """The server cannot save: send nothing for a back-off period (1 s doubling to 10 s
        while it lasts). Frames already in flight when the back-off began do not extend it.
        Logged once per streak."""
        now = time.monotonic()
        if not self.storage_failing:
            self.storage_failing = True
            self.client._problem(
                f"the server cannot save the map ({reply.message}); backing off, "
                "frames due meanwhile are skipped"
            )
        if now >= self.hold_until_s:
            self.hold_until_s = now + self.storage_backoff.next_delay()

    async def wait_for_slot(self, wait_for_link: bool) -> bool:
        """True once the socket is up with room in the window; False if stopped, or if the
        socket is down (or a storage back-off runs) and `wait_for_link` is False (a frame
        skipped in a back-off counts in `storage_backoff_skipped`). A window stuck full for
        ACK_TIMEOUT_S means a dead connection: it is aborted and reopened."""
        async with self.changed:
            while not self._done():
                backoff_s = self.hold_until_s - time.monotonic()
                if backoff_s > 0:
                    if not wait_for_link:
                        self.stats.storage_backoff_skipped += 1
                        return False
                    with contextlib.suppress(TimeoutError):  # a back-off timer (or stop)
                        await asyncio.wait_for(self.changed.wait(), backoff_s)
                    continue
                if self.ws is None:
                    if not wait_for_link:
                        return False
                    await self.changed.wait()
                    continue
                if len(self.in_flight) < self.max_in_flight:
                    return True
                try:
                    await asyncio.wait_for(self.changed.wait(), ACK_TIMEOUT_S)
                except TimeoutError:
                    self.client._problem(f"no ack for {ACK_TIMEOUT_S:g} s; reconnecting")
                    if self.ws is not None:
                        self.ws.transport.abort()
            return False

    async def send(self, encoded: EncodedFrame) -> bool:
        """Send one encoded frame; False if the socket went down first."""
        ws = self.ws
        if ws is None or self._done():
            return False
        data = msgpack.packb(encoded.message, use_bin_type=True)
        seq = encoded.message["seq"]
        self.in_flight[seq] = time.perf_counter()
        try:
            await ws.send(data)
        except CONNECTION_ERRORS:
            self.in_flight.pop(seq, None)
            return False
        self.stats.frames_sent += 1
        self.stats.sightings_sent += encoded.message["type"] == "sighting"
        for kind, n_bytes in encoded.bytes_by_kind.items():
            self.stats.bytes_up_by_kind[kind] = self.stats.bytes_up_by_kind.get(kind, 0) + n_bytes
        return True

    async def drain(self, timeout_s: float) -> None:
        """Wait for the replies of frames in flight (not across an outage: those are lost)."""
        deadline = time.monotonic() + timeout_s
        async with self.changed:
            while self.in_flight and self.ws is not None and not self._done():
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self.changed.wait(), remaining)

    async def close(self) -> None:
        self.closing = True
        ws = self.ws
        if ws is not None:
            with contextlib.suppress(Exception):
                await ws.close()
        await self.notify()
