"""`semanticxr device`: an emulated XR device that streams a source, follows the map and asks.

    semanticxr device --server http://127.0.0.1:8000 --create --source synthetic:living_room \\
        --frames 150 --fps 5 --query "where is the sofa" --json device.json

It creates (or joins) a session, streams the source's frames at --fps (every --send-every-th
frame), keeps a local copy of the map from the session's updates, prints progress on stderr
about once a second, and at the end asks each --query (SQ or LQ, see client_sim/querying.py)
and prints the answers, then each --ask-audio recording, which the server recognises and
answers. Ctrl-C stops it cleanly (the summary is still written).

Local queries need the session's text encoder (the model the session announces in
`embedding`): MiniLM is packaged; CLIP's text tower (sessions on `--perception models`)
comes from `--models-dir DIR`, the folder the server's `--models-dir` holds (text tower
only); a static tower (`--create --text-tower static`) is downloaded from the server by
its hash once and kept in `--tower-cache DIR`. Without one the device says once that local
queries are off and asks the server.
Exit status: 0 when streaming worked and every query got an answer, 1 when a query (typed or
spoken) got none, 2 on a set-up error (a missing --ask-audio file or one of unknown type among
them), 130 on Ctrl-C.

The device itself is client_sim (DeviceClient, QueryRouter, the local map); this module is
the command around it: flags, progress line, answers and the summary.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import dataclasses
import math
import os
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from app.cli.common import frames_words, write_json
from app.client import ApiError, http_base_url
from app.client.rest import AUDIO_FILE_TYPES, audio_type, parsed_answer
from app.config import Knobs, updated_knobs
from app.flags import (
    add_knob_flags,
    add_tls_ca_flag,
    explicit_knobs,
    knobs_from_args,
    server_url,
)
from app.protocol import SessionCreated, SessionStats

if TYPE_CHECKING:  # the real imports are in the functions: torch loads in ~1.5 s, and
    # app.cli builds this parser for every command, not only `device`
    from collections.abc import Callable

    from app.semantics import TextEncoder
    from client_sim.querying import QueryAnswer
    from client_sim.sources.base import FrameSource
    from client_sim.streaming import DeviceClient

PROGRESS_PERIOD_S = 1.0
"""How often the progress line is printed."""
SYNC_TIMEOUT_S = 3.0
"""After streaming, how long to wait for the local map to catch up before querying. The
server publishes every `local_map_update_frequency` keyframes, so the last keyframes' changes
may never be pushed: the wait is short, and queries go ahead either way."""
SYNTHETIC_DEFAULT_FRAMES = 300


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the `device` subcommand (with its knob flags) to `semanticxr`'s subparsers."""
    parser = subparsers.add_parser(
        "device",
        help="emulate an XR device: stream a source to a server, follow the map, ask queries",
        description="Stream RGB-D frames to a SemanticXR server over wire protocol v1, keep a "
        "local copy of the map from its updates, and answer queries by server query (SQ) or "
        "local query (LQ) depending on the round-trip time.",
    )
    parser.add_argument(
        "--server", required=True, type=server_url, metavar="URL", help="e.g. http://host:8000"
    )
    add_tls_ca_flag(parser)
    session = parser.add_argument_group("session (join one, or --create one)")
    session.add_argument("--session", metavar="SID", help="session id to join")
    session.add_argument("--token", help="the session's token (default: the API key)")
    session.add_argument("--create", action="store_true", help="create a new session")
    session.add_argument("--name", help="name of the created session")
    session.add_argument(
        "--mode", default="semanticxr", choices=("semanticxr", "baseline"), help="of --create"
    )
    session.add_argument(
        "--text-tower",
        default="minilm",
        choices=("minilm", "static"),
        help="of --create: the session's text tower (static: a table distilled from MiniLM, "
        "which the device downloads by hash and answers local queries with in well under a "
        "millisecond; default minilm)",
    )
    session.add_argument(
        "--api-key",
        default=os.environ.get("SEMANTICXR_API_KEY"),
        help="server API key, needed by --create when set (default: env SEMANTICXR_API_KEY)",
    )
    parser.add_argument(
        "--source",
        default="synthetic:apartment",
        help="synthetic:<scene> | 7scenes:<dir> | replica:<dir> | tum:<dir> | "
        "record3d:<file.r3d> | stray:<dir> (iPhone/iPad captures) (default synthetic:apartment)",
    )
    parser.add_argument(
        "--source-max-side",
        type=int,
        metavar="PX",
        help="record3d:/stray: captures: scale frames so their longer side is at most PX, "
        "intrinsics with them (default 640, the emulated device's 640x480; 0 keeps the "
        "capture's size, 1920x1440 on a LiDAR iPhone)",
    )
    parser.add_argument(
        "--frames",
        type=int,
        metavar="N",
        help=f"source frames to play (default: all; synthetic walks {SYNTHETIC_DEFAULT_FRAMES})",
    )
    parser.add_argument(
        "--fps", type=float, default=5.0, help="source frame rate; 0 = as fast as acks allow"
    )
    parser.add_argument(
        "--send-every", type=int, default=1, metavar="N", help="send every N-th frame only"
    )
    parser.add_argument(
        "--max-in-flight", type=int, default=4, metavar="N", help="un-acked frames at most"
    )
    parser.add_argument(
        "--whole-frames",
        dest="sightings",
        action="store_false",
        help="send every frame whole, as a plain v1 client does, instead of offering the "
        "sightings extension (keyframes whole, coarse sightings between them)",
    )
    add_encoder_flags(parser)
    parser.add_argument(
        "--query",
        action="append",
        default=[],
        metavar="TEXT",
        help="ask this at the end (repeatable); prints mode, latency and top results",
    )
    parser.add_argument(
        "--ask-audio",
        action="append",
        default=[],
        metavar="FILE",
        help="ask this recorded question at the end, after the --query ones (repeatable): the "
        "server recognises it offline and answers as a typed query is answered; prints what "
        "it heard and the answer. Its type comes from the extension: "
        + ", ".join(AUDIO_FILE_TYPES),
    )
    parser.add_argument("-k", type=int, default=3, help="results per query")
    parser.add_argument(
        "--models-dir",
        metavar="DIR",
        help="where the text tower of a `--perception models` session is (the server's "
        "--models-dir; only the text tower is loaded); without it such a session's queries "
        "go to the server",
    )
    parser.add_argument(
        "--tower-cache",
        metavar="DIR",
        help="where the static text towers downloaded from servers are kept, by hash "
        "(default ~/.cache/semanticxr/towers)",
    )
    parser.add_argument(
        "--rerank",
        action="store_true",
        help="on a static-tower session, ask the server to re-rank its answers with MiniLM "
        "(server queries only; local answers stay the static tower's)",
    )
    parser.add_argument("--json", metavar="PATH", help="write a summary as JSON here")
    add_knob_flags(parser)
    parser.set_defaults(func=run)
    return parser


def add_encoder_flags(parser: argparse.ArgumentParser) -> None:
    """Flags of the upstream encoding (defaults: client_sim/encoder.py, chosen by bench.device)."""
    from app.codecs import DEPTH_CODECS
    from client_sim import encoder

    group = parser.add_argument_group("upstream encoding (all within wire protocol v1)")
    group.add_argument(
        "--jpeg-quality",
        type=int,
        default=encoder.DEFAULT_JPEG_QUALITY,
        help="RGB JPEG quality 1..100 (default %(default)s; the `detections` backend does not "
        "look at RGB, a `clip` backend would)",
    )
    group.add_argument(
        "--no-jpeg-optimize",
        dest="jpeg_optimize",
        action="store_false",
        help="skip the optimised Huffman tables (lossless, ~2 kB smaller per 640x480 frame)",
    )
    group.add_argument(
        "--depth-codec",
        choices=DEPTH_CODECS,
        default=encoder.DEFAULT_DEPTH_CODEC,
        help="codec of the uint16 depth image (default %(default)s)",
    )
    group.add_argument(
        "--depth-step-mm",
        type=float,
        default=encoder.DEFAULT_DEPTH_SCALE_M * 1000,
        metavar="MM",
        help="depth units on the wire (the frame's depth.scale): depth is rounded to this "
        "step; 1 keeps millimetres (default %(default)g)",
    )
    group.add_argument(
        "--detections-codec",
        choices=DEPTH_CODECS,
        default=encoder.DEFAULT_DETECTIONS_CODEC,
        help="codec of the instance-id image (default %(default)s)",
    )
    group.add_argument(
        "--zstd-level",
        type=int,
        default=encoder.DEFAULT_ZSTD_LEVEL,
        help=f"zstd level 1..{encoder.MAX_ZSTD_LEVEL} of zstd images (default %(default)s)",
    )


def encoder_options_from_args(args: argparse.Namespace) -> dict[str, Any]:
    """FrameEncoder keyword arguments of the encoding flags; ValueError if one is bad."""
    from client_sim.encoder import FrameEncoder

    options = {
        "jpeg_quality": args.jpeg_quality,
        "jpeg_optimize": args.jpeg_optimize,
        "depth_codec": args.depth_codec,
        "depth_scale_m": args.depth_step_mm / 1000,
        "detections_codec": args.detections_codec,
        "zstd_level": args.zstd_level,
    }
    FrameEncoder(**options)  # validates each option; the message names the bad one
    return options


def run(args: argparse.Namespace) -> int:
    """Run the device command; 0 on success, 1 when a query got no answer, 2 on a set-up
    error, 130 on Ctrl-C."""
    from client_sim.sources import SourceError
    from client_sim.streaming import DeviceError

    knobs_from_args(args)  # validates the knob flags (KnobError names the bad one)
    if not args.create and not args.session:
        print("semanticxr device: give --session SID (with --token) or --create", file=sys.stderr)
        return 2
    if args.send_every < 1 or args.max_in_flight < 1 or (args.frames or 0) < 0 or args.fps < 0:
        print(
            "semanticxr device: --send-every and --max-in-flight must be >= 1, "
            "--frames and --fps >= 0",
            file=sys.stderr,
        )
        return 2
    try:
        http_base_url(args.server)
        encoder_options_from_args(args)
        # The source and the recordings first: a wrong path should not leave an empty
        # session behind.
        source = make_device_source(args.source, args.frames, args.source_max_side)
        recordings = read_recordings(args.ask_audio)
    except (ValueError, OSError) as exc:
        print(f"semanticxr device: {exc}", file=sys.stderr)
        return 2
    try:
        return asyncio.run(_run(args, source, recordings))
    except (ApiError, DeviceError, SourceError) as exc:  # SourceError: a frame that cannot be read
        print(f"semanticxr device: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("\ninterrupted", file=sys.stderr)
        return 130


def make_device_source(
    spec: str, frames: int | None, max_side_px: int | None = None
) -> FrameSource:
    """synthetic:<scene> (a walk of `frames` frames) or a recorded dataset "kind:path";
    `max_side_px` (None: the source's default, 0: full size) for iPhone/iPad captures only."""
    from client_sim.sources import PHONE_SOURCE_KINDS, make_source

    kind, _, rest = spec.partition(":")
    if kind == "synthetic":
        from client_sim.sources.synthetic import SyntheticSource

        return SyntheticSource(rest or "apartment", n_frames=frames or SYNTHETIC_DEFAULT_FRAMES)
    if max_side_px is None:
        return make_source(spec)
    if kind not in PHONE_SOURCE_KINDS:
        raise ValueError(f"--source-max-side applies to {' and '.join(PHONE_SOURCE_KINDS)} sources")
    if max_side_px < 0:
        raise ValueError(f"--source-max-side must be >= 0 (0: full size), got {max_side_px}")
    return make_source(spec, max_side_px=max_side_px or None)


@dataclasses.dataclass(frozen=True)
class Recording:
    """A recorded question to ask (--ask-audio)."""

    path: str
    content_type: str
    """Its type by its extension (`app.client.rest.audio_type`), e.g. "audio/wav"."""
    audio: bytes


def read_recordings(paths: list[str]) -> list[Recording]:
    """Each --ask-audio file, read whole with its type; ValueError for an unknown extension,
    OSError naming a file that cannot be read."""
    recordings = []
    for path in paths:
        try:
            content_type = audio_type(path)  # before reading: the extension is the first check
            audio = Path(path).read_bytes()
        except ValueError as exc:
            raise ValueError(f"--ask-audio {exc}") from None
        except OSError as exc:
            raise OSError(f"--ask-audio {path}: {exc.strerror or exc}") from None
        recordings.append(Recording(path, content_type, audio))
    return recordings


async def _join_session(
    args: argparse.Namespace,
) -> tuple[str, str | None, SessionCreated | SessionStats]:
    """(session id, token, the session's `knobs` and `embedding`: the answer creating it, or its
    stats) for --create or --session."""
    from app.client.rest import create_session
    from client_sim.streaming import DeviceClient

    changes = explicit_knobs(args)
    if args.create:
        sid, token, answer = await create_session(
            args.server,
            name=args.name,
            mode=args.mode,
            knobs=changes,
            api_key=args.api_key,
            ssl_context=args.tls_ca,
            text_tower=args.text_tower,
        )
        print(f"[device] created session {sid} (token {token})", file=sys.stderr)
        return sid, token, parsed_answer(SessionCreated, answer, "POST /v1/sessions")
    token = args.token or args.api_key
    trust = args.tls_ca
    if changes:  # knobs are settable at run time: the flags apply to the joined session
        await DeviceClient.patch_knobs(args.server, args.session, token, changes, ssl_context=trust)
    stats = await DeviceClient.fetch_session(args.server, args.session, token, ssl_context=trust)
    return args.session, token, stats


class _Progress:
    """The once-a-second status line: frames, fps, upstream Mbps, local objects, RTT, mode."""

    def __init__(
        self, client: DeviceClient, threshold_ms: float, n_frames: int, local_queries: bool
    ):
        self.client, self.threshold_ms, self.n_frames = client, threshold_ms, n_frames
        self.local_queries = local_queries
        self.start_s = self._last_s = time.monotonic()
        self._last_sent = 0
        self._last_bytes = 0

    def line(self) -> str:
        from client_sim.querying import planned_mode

        stats, now_s = self.client.stats, time.monotonic()
        elapsed_s = max(now_s - self._last_s, 1e-6)
        sent, up_bytes = stats.frames_sent, stats.bytes_up_by_kind.get("total", 0)
        fps = (sent - self._last_sent) / elapsed_s
        mbps = (up_bytes - self._last_bytes) * 8 / elapsed_s / 1e6
        self._last_s, self._last_sent, self._last_bytes = now_s, sent, up_bytes
        rtt = self.client.rtt_ms
        rtt_text = "?" if rtt is None else ("down" if math.isinf(rtt) else f"{rtt:.0f} ms")
        local = self.client.local_map
        mode = planned_mode(rtt, self.threshold_ms) if self.local_queries else "SQ (LQ off)"
        return (
            f"[device] sent {sent}/{self.n_frames} ({fps:.1f} fps, {mbps:.2f} Mbps up) "
            f"acked {stats.acks} dropped {stats.dropped} | local {len(local)} objects "
            f"{local.memory_bytes() / 1e6:.2f} MB seq {local.seq} | RTT {rtt_text} "
            f"query {mode} | reconnects {stats.reconnects}"
        )

    async def run(self) -> None:
        while True:
            await asyncio.sleep(PROGRESS_PERIOD_S)  # a display period, not synchronisation
            print(self.line(), file=sys.stderr, flush=True)


def _print_answer(answer: QueryAnswer) -> None:
    ranked = f"; ranked by {answer.ranked_by}" if answer.ranked_by else ""
    print(
        f"{answer.text!r}: {answer.mode} in {answer.latency_ms:.1f} ms ({answer.reason}{ranked})",
        flush=True,
    )
    if not answer.results:
        print("  (no objects)")
    elif not answer.match:
        print("  no confident match; the nearest objects:")
    for hit in answer.results:
        centroid = ", ".join(f"{v:.2f}" for v in hit["centroid"])
        print(
            f"  #{hit['id']:<5} {hit['label']:<24} relevance {hit['relevance']:.2f} "
            f"(score {hit['score']:.3f})  at ({centroid})"
        )


def _print_spoken(recording: Recording, answer: QueryAnswer) -> None:
    """What the server heard of a recording, then its answer as a typed one's is printed."""
    if answer.transcript is None:
        print(f"{recording.path}: {answer.reason}", flush=True)
        return
    sure = "" if answer.confidence is None else f", confidence {answer.confidence:.2f}"
    print(
        f"{recording.path}: heard {answer.transcript!r} (recognised on the server in "
        f"{answer.asr_ms:.0f} ms{sure})",
        flush=True,
    )
    _print_answer(answer)


def _local_queries(
    args: argparse.Namespace, embedding: dict
) -> tuple[Callable[[], TextEncoder] | None, str | None]:
    """(loader of the session's text encoder, None) or (None, why local queries are off);
    says which, once, on stderr."""
    from client_sim.querying import EncoderMismatchError, LocalQueriesOff, session_encoder_loader

    try:
        loader = session_encoder_loader(
            embedding,
            args.models_dir,
            server_url=args.server,
            ssl_context=args.tls_ca,
            tower_cache=args.tower_cache,
        )
        return loader, None
    except LocalQueriesOff as exc:
        print(f"[device] local queries are off for this session: {exc}", file=sys.stderr)
        return None, str(exc)
    except EncoderMismatchError as exc:
        print(f"semanticxr device: error: {exc}", file=sys.stderr)
        return None, str(exc)


async def _run(args: argparse.Namespace, source: FrameSource, recordings: list[Recording]) -> int:
    from client_sim.querying import NONE, EncoderMismatchError, QueryRouter
    from client_sim.streaming import DeviceClient, make_local_map

    sid, token, info = await _join_session(args)
    knobs = updated_knobs(Knobs(), info.knobs.model_dump())  # the knobs in force on the server
    embedding = info.embedding.model_dump()
    n_frames = len(source) if args.frames is None else min(args.frames, len(source))
    client = DeviceClient(
        args.server,
        sid,
        token,
        knobs=knobs,
        encoder_options=encoder_options_from_args(args),
        send_every=args.send_every,
        sightings=args.sightings,
        local_map=make_local_map(knobs, embedding["dim"]),
        on_log=lambda message: print(f"[device] {message}", file=sys.stderr, flush=True),
        ssl_context=args.tls_ca,
    )
    loader, local_off = _local_queries(args, embedding)
    # The text encoder takes seconds to load: in parallel with streaming, and only if needed.
    load_it = args.query and loader is not None
    encoder_task = _load_encoder_in_background(loader) if load_it else None
    threshold_ms = knobs.net_latency_switch_threshold_ms
    progress = _Progress(
        client, threshold_ms, len(range(0, n_frames, args.send_every)), local_off is None
    )
    tasks = [asyncio.create_task(client.follow_updates()), asyncio.create_task(progress.run())]
    answers: list[QueryAnswer] = []
    start_s = time.monotonic()
    interrupted = False
    try:
        stats = await client.stream(
            source, fps=args.fps or None, limit=n_frames, max_in_flight=args.max_in_flight
        )
        if not await client.wait_synced(stats.server_seq, SYNC_TIMEOUT_S):
            print(
                f"[device] local map at seq {client.local_map.seq}, server at "
                f"{stats.server_seq} after {SYNC_TIMEOUT_S:g} s (the server publishes every "
                f"{knobs.local_map_update_frequency} keyframes; the rest comes with the next)",
                file=sys.stderr,
            )
        print(progress.line(), file=sys.stderr, flush=True)
        with contextlib.suppress(ApiError):  # what the server counted and warned of, if reachable
            session = await _after_settle(client, args, sid, token)
            print(
                f"[device] the server counted {frames_words(session)}", file=sys.stderr, flush=True
            )
            for warning in session.warnings:  # each said once
                print(f"[device] server warns: {warning}", file=sys.stderr, flush=True)
            # a closed stream settles the server's map: its update comes after the last ack
            if session.update_seq > stats.server_seq and await client.wait_synced(
                session.update_seq, SYNC_TIMEOUT_S
            ):
                stats.server_seq = session.update_seq
        encoder = None
        if encoder_task is not None:
            try:
                encoder = await encoder_task
            except (EncoderMismatchError, OSError, ValueError) as exc:  # refused, or unreadable
                local_off = f"{exc}"
                print(f"semanticxr device: error: {exc}", file=sys.stderr)
        if args.query or recordings:
            async with QueryRouter(
                args.server,
                sid,
                token,
                client.local_map,
                encoder,
                threshold_ms=threshold_ms,
                rtt_ms=lambda: client.rtt_ms,
                embedding=embedding,
                local_off_reason=local_off or "",
                ssl_context=args.tls_ca,
                rerank=args.rerank,
            ) as router:
                for text in args.query:
                    answers.append(await router.query(text, args.k))
                    _print_answer(answers[-1])
                for recording in recordings:
                    answers.append(
                        await router.ask_aloud(recording.audio, recording.content_type, args.k)
                    )
                    _print_spoken(recording, answers[-1])
    except asyncio.CancelledError:  # Ctrl-C: asyncio.run cancels us, then raises KeyboardInterrupt
        interrupted = True
        raise
    finally:
        await client.stop()
        for task in tasks:
            task.cancel()
        if encoder_task is not None:
            encoder_task.cancel()
            tasks.append(encoder_task)
        await asyncio.gather(*tasks, return_exceptions=True)
        if args.json:
            summary = _summary(args, sid, client, answers, start_s, interrupted)
            summary["local_queries"] = {"on": local_off is None, "off_because": local_off}
            write_json(args.json, summary)
    unanswered = sum(answer.mode == NONE for answer in answers)
    if unanswered:
        print(
            f"semanticxr device: {unanswered} of {len(answers)} queries got no answer",
            file=sys.stderr,
        )
        return 1
    return 0


async def _after_settle(client, args: argparse.Namespace, sid: str, token: str | None):
    """The session's stats once the server has settled the map after our stream closed (its
    `streams` back to 0; a server that does not count them is read at once), waiting at most
    SYNC_TIMEOUT_S: a query asked before the settle is published would be answered by a map
    the server no longer holds."""
    deadline = time.monotonic() + SYNC_TIMEOUT_S
    while True:
        session = await client.fetch_session(args.server, sid, token, ssl_context=args.tls_ca)
        if not session.streams or time.monotonic() >= deadline:
            return session
        await asyncio.sleep(0.05)


def _load_encoder_in_background(load: Callable[[], TextEncoder]) -> asyncio.Future[TextEncoder]:
    """The text encoder for LQ, loaded in a daemon thread: a Ctrl-C during the load exits at
    once instead of waiting for it (asyncio.to_thread's pool is joined at exit)."""
    loop = asyncio.get_running_loop()
    future: asyncio.Future[TextEncoder] = loop.create_future()

    def settle(result: TextEncoder | None, error: BaseException | None) -> None:
        if future.done():  # cancelled meanwhile
            return
        if error is not None:
            future.set_exception(error)
        else:
            future.set_result(result)

    def run_load() -> None:
        try:
            encoder = load()  # checks the encoder against the session's announcement
        except BaseException as exc:
            with contextlib.suppress(RuntimeError):  # the loop may be closed already
                loop.call_soon_threadsafe(settle, None, exc)
        else:
            with contextlib.suppress(RuntimeError):
                loop.call_soon_threadsafe(settle, encoder, None)

    threading.Thread(target=run_load, name="load-text-encoder", daemon=True).start()
    return future


def _summary(
    args: argparse.Namespace,
    sid: str,
    client: DeviceClient,
    answers: list[QueryAnswer],
    start_s: float,
    interrupted: bool,
) -> dict:
    """The --json document (times in ms, sizes in bytes, rates per second)."""
    stats = client.stats
    duration_s = max(time.monotonic() - start_s, 1e-6)
    local = client.local_map
    return {
        "server": args.server,
        "session_id": sid,
        "source": args.source,
        "interrupted": interrupted,
        "duration_s": duration_s,
        "frames": {
            "sent": stats.frames_sent,
            "sightings": stats.sightings_sent,
            "acked": stats.acks,
            "keyframes": stats.keyframes_acked,
            "superseded": stats.superseded,
            "dropped": stats.dropped,
            "lost_in_flight": stats.lost_in_flight,
            "errors": stats.errors,
        },
        "encoder": client.encoder_options,
        "bytes_up": dict(stats.bytes_up_by_kind),
        "upstream_mbps": stats.bytes_up_by_kind.get("total", 0) * 8 / duration_s / 1e6,
        "bytes_down": stats.bytes_down,
        "rtt_ms": _finite_or_none(stats.rtt_ms_smoothed),
        "reconnects": stats.reconnects,
        "resyncs": stats.resyncs,
        "last_error": stats.last_error,
        "local_map": {
            "objects": len(local),
            "memory_bytes": local.memory_bytes(),
            "seq": local.seq,
            "server_seq": stats.server_seq,
            "evicted": local.evicted,
        },
        "queries": [
            dict(dataclasses.asdict(answer), rtt_ms=_finite_or_none(answer.rtt_ms))
            for answer in answers
        ],
    }


def _finite_or_none(value: float | None) -> float | None:
    """JSON has no infinity: an unknown or down-link RTT is null."""
    return value if value is not None and math.isfinite(value) else None
