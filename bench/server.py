"""Server benchmarks through the real stack (a `semanticxr serve` process on loopback).

    python -m bench.server [--frames 150] [--seconds 20] [--out out/]
    python -m bench.server --stored-sessions 10,100,1000     # that section alone
    python -m bench.server --paced-only [--devices 8,16,32] [--paced-seconds 20]

The server runs as `app.server.runner.ServerProcess` (`python -m app.cli serve`); every call
goes through the API client (app.client). Measures: ingest-to-ack latency per keyframe and per plain frame; frames per
second sustained by 1 and 4 concurrent device streams (640x480, depth ÷5); bytes per
downstream update in `semanticxr` vs `baseline` mode on the standard synthetic scene.

Stored sessions: a store holding N sessions of a few objects each (written
through the store directly, as a server would have committed them: creating 1,000 maps
through the API would mean streaming 1,000 walks), then the server's start-up time (process
start to /healthz 200, polled every 0.1 s), its resident memory after start, and the first
use of one session (its map loaded from the store). Start-up must not grow with N.

Paced devices: N emulated devices, each in its own session on its own socket,
each sending the walk at 5 fps on a fixed clock (frame k at its start + k × 200 ms, starts
offset at random within the first 200 ms), never waiting for acks but with at most 8 frames
in flight (a frame due beyond that is skipped and counted as a stall). Reports ingest-to-ack
p50/p95 of keyframes and of plain frames over all devices, keyframes acknowledged as
dropped, errors, stalls and frames left unanswered, for each N; per device too in the JSON.
The emulated devices run in this process, on the same cores as the server.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import sys
import tempfile
import time
import uuid
from collections import Counter
from pathlib import Path

import httpx
import msgpack
import numpy as np

from app.client import CONNECTION_ERRORS, ApiError, create_session, open_websocket
from app.client.rest import delete_session
from app.protocol import SessionSummary
from app.server.runner import ServerProcess
from bench.common import bench_parser, check, machine, save_plot, write_outputs


async def new_session(server: ServerProcess, mode: str = "semanticxr", **knobs) -> str:
    """A session on the (open) bench server with these knobs; its id."""
    sid, _token, _answer = await create_session(server.url, mode=mode, knobs=knobs)
    return sid


def encode_frames(n_frames: int, scene: str) -> tuple[list[bytes], list[bytes]]:
    """Pre-encoded device frames (all frames of the walk, and its keyframes only)."""
    from client_sim.encoder import FrameEncoder
    from client_sim.sources.synthetic import SyntheticSource

    source = SyntheticSource(scene, n_frames=n_frames, noise="standard")
    encoder = FrameEncoder(5)
    out = []
    for frame in source.frames():
        msg = encoder.encode_source_frame(frame).message
        out.append(msgpack.packb(msg))
        if (frame.index + 1) % 50 == 0:
            print(f"  encoded {frame.index + 1}/{n_frames} frames", file=sys.stderr)
    return out, out[::5]


async def ack_latency(url: str, frames: list[bytes]) -> dict:
    """One frame in flight at a time: ingest-to-ack latency, keyframes and plain frames apart."""
    key, plain = [], []
    async with await open_websocket(url, None) as ws:
        for data in frames:
            t0 = time.perf_counter()
            await ws.send(data)
            reply = msgpack.unpackb(await asyncio.wait_for(ws.recv(), 60))
            (key if reply.get("keyframe") else plain).append((time.perf_counter() - t0) * 1e3)
    pct = lambda v, q: float(np.percentile(v, q)) if v else None  # noqa: E731
    return {
        "keyframe_p50_ms": pct(key, 50),
        "keyframe_p95_ms": pct(key, 95),
        "frame_p50_ms": pct(plain, 50),
        "frame_p95_ms": pct(plain, 95),
        "keyframes": len(key),
    }


async def sustained(
    server: ServerProcess, frames: list[bytes], streams: int, seconds: float
) -> dict:
    """`streams` devices, each with up to 4 frames in flight, for `seconds`; acked fps."""
    sids = [await new_session(server, keyframe_interval=5) for _ in range(streams)]

    async def device(sid: str) -> tuple[int, int, int]:
        acked = mapped = dropped = 0
        async with await open_websocket(f"{server.ws_url}/v1/sessions/{sid}/stream", None) as ws:
            end, i, in_flight = time.perf_counter() + seconds, 0, 0
            while time.perf_counter() < end or in_flight:
                while in_flight < 4 and time.perf_counter() < end:
                    await ws.send(frames[i % len(frames)])
                    i, in_flight = i + 1, in_flight + 1
                reply = msgpack.unpackb(await asyncio.wait_for(ws.recv(), 60))
                in_flight -= 1
                acked += reply["type"] == "ack"
                mapped += bool(reply.get("keyframe"))
                dropped += bool(reply.get("dropped"))
        return acked, mapped, dropped

    t0 = time.perf_counter()
    results = await asyncio.gather(*(device(s) for s in sids))
    elapsed = time.perf_counter() - t0
    return {
        "streams": streams,
        "fps_per_stream": [r[0] / elapsed for r in results],
        "fps_total": sum(r[0] for r in results) / elapsed,
        "keyframes_mapped_per_s": sum(r[1] for r in results) / elapsed,
        "dropped_keyframes": sum(r[2] for r in results),
    }


async def update_bytes(server: ServerProcess, keyframes: list[bytes], mode: str) -> list[int]:
    """Bytes of each downstream update while the keyframes stream in."""
    sid = await new_session(server, mode, keyframe_interval=1, local_map_update_frequency=2)
    sizes: list[int] = []
    async with await open_websocket(
        f"{server.ws_url}/v1/sessions/{sid}/updates?since=0", None
    ) as sub:
        await asyncio.wait_for(sub.recv(), 30)  # the initial (empty) sync

        async def listen():
            while True:
                sizes.append(len(await sub.recv()))

        listener = asyncio.create_task(listen())
        async with await open_websocket(f"{server.ws_url}/v1/sessions/{sid}/stream", None) as ws:
            for data in keyframes:
                await ws.send(data)
                await asyncio.wait_for(ws.recv(), 60)
        await asyncio.sleep(1.0)  # let the last update arrive
        listener.cancel()
    return sizes


PACED_FPS = 5.0
"""Frames per second each paced device sends, on its own fixed clock."""
PACED_MAX_IN_FLIGHT = 8
"""Frames a paced device may have sent and not yet seen answered; a frame due while this many
are in flight is not sent (a stall) and the device's clock keeps going."""
MAX_PACED_DEVICES = 64
"""Most devices a paced run may start (--devices)."""
MAX_PACED_SECONDS = 120.0
"""Longest a paced run may last (--paced-seconds)."""
PACED_DRAIN_S = 60.0
"""Longest a paced device waits for its last answers after its last frame is due."""


def paced_frame_count(seconds: float) -> int:
    """Frames one paced device sends in `seconds` (each once: no part of the walk is replayed,
    so seqs only grow)."""
    return math.ceil(seconds * PACED_FPS)


def _percentiles_ms(values: list[float]) -> dict:
    if not values:
        return {"p50": None, "p95": None, "mean": None, "max": None, "count": 0}
    return {
        "p50": float(np.percentile(values, 50)),
        "p95": float(np.percentile(values, 95)),
        "mean": float(np.mean(values)),
        "max": float(np.max(values)),
        "count": len(values),
    }


async def paced_device(ws, frames: list[bytes], seqs: list[int], start_t: float) -> dict:
    """One device on an open stream socket: frame k is due at `start_t` + k / PACED_FPS
    (perf_counter clock) and sent then, whatever is still unanswered, unless
    PACED_MAX_IN_FLIGHT are in flight (a stall: that frame is skipped). Replies are matched
    to frames by seq. Ingest-to-ack latency runs from just before the send to the reply's
    arrival, keyframes (ack `keyframe` true) and plain frames apart; a keyframe acknowledged
    `dropped` (superseded by a newer one before mapping) is counted, not timed."""
    sent_at: dict[int, float] = {}
    result: dict = {
        "frames_sent": 0,
        "stalls": 0,
        "keyframe_ms": [],
        "frame_ms": [],
        "dropped_keyframes": 0,
        "errors": Counter(),
        "send_lag_max_ms": 0.0,
    }
    sending_done, all_answered = asyncio.Event(), asyncio.Event()

    async def send_on_clock() -> None:
        try:
            for k, data in enumerate(frames):
                due = start_t + k / PACED_FPS
                await asyncio.sleep(max(0.0, due - time.perf_counter()))  # the device's clock
                if len(sent_at) >= PACED_MAX_IN_FLIGHT:
                    result["stalls"] += 1
                    continue
                t0 = time.perf_counter()
                result["send_lag_max_ms"] = max(result["send_lag_max_ms"], (t0 - due) * 1e3)
                sent_at[seqs[k]] = t0
                await ws.send(data)
                result["frames_sent"] += 1
        except CONNECTION_ERRORS as exc:
            result["errors"][f"send: {type(exc).__name__}"] += 1
            all_answered.set()
        sending_done.set()
        if not sent_at:
            all_answered.set()

    async def receive_answers() -> None:
        try:
            while True:
                reply = msgpack.unpackb(await ws.recv())
                latency_ms = (time.perf_counter() - sent_at.pop(reply.get("seq"), math.nan)) * 1e3
                if reply.get("type") == "error":
                    result["errors"][str(reply.get("code"))] += 1
                elif math.isnan(latency_ms):
                    result["errors"]["ack for no frame in flight"] += 1
                elif reply.get("dropped"):
                    result["dropped_keyframes"] += 1
                else:
                    result["keyframe_ms" if reply.get("keyframe") else "frame_ms"].append(
                        latency_ms
                    )
                if sending_done.is_set() and not sent_at:
                    all_answered.set()
        except CONNECTION_ERRORS as exc:
            result["errors"][f"receive: {type(exc).__name__}"] += 1
            all_answered.set()

    receiver = asyncio.create_task(receive_answers())
    try:
        await send_on_clock()
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(all_answered.wait(), PACED_DRAIN_S)
    finally:
        receiver.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await receiver
    result["unanswered"] = len(sent_at)
    return result


async def paced_run(server: ServerProcess, frames: list[bytes], devices: int, seed: int) -> dict:
    """`devices` paced devices, each in its own session on its own socket, each sending all of
    `frames` at PACED_FPS from its own start (offset at random within the first frame period,
    so they do not all send at once); their sessions are deleted afterwards."""
    seqs = [msgpack.unpackb(data)["seq"] for data in frames]
    sids = [await new_session(server, keyframe_interval=5) for _ in range(devices)]
    offsets_s = np.random.default_rng(seed).uniform(0.0, 1.0 / PACED_FPS, devices)
    load_before = os.getloadavg()[0]
    try:
        async with contextlib.AsyncExitStack() as sockets:
            streams = [
                await sockets.enter_async_context(
                    await open_websocket(f"{server.ws_url}/v1/sessions/{sid}/stream", None)
                )
                for sid in sids
            ]
            t0 = time.perf_counter() + 0.2  # every socket is open before any clock starts
            results = await asyncio.gather(
                *(
                    paced_device(ws, frames, seqs, t0 + offset)
                    for ws, offset in zip(streams, offsets_s, strict=True)
                )
            )
            elapsed_s = time.perf_counter() - t0
    finally:
        for sid in sids:
            with contextlib.suppress(ApiError):
                await delete_session(server.url, sid)
    errors = sum((r["errors"] for r in results), Counter())
    per_device = [
        {
            "frames_sent": r["frames_sent"],
            "keyframe_ack_ms": _percentiles_ms(r["keyframe_ms"]),
            "frame_ack_ms": _percentiles_ms(r["frame_ms"]),
            "dropped_keyframes": r["dropped_keyframes"],
            "errors": sum(r["errors"].values()),
            "stalls": r["stalls"],
            "unanswered": r["unanswered"],
            "send_lag_max_ms": r["send_lag_max_ms"],
        }
        for r in results
    ]
    return {
        "devices": devices,
        "frames_due_per_device": len(frames),
        "frames_sent": sum(r["frames_sent"] for r in results),
        "keyframe_ack_ms": _percentiles_ms([ms for r in results for ms in r["keyframe_ms"]]),
        "frame_ack_ms": _percentiles_ms([ms for r in results for ms in r["frame_ms"]]),
        "dropped_keyframes": sum(r["dropped_keyframes"] for r in results),
        "errors": sum(errors.values()),
        "error_kinds": dict(errors),
        "stalls": sum(r["stalls"] for r in results),
        "unanswered": sum(r["unanswered"] for r in results),
        "client_send_lag_max_ms": max(r["send_lag_max_ms"] for r in results),
        "elapsed_s": elapsed_s,
        "load_avg_1m_before": load_before,
        "load_avg_1m_after": os.getloadavg()[0],
        "per_device": per_device,
    }


async def warm_up(server: ServerProcess, frames: list[bytes]) -> float:
    """Stream `frames` one at a time through a session that is then deleted, so that what a
    server does once (e.g. the first keyframe's model warm-up) is not in a paced run; seconds."""
    sid = await new_session(server, keyframe_interval=5)
    t0 = time.perf_counter()
    await ack_latency(f"{server.ws_url}/v1/sessions/{sid}/stream", frames)
    elapsed_s = time.perf_counter() - t0
    await delete_session(server.url, sid)
    return elapsed_s


def paced_devices(
    server: ServerProcess, frames: list[bytes], device_counts: list[int], seconds: float
) -> dict:
    """One paced run per count in `device_counts`, on `server`, for `seconds` each; prints a
    table and returns the section of the JSON document."""
    frames = frames[: paced_frame_count(seconds)]
    warm_up_s = asyncio.run(warm_up(server, frames[:10]))
    print(f"  warm-up: 10 frames, 2 keyframes, one at a time in {warm_up_s:.1f} s", file=sys.stderr)
    runs = []
    for devices in device_counts:
        runs.append(asyncio.run(paced_run(server, frames, devices, seed=devices)))
        print(f"  {devices} paced devices done", file=sys.stderr)
    ms = lambda v: "-" if v is None else f"{v:.1f}"  # noqa: E731
    print(
        f"paced devices: {PACED_FPS:g} fps each for {len(frames) / PACED_FPS:g} s, at most "
        f"{PACED_MAX_IN_FLIGHT} frames in flight per device; ingest-to-ack ms over all devices"
    )
    print(
        f"{'devices':>7} {'sent':>6} {'keyframes':>9} {'kf p50':>7} {'kf p95':>7} "
        f"{'fr p50':>7} {'fr p95':>7} {'dropped':>7} {'stalls':>6} {'errors':>6} {'unans.':>6}"
    )
    for run in runs:
        key, plain = run["keyframe_ack_ms"], run["frame_ack_ms"]
        print(
            f"{run['devices']:>7} {run['frames_sent']:>6} {key['count']:>9} "
            f"{ms(key['p50']):>7} {ms(key['p95']):>7} {ms(plain['p50']):>7} {ms(plain['p95']):>7} "
            f"{run['dropped_keyframes']:>7} {run['stalls']:>6} {run['errors']:>6} "
            f"{run['unanswered']:>6}"
        )
    return {
        "fps_per_device": PACED_FPS,
        "seconds": len(frames) / PACED_FPS,
        "max_in_flight_per_device": PACED_MAX_IN_FLIGHT,
        "keyframe_interval": 5,
        "warm_up_s": warm_up_s,
        "runs": runs,
    }


STORED_OBJECTS = 8
"""Objects per stored session."""
STORED_POINTS = 500
"""Points per stored object."""
EMBEDDING_DIM = 384
"""The default text encoder's (all-MiniLM-L6-v2)."""


def add_stored_sessions(data_dir: str, count: int, seed: int = 0) -> None:
    """Add `count` sessions of STORED_OBJECTS confirmed objects each to the store of a
    server whose data dir is `data_dir`, committed as the server commits a keyframe."""
    from app.config import Knobs, knobs_to_dict
    from app.mapping.object import MapObject
    from app.server.sessions import hash_token
    from app.server.settings import STORE_FILE
    from app.store import KeyframeCommit, SessionRecord
    from app.store.sqlite import SqliteStore

    rng = np.random.default_rng(seed)
    knobs = knobs_to_dict(Knobs())
    with SqliteStore(Path(data_dir) / STORE_FILE) as store:
        for _ in range(count):
            sid = uuid.uuid4().hex[:16]
            store.create_session(
                SessionRecord(
                    sid, f"stored-{sid[:6]}", "semanticxr", knobs, hash_token(sid), time.time()
                )
            )
            objects = []
            for oid in range(1, STORED_OBJECTS + 1):
                embedding = rng.standard_normal(EMBEDDING_DIM).astype(np.float32)
                obj = MapObject(
                    id=oid,
                    embedding_sum=embedding / np.linalg.norm(embedding),
                    label_counts=Counter({f"thing-{oid}": 3}),
                    n_obs=3,
                    frames_seen=3,
                    first_seen=0,
                    last_seen=2,
                    version=3,
                    confirmed=True,
                )
                centre = rng.uniform(-5, 5, 3)
                points = centre + rng.uniform(-0.4, 0.4, (STORED_POINTS, 3))
                obj.set_points(points.astype(np.float32), 0.025)
                objects.append(obj)
            store.commit_keyframe(
                KeyframeCommit(
                    sid, 1, objects, [], {"frames": 15, "keyframes": 3}, STORED_OBJECTS + 1
                )
            )


def rss_mb(pid: int) -> float:
    """Resident memory of process `pid` (VmRSS), MB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError(f"no VmRSS for process {pid}")


def stored_sessions(sizes: list[int]) -> list[dict]:
    """Start-up time, RSS after start and one session's first use, with `sizes` sessions
    stored (one store grown from size to size)."""
    runs = []
    with tempfile.TemporaryDirectory() as data_dir:
        stored = 0
        for size in sorted(sizes):
            t0 = time.perf_counter()
            add_stored_sessions(data_dir, size - stored, seed=size)
            fill_s = time.perf_counter() - t0
            stored = size
            t0 = time.perf_counter()
            server = ServerProcess(data_dir).start()
            try:
                startup_s = time.perf_counter() - t0
                rss_after_start = rss_mb(server.pid)
                t0 = time.perf_counter()
                answer = httpx.get(f"{server.url}/v1/sessions", timeout=60).json()
                list_ms = (time.perf_counter() - t0) * 1e3
                listed = [SessionSummary.model_validate(entry) for entry in answer]
                use_ms, load_s = [], []
                for entry in listed[:6]:  # the first use of each: its map loads from the store
                    t0 = time.perf_counter()
                    url = f"{server.url}/v1/sessions/{entry.session_id}/objects"
                    objects = httpx.get(url, timeout=60).json()
                    use_ms.append((time.perf_counter() - t0) * 1e3)
                    assert len(objects) == STORED_OBJECTS
                    load_s.append(_metric(server.url, "semanticxr_session_load_seconds_sum"))
                assert len(listed) == size
            finally:
                server.stop()
            run = {
                "stored_sessions": size,
                "startup_s": startup_s,
                "rss_after_start_mb": rss_after_start,
                "list_ms": list_ms,
                "first_use_ms": use_ms[0],
                "next_first_uses_ms": float(np.median(use_ms[1:])),
                "first_load_ms": load_s[0] * 1e3,
                "next_loads_ms": float(np.median(np.diff(load_s))) * 1e3,
                "store_fill_s": fill_s,
            }
            runs.append(run)
            print(
                f"{size} stored sessions: start-up {startup_s:.2f} s, RSS {rss_after_start:.0f} MB, "
                f"GET /v1/sessions {list_ms:.0f} ms; first use of a session {use_ms[0]:.0f} ms "
                f"(the very first, loading {run['first_load_ms']:.0f} ms), then "
                f"{run['next_first_uses_ms']:.0f} ms (median, loading "
                f"{run['next_loads_ms']:.1f} ms); store filled in {fill_s:.1f} s"
            )
    return runs


def _metric(url: str, name: str) -> float:
    from prometheus_client.parser import text_string_to_metric_families

    for family in text_string_to_metric_families(httpx.get(f"{url}/metrics").text):
        for sample in family.samples:
            if sample.name == name:
                return sample.value
    raise RuntimeError(f"no {name} in /metrics")


def stored_sessions_targets(runs: list[dict]) -> list[dict]:
    smallest, largest = runs[0], runs[-1]
    name = f"{largest['stored_sessions']} vs {smallest['stored_sessions']} stored sessions"
    return [
        check(f"start-up, {name}", largest["startup_s"] / smallest["startup_s"], "<=", 1.25, "x"),
        check(
            f"RSS after start, {name}",
            largest["rss_after_start_mb"] - smallest["rss_after_start_mb"],
            "<=",
            20.0,
            " MB",
        ),
    ]


def main(argv: list[str] | None = None) -> int:
    parser = bench_parser(__doc__)
    parser.add_argument("--scene", default="apartment", help="synthetic scene of the streamed walk")
    parser.add_argument("--frames", type=int, default=300, help="frames of the walk to pre-encode")
    parser.add_argument(
        "--seconds", type=float, default=15.0, help="duration of each sustained run"
    )
    parser.add_argument("--out", default="out", help="folder for server.json and the plot")
    parser.add_argument(
        "--stored-sessions",
        default=None,
        metavar="N,N,...",
        help="run only the stored-sessions section with these store sizes (server_stored.json); "
        "the full run includes it with 10,100,1000",
    )
    parser.add_argument(
        "--devices",
        default="8,16,32",
        metavar="N,N,...",
        help="device counts of the paced-devices section (each device 5 fps, its own session)",
    )
    parser.add_argument(
        "--paced-seconds", type=float, default=20.0, help="duration of each paced-devices run"
    )
    parser.add_argument(
        "--paced-only",
        action="store_true",
        help="run only the paced-devices section (server_paced.json); the full run includes it",
    )
    args = parser.parse_args(argv)
    device_counts = [int(n) for n in args.devices.split(",") if n.strip()]
    if not device_counts or min(device_counts) < 1 or max(device_counts) > MAX_PACED_DEVICES:
        parser.error(
            f"--devices must list counts from 1 to {MAX_PACED_DEVICES}, got {args.devices!r}"
        )
    if not 0 < args.paced_seconds <= MAX_PACED_SECONDS:
        parser.error(
            f"--paced-seconds must be in (0, {MAX_PACED_SECONDS:g}], got {args.paced_seconds:g}"
        )
    paced_frames = paced_frame_count(args.paced_seconds)
    if args.paced_only:
        print("encoding frames...", file=sys.stderr)
        frames, _ = encode_frames(paced_frames, args.scene)
        with tempfile.TemporaryDirectory() as data_dir:
            server = ServerProcess(data_dir, quiet=False).start()
            try:
                paced = paced_devices(server, frames, device_counts, args.paced_seconds)
            finally:
                server.stop()
        document = {
            "bench": "server_paced",
            "machine": machine(),
            "scene": args.scene,
            "upstream_bytes_per_frame": float(np.mean([len(f) for f in frames])),
            "paced_devices": paced,
        }
        write_outputs(args.out, "server_paced", document)
        return 0
    if args.stored_sessions is not None:
        sizes = [int(n) for n in args.stored_sessions.split(",") if n.strip()]
        runs = stored_sessions(sizes)
        document = {
            "bench": "server_stored",
            "machine": machine(),
            "objects_per_session": STORED_OBJECTS,
            "points_per_object": STORED_POINTS,
            "stored_sessions": runs,
            "targets": stored_sessions_targets(runs) if len(runs) > 1 else [],
        }
        write_outputs(args.out, "server_stored", document)
        return 0

    print("encoding frames...", file=sys.stderr)
    frames, keyframes = encode_frames(max(args.frames, paced_frames), args.scene)
    upstream_bytes = float(np.mean([len(f) for f in frames]))
    with tempfile.TemporaryDirectory() as data_dir:
        server = ServerProcess(data_dir, quiet=False).start()
        try:
            sid = asyncio.run(new_session(server, keyframe_interval=5))
            latency = asyncio.run(
                ack_latency(f"{server.ws_url}/v1/sessions/{sid}/stream", frames[:150])
            )
            print(
                f"ingest-to-ack: keyframe p50 {latency['keyframe_p50_ms']:.1f} ms, "
                f"frame p50 {latency['frame_p50_ms']:.1f} ms"
            )
            runs = []
            for streams in (1, 4):
                run = asyncio.run(sustained(server, frames, streams, args.seconds))
                runs.append(run)
                print(
                    f"{streams} stream(s): {run['fps_total']:.1f} frames/s total, "
                    f"{run['keyframes_mapped_per_s']:.1f} keyframes mapped/s, {run['dropped_keyframes']} dropped"
                )
            updates = {
                mode: asyncio.run(update_bytes(server, keyframes, mode))
                for mode in ("semanticxr", "baseline")
            }
            paced = paced_devices(server, frames, device_counts, args.paced_seconds)
        finally:
            server.stop()

    plateau = {m: float(np.mean(s[len(s) // 2 :])) if s else 0.0 for m, s in updates.items()}
    ratio = 100.0 * plateau["semanticxr"] / max(plateau["baseline"], 1.0)
    print(
        f"bytes/update at plateau: semanticxr {plateau['semanticxr']:.0f}, baseline {plateau['baseline']:.0f} "
        f"({ratio:.1f}%)"
    )
    stored = stored_sessions([10, 100, 1000])
    targets = [
        check("1 stream sustains 30 fps input", runs[0]["fps_total"], ">=", 30.0, " fps"),
        check("downstream bytes/update vs baseline at plateau", ratio, "<=", 10.0, "%"),
        *stored_sessions_targets(stored),
    ]
    document = {
        "bench": "server",
        "machine": machine(),
        "scene": args.scene,
        "upstream_bytes_per_frame": upstream_bytes,
        "ack_latency": latency,
        "sustained": runs,
        "update_bytes": updates,
        "update_bytes_plateau": plateau,
        "update_ratio_percent": ratio,
        "stored_sessions": stored,
        "paced_devices": paced,
        "targets": targets,
    }
    write_outputs(args.out, "server", document)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.5))
    for mode, color in (("baseline", "tab:red"), ("semanticxr", "tab:blue")):
        ax.plot(np.asarray(updates[mode]) / 1024, color=color, label=mode)
    ax.set_xlabel("update index")
    ax.set_ylabel("KiB per update")
    ax.set_yscale("log")
    ax.legend()
    ax.set_title("downstream bytes per update")
    save_plot(fig, args.out, "server_updates")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
