"""Load bench: many devices, each its own session, against one server process; or
the servers of two checkouts side by side.

    python -m bench.load [--devices 8,32] [--seconds 30] [--fps 5] [--out out/]
    python -m bench.load --saturate                      # closed loop: max frames/s
    python -m bench.load --sightings                     # keyframes whole, sightings between
    python -m bench.load --semanticxr PATH               # the server of another checkout
    python -m bench.load --compare PATH_A PATH_B         # both, alternating, side by side

Each run starts a fresh server (`python -m app.cli serve` with an API key, in a child process,
on loopback, a new data dir), streams 10 frames through a warm-up session one at a time (what
a server does once is not measured), then creates one session per device with
POST /v1/sessions (the API key) and opens its stream socket with the session's token, as
the protocol says. The devices send the same pre-encoded walk of the synthetic apartment
(640x480 RGB, depth ÷5, the device's noisy detections; encoded once, before any timing),
each in its own session:

- paced (default): device k sends frame i at its start + i / fps (starts offset at random
  within the first frame period), never waiting for acks, with at most 8 frames in flight
  (a frame due beyond that is skipped, counted as `skipped`);
- saturated (`--saturate`): closed loop, each device sends its next frame when the previous
  one is answered, for `--seconds` (the walk replays with growing seq and t if it runs out).

Whole frames by default (the server picks 1 keyframe in `keyframe_interval`); with
`--sightings` each device offers the sightings extension and, where the server selects it,
sends keyframes whole and a sighting of each frame between them (docs/protocol.md); on a
server that does not know it, whole frames (the JSON says how many sockets negotiated it).

Measured over the window [start, start + seconds] (the warm-up and session set-up excluded):
frames acked per second (acks that arrived in the window), the server's CPU
(/proc/<pid>/stat utime + stime) per frame acked in it, and this process's CPU. Over the
whole run (the drain after the window included): ingest-to-ack latency of keyframes
(p50/p95/p99) and of plain frames (p50/p95), keyframes acknowledged as superseded
(`dropped`), error replies, frames never answered, sockets that waited > 1 s for any reply
with frames in flight (stalled), and frames acked as a share of frames due (a superseded
keyframe is acked, so the share is also given without them: the ≥ 99 % target counts only
frames the server kept). The server's RSS (VmRSS) and peak (VmHWM) at the end. Writes OUT/load.json and OUT/load.png (latency and CPU per frame vs devices, a line
per server), a table on stdout, progress on stderr.

`--semanticxr PATH` runs `PATH/.venv/bin/python -m app.cli serve` if that venv exists, else
this venv's python with cwd PATH and PYTHONPATH=PATH, with the flags every `serve` since
d801b31 accepts (--host, --port, --data-dir, --api-key, --log-level). The devices (frames,
protocol v1, sessions) always come from this checkout.

The emulated devices run in this process, in one asyncio loop, on the same two cores as the
server: at 32 devices they take a share of the machine the server does not get (the JSON
reports this process's CPU beside the server's).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import secrets
import subprocess
import sys
import tempfile
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import msgpack
import numpy as np

from app.client import CONNECTION_ERRORS, ApiError, create_session, open_websocket
from app.client.rest import delete_session
from app.keyframes import is_keyframe
from app.protocol import SIGHTINGS_SUBPROTOCOL, ErrorReply, InputError, unpack_reply
from app.server.runner import ServerProcess
from bench.common import bench_parser, check, machine, save_plot, write_outputs
from bench.server import MAX_PACED_DEVICES, PACED_DRAIN_S, PACED_MAX_IN_FLIGHT, rss_mb

REPO_ROOT = Path(__file__).resolve().parents[1]
"""This checkout: the devices' code, and the server's unless --semanticxr names another."""
MAX_SECONDS = 600.0
"""Longest window a run may last (--seconds)."""
STALL_S = 1.0
"""A socket with frames in flight and no reply for longer than this has stalled."""
WARM_UP_FRAMES = 10
"""Frames (2 keyframes) streamed one at a time through a session before each run."""


# --- the walk ---------------------------------------------------------------------------


@dataclass
class Walk:
    """The pre-encoded frames every device sends (packed msgpack messages)."""

    whole: list[bytes]
    """Frame i as a v1 `frame` (seq i, t = i / fps)."""
    sightings: list[bytes | None]
    """Frame i as a `sighting` (None without detections; empty without --sightings)."""
    frame_period_s: float
    """Device time between two frames of the walk (1 / fps)."""
    size_px: tuple[int, int]
    """RGB width and height."""

    def message(self, index: int, as_sighting: bool) -> bytes | None:
        """Frame `index` of an endless walk: the walk replayed with seq = index and t moved on
        by whole walks (re-packed) once it runs out; None for a sighting without detections."""
        n = len(self.whole)
        loop, i = divmod(index, n)
        data = self.sightings[i] if as_sighting else self.whole[i]
        if data is None or loop == 0:
            return data
        message = msgpack.unpackb(data)
        message["seq"] = index
        message["t"] = float(message["t"]) + loop * n * self.frame_period_s
        return msgpack.packb(message)


def encode_walk(
    n_frames: int, fps: float, *, sightings: bool, scene: str = "apartment", size_px=(640, 480)
) -> Walk:
    """The synthetic walk rendered and encoded as our device encodes it (depth ÷5, the
    standard detection noise), whole and, with `sightings`, as sightings too."""
    from client_sim.encoder import FrameEncoder
    from client_sim.sources.synthetic import SyntheticSource
    from world.render import default_camera

    source = SyntheticSource(
        scene, n_frames=n_frames, camera=default_camera(*size_px), noise="standard", fps=fps
    )
    encoder = FrameEncoder(5)
    whole: list[bytes] = []
    as_sightings: list[bytes | None] = []
    for frame in source.frames():
        whole.append(msgpack.packb(encoder.encode_source_frame(frame).message))
        if sightings:
            sighting = (
                None
                if frame.instance_ids is None
                else encoder.encode_source_frame_as_sighting(frame).message
            )
            as_sightings.append(None if sighting is None else msgpack.packb(sighting))
        if (frame.index + 1) % 50 == 0:
            print(f"  encoded {frame.index + 1}/{n_frames} frames", file=sys.stderr)
    return Walk(whole, as_sightings, 1.0 / fps, tuple(size_px))


# --- the servers ------------------------------------------------------------------------


@dataclass
class ServerSpec:
    """Which checkout's server a run starts."""

    label: str
    """Its name in the table, the JSON and the plot (commit, "+" if it has local changes)."""
    checkout: Path
    """The checkout's root."""
    python: str
    """The interpreter that runs it."""
    commit: str | None
    """`git rev-parse HEAD` there (None if it is no git checkout)."""
    local_changes: bool
    """Tracked files differ from that commit."""


def _git(checkout: Path, *args: str) -> str | None:
    try:
        done = subprocess.run(
            ["git", "-C", str(checkout), *args], capture_output=True, text=True, timeout=30
        )
    except (OSError, subprocess.TimeoutExpired):
        return None
    return done.stdout.strip() if done.returncode == 0 else None


def server_spec(checkout: Path) -> ServerSpec:
    """The server of `checkout`, with its own venv's python if it has one (else ours)."""
    checkout = checkout.resolve()
    venv_python = checkout / ".venv" / "bin" / "python"
    commit = _git(checkout, "rev-parse", "HEAD")
    changes = bool(_git(checkout, "status", "--porcelain", "--untracked-files=no"))
    label = (commit[:7] if commit else checkout.name) + ("+" if changes else "")
    return ServerSpec(
        label,
        checkout,
        str(venv_python) if venv_python.exists() else sys.executable,
        commit,
        changes,
    )


def is_checkout(path: Path) -> bool:
    """Whether `path` holds a SemanticXR server (app/cli as a package or, before the CLI was
    split, as app/cli.py)."""
    return (path / "app" / "cli" / "__init__.py").exists() or (path / "app" / "cli.py").exists()


def start_server(spec: ServerSpec, data_dir: str, api_key: str) -> ServerProcess:
    """`serve` of `spec`'s checkout in a child process, on a free loopback port, with only the
    flags every version accepts; started (its /healthz answered)."""
    server = ServerProcess(data_dir, extra_args=["--api-key", api_key])
    assert server.argv[0] == sys.executable, server.argv
    # The checkout is the cwd (first on sys.path for `python -m`) and on PYTHONPATH (before
    # the editable install of this checkout in our venv); `env` execs, so the pid stays the
    # server's. This checkout's server runs the same way.
    server.argv = [
        "env",
        "-C",
        str(spec.checkout),
        f"PYTHONPATH={spec.checkout}",
        spec.python,
        *server.argv[1:],
    ]
    return server.start()


def cpu_s(pid: int) -> float:
    """CPU time process `pid` has used so far (all its threads, user + system), seconds."""
    # Fields after the command name (which may hold spaces) in /proc/<pid>/stat: state is
    # field 3, utime 14, stime 15.
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def peak_rss_mb(pid: int) -> float:
    """Peak resident memory of process `pid` (VmHWM), MB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError(f"no VmHWM for process {pid}")


# --- one device -------------------------------------------------------------------------


@dataclass
class DeviceRun:
    """What one device sent and heard."""

    sightings: bool = False
    """The server selected the sightings extension on this device's socket."""
    frames_due: int = 0
    """Frames the device had to send (a sighting without detections is not due)."""
    frames_sent: int = 0
    sightings_sent: int = 0
    skipped: int = 0
    """Paced: frames due while PACED_MAX_IN_FLIGHT were in flight, not sent."""
    keyframe_ms: list[float] = field(default_factory=list)
    frame_ms: list[float] = field(default_factory=list)
    superseded: int = 0
    """Keyframes acknowledged `dropped` (superseded by a newer one before mapping)."""
    ack_times: list[float] = field(default_factory=list)
    """perf_counter() at each ack's arrival (superseded keyframes too)."""
    errors: Counter = field(default_factory=Counter)
    unanswered: int = 0
    longest_wait_ms: float = 0.0
    """Longest time with frames in flight and no reply at all."""
    send_lag_max_ms: float = 0.0
    """Paced: most a send was late on the device's clock (the emulation's own lag)."""


async def run_device(
    ws, walk: Walk, start_t: float, end_t: float, *, fps: float, saturate: bool, interval: int
) -> DeviceRun:
    """One device on an open stream socket between `start_t` and `end_t` (perf_counter
    clock), then up to PACED_DRAIN_S for its last replies. Paced: frame i is due at
    start_t + i / fps, for every i / fps before end_t - start_t. Saturated: each frame is sent
    once the previous one is answered, until `end_t`. With the sightings extension on the
    socket, frames that are no keyframe (`interval`, the server's selector) go as sightings.
    Replies are matched to frames by seq (an error without one answers the oldest frame in
    flight); ingest-to-ack runs from just before the send to the reply's arrival."""
    run = DeviceRun(sightings=ws.subprotocol == SIGHTINGS_SUBPROTOCOL)
    sent_at: dict[int, float] = {}
    waiting_since: float | None = None  # frames in flight and no reply since
    idle, sending_done, all_answered = asyncio.Event(), asyncio.Event(), asyncio.Event()
    idle.set()

    def note_wait(now: float) -> None:
        if waiting_since is not None:
            run.longest_wait_ms = max(run.longest_wait_ms, (now - waiting_since) * 1e3)

    async def send(index: int, data: bytes, as_sighting: bool) -> None:
        nonlocal waiting_since
        now = time.perf_counter()
        if not sent_at:
            waiting_since = now
        sent_at[index] = now
        idle.clear()
        await ws.send(data)
        run.frames_sent += 1
        run.sightings_sent += as_sighting

    def next_frame(index: int) -> tuple[bytes | None, bool]:
        as_sighting = run.sightings and not is_keyframe(index, interval)
        return walk.message(index, as_sighting), as_sighting

    async def send_frames() -> None:
        try:
            if saturate:
                index = 0
                while time.perf_counter() < end_t:
                    data, as_sighting = next_frame(index)
                    if data is not None:
                        run.frames_due += 1
                        await send(index, data, as_sighting)
                        await idle.wait()
                    index += 1
            else:
                for index in range(math.ceil((end_t - start_t) * fps - 1e-9)):
                    due = start_t + index / fps
                    await asyncio.sleep(max(0.0, due - time.perf_counter()))  # the device's clock
                    data, as_sighting = next_frame(index)
                    if data is None:
                        continue  # a sighting without detections: nothing to send
                    run.frames_due += 1
                    if len(sent_at) >= PACED_MAX_IN_FLIGHT:
                        run.skipped += 1
                        continue
                    run.send_lag_max_ms = max(
                        run.send_lag_max_ms, (time.perf_counter() - due) * 1e3
                    )
                    await send(index, data, as_sighting)
        except CONNECTION_ERRORS as exc:
            run.errors[f"send: {type(exc).__name__}"] += 1
            all_answered.set()
        sending_done.set()
        if not sent_at:
            all_answered.set()

    async def receive_replies() -> None:
        nonlocal waiting_since
        try:
            async for raw in ws:
                now = time.perf_counter()
                note_wait(now)
                try:
                    reply = unpack_reply(raw)
                except InputError:
                    run.errors["malformed reply"] += 1
                    continue
                seq = reply.seq
                if seq is None and sent_at:
                    seq = next(iter(sent_at))  # the oldest frame in flight
                sent = sent_at.pop(seq, None) if seq is not None else None
                waiting_since = now if sent_at else None
                if not sent_at:
                    idle.set()
                if isinstance(reply, ErrorReply):
                    run.errors[reply.code] += 1
                elif sent is None:
                    run.errors["ack for no frame in flight"] += 1
                else:
                    run.ack_times.append(now)
                    if reply.dropped:
                        run.superseded += 1
                    elif reply.keyframe:
                        run.keyframe_ms.append((now - sent) * 1e3)
                    else:
                        run.frame_ms.append((now - sent) * 1e3)
                if sending_done.is_set() and not sent_at:
                    all_answered.set()
        except CONNECTION_ERRORS as exc:
            run.errors[f"receive: {type(exc).__name__}"] += 1
        all_answered.set()
        idle.set()  # nothing more will come: a saturated sender must not wait for it

    receiver = asyncio.create_task(receive_replies())
    try:
        await asyncio.sleep(max(0.0, start_t - time.perf_counter()))
        await send_frames()
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(all_answered.wait(), PACED_DRAIN_S)
    finally:
        receiver.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await receiver
    note_wait(time.perf_counter())
    run.unanswered = len(sent_at)
    return run


# --- one run ----------------------------------------------------------------------------


def latency_summary(values_ms: list[float]) -> dict:
    """p50/p95/p99, mean, max and count of latencies (None where there are none), ms."""
    if not values_ms:
        return {"p50": None, "p95": None, "p99": None, "mean": None, "max": None, "count": 0}
    p50, p95, p99 = np.percentile(values_ms, [50, 95, 99])
    return {
        "p50": float(p50),
        "p95": float(p95),
        "p99": float(p99),
        "mean": float(np.mean(values_ms)),
        "max": float(np.max(values_ms)),
        "count": len(values_ms),
    }


async def measure_window(pids: list[int], start_t: float, end_t: float) -> dict:
    """CPU of the server's processes (summed) and of this process between `start_t` and
    `end_t` (perf_counter clock), sampled as close to them as the loop allows (the actual
    instants are returned)."""
    await asyncio.sleep(max(0.0, start_t - time.perf_counter()))
    t0, server0, client0 = time.perf_counter(), sum(map(cpu_s, pids)), time.process_time()
    await asyncio.sleep(max(0.0, end_t - time.perf_counter()))
    t1, server1, client1 = time.perf_counter(), sum(map(cpu_s, pids)), time.process_time()
    return {
        "t0": t0,
        "t1": t1,
        "server_cpu_s": server1 - server0,
        "client_cpu_s": client1 - client0,
    }


async def warm_up(server: ServerProcess, walk: Walk, api_key: str) -> float:
    """WARM_UP_FRAMES whole frames one at a time through a session that is then deleted;
    seconds."""
    sid, token, _ = await create_session(server.url, name="load-warm-up", api_key=api_key)
    t0 = time.perf_counter()
    async with await open_websocket(f"{server.ws_url}/v1/sessions/{sid}/stream", token) as ws:
        for data in walk.whole[:WARM_UP_FRAMES]:
            await ws.send(data)
            await asyncio.wait_for(ws.recv(), 120)
    elapsed_s = time.perf_counter() - t0
    await delete_session(server.url, sid, token=token)
    return elapsed_s


async def load_run(
    server: ServerProcess,
    walk: Walk,
    devices: int,
    *,
    api_key: str,
    seconds: float,
    fps: float,
    saturate: bool,
    sightings: bool,
    seed: int = 0,
) -> dict:
    """`devices` devices, each in its own session on its own socket, for `seconds`; their
    sessions are deleted afterwards. The run's section of the JSON (without `server`).
    A server with `pids` (a cluster: its gateway and shards) is measured over all of them."""
    pids = list(getattr(server, "pids", None) or [server.pid])
    sessions = [
        await create_session(server.url, name=f"load-{i}", api_key=api_key) for i in range(devices)
    ]
    interval = int(sessions[0][2]["knobs"]["keyframe_interval"])
    offsets_s = np.random.default_rng(seed).uniform(0.0, 1.0 / fps, devices)
    offer = {"subprotocols": [SIGHTINGS_SUBPROTOCOL]} if sightings else {}
    load_before = os.getloadavg()[0]
    try:
        async with contextlib.AsyncExitStack() as sockets:
            streams = [
                await sockets.enter_async_context(
                    await open_websocket(
                        f"{server.ws_url}/v1/sessions/{sid}/stream", token, **offer
                    )
                )
                for sid, token, _ in sessions
            ]
            t0 = time.perf_counter() + 0.3  # every socket is open before any clock starts
            meter = asyncio.create_task(measure_window(pids, t0, t0 + seconds))
            runs = await asyncio.gather(
                *(
                    run_device(
                        ws,
                        walk,
                        t0 + offset,
                        t0 + offset + seconds,
                        fps=fps,
                        saturate=saturate,
                        interval=interval,
                    )
                    for ws, offset in zip(streams, offsets_s, strict=True)
                )
            )
            window = await meter
            elapsed_s = time.perf_counter() - t0
            rss, rss_peak = sum(map(rss_mb, pids)), sum(map(peak_rss_mb, pids))
            server_cwd = os.readlink(f"/proc/{pids[0]}/cwd")
    finally:
        for sid, token, _ in sessions:
            with contextlib.suppress(ApiError):
                await delete_session(server.url, sid, token=token)
    return {
        **summarize(runs, window, devices, elapsed_s, rss, rss_peak, interval),
        "server_cwd": server_cwd,
        "load_avg_1m_before": load_before,
        "load_avg_1m_after": os.getloadavg()[0],
    }


def summarize(
    runs: list[DeviceRun],
    window: dict,
    devices: int,
    elapsed_s: float,
    rss: float,
    rss_peak: float,
    interval: int,
) -> dict:
    """The figures of one run from its devices and its window."""
    window_s = window["t1"] - window["t0"]
    acked_in_window = sum(
        sum(window["t0"] <= t <= window["t1"] for t in run.ack_times) for run in runs
    )
    due = sum(r.frames_due for r in runs)
    acked = sum(len(r.ack_times) for r in runs)
    superseded = sum(r.superseded for r in runs)
    keyframe_ms = [ms for r in runs for ms in r.keyframe_ms]
    errors = sum((r.errors for r in runs), Counter())
    return {
        "devices": devices,
        "keyframe_interval": interval,
        "sightings_sockets": sum(r.sightings for r in runs),
        "frames_due": due,
        "frames_sent": sum(r.frames_sent for r in runs),
        "sightings_sent": sum(r.sightings_sent for r in runs),
        "skipped": sum(r.skipped for r in runs),
        "frames_acked": acked,
        "acked_percent": 100.0 * acked / due if due else None,
        "acked_not_superseded_percent": 100.0 * (acked - superseded) / due if due else None,
        "window_s": window_s,
        "acked_in_window": acked_in_window,
        "acked_per_s": acked_in_window / window_s,
        "keyframe_ack_ms": latency_summary(keyframe_ms),
        "frame_ack_ms": latency_summary([ms for r in runs for ms in r.frame_ms]),
        "superseded_keyframes": superseded,
        "superseded_percent": 100.0 * superseded / (superseded + len(keyframe_ms))
        if superseded + len(keyframe_ms)
        else None,
        "errors": sum(errors.values()),
        "error_kinds": dict(errors),
        "unanswered": sum(r.unanswered for r in runs),
        "stalled_sockets": sum(r.longest_wait_ms > STALL_S * 1e3 for r in runs),
        "longest_wait_ms": max(r.longest_wait_ms for r in runs),
        "server_cpu_s": window["server_cpu_s"],
        "server_cpu_percent": 100.0 * window["server_cpu_s"] / window_s,
        "server_cpu_ms_per_acked_frame": 1e3 * window["server_cpu_s"] / acked_in_window
        if acked_in_window
        else None,
        "client_cpu_percent": 100.0 * window["client_cpu_s"] / window_s,
        "client_send_lag_max_ms": max(r.send_lag_max_ms for r in runs),
        "rss_mb": rss,
        "rss_peak_mb": rss_peak,
        "elapsed_s": elapsed_s,
        "per_device": [
            {
                "frames_due": r.frames_due,
                "frames_sent": r.frames_sent,
                "frames_acked": len(r.ack_times),
                "keyframe_ack_p95_ms": latency_summary(r.keyframe_ms)["p95"],
                "superseded_keyframes": r.superseded,
                "errors": sum(r.errors.values()),
                "unanswered": r.unanswered,
                "longest_wait_ms": r.longest_wait_ms,
            }
            for r in runs
        ],
    }


def run_all(
    specs: list[ServerSpec],
    walk: Walk,
    device_counts: list[int],
    *,
    seconds: float,
    fps: float,
    saturate: bool,
    sightings: bool,
) -> list[dict]:
    """One run per device count and server, each on a fresh server; with several servers the
    order alternates from count to count (A B, then B A, ...)."""
    api_key = secrets.token_urlsafe(16)
    runs = []
    for n, devices in enumerate(device_counts):
        for spec in specs if n % 2 == 0 else specs[::-1]:
            with tempfile.TemporaryDirectory(prefix="semanticxr-load-") as data_dir:
                print(f"  {spec.label}: starting its server", file=sys.stderr)
                server = start_server(spec, data_dir, api_key)
                try:
                    warm_up_s = asyncio.run(warm_up(server, walk, api_key))
                    print(
                        f"  {spec.label}: warm-up {warm_up_s:.1f} s; {devices} devices for "
                        f"{seconds:g} s",
                        file=sys.stderr,
                    )
                    run = asyncio.run(
                        load_run(
                            server,
                            walk,
                            devices,
                            api_key=api_key,
                            seconds=seconds,
                            fps=fps,
                            saturate=saturate,
                            sightings=sightings,
                            seed=devices,
                        )
                    )
                except BaseException:
                    print(f"{spec.label}'s server log:\n{server.output()[-3000:]}", file=sys.stderr)
                    raise
                finally:
                    server.stop()
            runs.append({"server": spec.label, "warm_up_s": warm_up_s, **run})
            print(
                f"  {spec.label}, {devices} devices: {run['acked_per_s']:.1f} frames acked/s, "
                f"keyframe p95 {_ms(run['keyframe_ack_ms']['p95'])} ms",
                file=sys.stderr,
            )
    return runs


# --- report -----------------------------------------------------------------------------


def _ms(value: float | None) -> str:
    return "-" if value is None else f"{value:.1f}"


def print_table(runs: list[dict], header: str) -> None:
    """A row per run, by device count, the servers in the order they were named."""
    print(header)
    order = {label: i for i, label in enumerate(dict.fromkeys(r["server"] for r in runs))}
    width = max(6, *(len(r["server"]) for r in runs))
    print(
        f"{'devices':>7} {'server':<{width}} {'acked/s':>7} {'acked%':>6} {'kf p50':>7} "
        f"{'kf p95':>7} {'kf p99':>7} {'fr p50':>6} {'fr p95':>6} {'supers.':>7} "
        f"{'cpu ms/fr':>9} {'cpu%':>5} {'dev cpu%':>8} {'RSS MB':>6} {'stalled':>7} {'errors':>6}"
    )
    for run in sorted(runs, key=lambda r: (r["devices"], order[r["server"]])):
        key, plain = run["keyframe_ack_ms"], run["frame_ack_ms"]
        acked = "-" if run["acked_percent"] is None else f"{run['acked_percent']:.1f}"
        print(
            f"{run['devices']:>7} {run['server']:<{width}} {run['acked_per_s']:>7.1f} "
            f"{acked:>6} {_ms(key['p50']):>7} {_ms(key['p95']):>7} {_ms(key['p99']):>7} "
            f"{_ms(plain['p50']):>6} {_ms(plain['p95']):>6} {run['superseded_keyframes']:>7} "
            f"{_ms(run['server_cpu_ms_per_acked_frame']):>9} {run['server_cpu_percent']:>5.0f} "
            f"{run['client_cpu_percent']:>8.0f} {run['rss_mb']:>6.0f} "
            f"{run['stalled_sockets']:>7} {run['errors'] + run['unanswered']:>6}"
        )


def targets(runs: list[dict], *, saturate: bool, sightings: bool) -> list[dict]:
    """The one-process targets (docs/evaluation.md "Targets", many devices), per server, from the paced runs at 8 and 32 devices."""
    if saturate:
        print("targets: for paced runs only (these devices were unpaced)")
        return []
    print("targets (one 2-core process, paced devices):")
    verdicts = []

    def verdict(name: str, value: float | None, op: str, target: float, unit: str) -> None:
        if value is None:
            print(f"  [MISS] {name}: nothing measured (target {op} {target}{unit})")
            verdicts.append({"name": name, "value": None, "op": op, "target": target, "ok": False})
        else:
            verdicts.append(check(name, value, op, target, unit))

    order = {label: i for i, label in enumerate(dict.fromkeys(r["server"] for r in runs))}
    for run in sorted(runs, key=lambda r: (order[r["server"]], r["devices"])):
        name = f"{run['server']}, {run['devices']} devices"
        if run["devices"] == 32:
            if not sightings:
                verdict(
                    f"{name}: server CPU per whole frame (mean)",
                    run["server_cpu_ms_per_acked_frame"],
                    "<=",
                    5.0,
                    " ms",
                )
            verdict(
                f"{name}: frames acked, {run['superseded_keyframes']} keyframes acked as "
                "superseded not counted",
                run["acked_not_superseded_percent"],
                ">=",
                99.0,
                " %",
            )
            verdict(f"{name}: keyframe ack p95", run["keyframe_ack_ms"]["p95"], "<=", 250.0, " ms")
        elif run["devices"] == 8:
            verdict(f"{name}: keyframe ack p95", run["keyframe_ack_ms"]["p95"], "<=", 100.0, " ms")
    if not verdicts:
        print("  (none: the targets are at 8 and 32 devices)")
    return verdicts


def plot(runs: list[dict], specs: list[ServerSpec], out_dir: str, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (latency_ax, cpu_ax) = plt.subplots(1, 2, figsize=(10, 3.8))
    for spec, color in zip(specs, ("tab:red", "tab:blue", "tab:green", "tab:orange"), strict=False):
        mine = sorted((r for r in runs if r["server"] == spec.label), key=lambda r: r["devices"])
        devices = [r["devices"] for r in mine]
        nan = lambda v: math.nan if v is None else v  # noqa: E731
        for q, style in (("p95", "-"), ("p50", "--")):
            latency_ax.plot(
                devices,
                [nan(r["keyframe_ack_ms"][q]) for r in mine],
                style,
                marker="o",
                color=color,
                label=f"{spec.label} keyframe {q}",
            )
        cpu_ax.plot(
            devices,
            [nan(r["server_cpu_ms_per_acked_frame"]) for r in mine],
            marker="o",
            color=color,
            label=spec.label,
        )
    counts = sorted({r["devices"] for r in runs})
    for ax in (latency_ax, cpu_ax):
        ax.set_xticks(counts)
    latency_ax.set_xlabel("devices")
    latency_ax.set_ylabel("keyframe ingest-to-ack, ms")
    latency_ax.legend(fontsize=8)
    cpu_ax.set_xlabel("devices")
    cpu_ax.set_ylabel("server CPU per acked frame, ms")
    cpu_ax.set_ylim(bottom=0)
    cpu_ax.legend(fontsize=8)
    fig.suptitle(title, fontsize=10)
    save_plot(fig, out_dir, "load")
    plt.close(fig)


# --- command ----------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    parser = bench_parser(__doc__)
    parser.add_argument(
        "--devices", default="8,32", metavar="N,N,...", help="device counts, a run each"
    )
    parser.add_argument("--seconds", type=float, default=30.0, help="measured window of a run")
    parser.add_argument("--fps", type=float, default=5.0, help="frames per second per device")
    parser.add_argument(
        "--saturate", action="store_true", help="closed loop: next frame when answered"
    )
    parser.add_argument(
        "--sightings", action="store_true", help="offer the sightings extension on every socket"
    )
    which = parser.add_mutually_exclusive_group()
    which.add_argument(
        "--semanticxr",
        action="append",
        type=Path,
        metavar="PATH",
        help="run the server of this checkout (repeat to compare several); default: this one",
    )
    which.add_argument(
        "--compare",
        nargs=2,
        type=Path,
        metavar=("PATH_A", "PATH_B"),
        help="run both checkouts' servers, alternating, side by side",
    )
    parser.add_argument("--scene", default="apartment", help="synthetic scene of the walk")
    parser.add_argument(
        "--size", default="640x480", metavar="WxH", help="RGB size of the encoded frames"
    )
    parser.add_argument("--out", default="out", help="folder for load.json and load.png")
    args = parser.parse_args(argv)

    try:
        device_counts = [int(n) for n in args.devices.split(",") if n.strip()]
        size_px = tuple(int(v) for v in args.size.lower().split("x"))
    except ValueError:
        parser.error(f"--devices N,N,... and --size WxH, got {args.devices!r} and {args.size!r}")
    if not device_counts or min(device_counts) < 1 or max(device_counts) > MAX_PACED_DEVICES:
        parser.error(f"--devices must list counts from 1 to {MAX_PACED_DEVICES}")
    if len(size_px) != 2 or min(size_px) < 16:
        parser.error(f"--size must be WxH with both at least 16, got {args.size!r}")
    if not 0 < args.seconds <= MAX_SECONDS:
        parser.error(f"--seconds must be in (0, {MAX_SECONDS:g}], got {args.seconds:g}")
    if not 0 < args.fps <= 60:
        parser.error(f"--fps must be in (0, 60], got {args.fps:g}")
    checkouts = args.compare or args.semanticxr or [REPO_ROOT]
    for path in checkouts:
        if not is_checkout(path):
            parser.error(f"{path} holds no SemanticXR checkout (no app/cli)")
    specs = [server_spec(path) for path in checkouts]
    for i, spec in enumerate(specs):  # a label names one server
        if any(other.label == spec.label for other in specs[:i]):
            spec.label = f"{spec.label}#{i + 1}"

    if os.getloadavg()[0] > 1.0:
        print(
            f"note: load average {os.getloadavg()[0]:.1f} before the runs: other work shares "
            "the cores the server is measured on",
            file=sys.stderr,
        )
    n_frames = math.ceil(args.seconds * args.fps - 1e-9)
    print(f"encoding {n_frames} frames...", file=sys.stderr)
    walk = encode_walk(
        n_frames, args.fps, sightings=args.sightings, scene=args.scene, size_px=size_px
    )
    runs = run_all(
        specs,
        walk,
        device_counts,
        seconds=args.seconds,
        fps=args.fps,
        saturate=args.saturate,
        sightings=args.sightings,
    )

    pacing = (
        "saturated (closed loop)"
        if args.saturate
        else f"paced {args.fps:g} fps per device, at most {PACED_MAX_IN_FLIGHT} in flight"
    )
    upload = "sightings extension" if args.sightings else "whole frames"
    title = (
        f"{pacing}, {args.seconds:g} s, {upload}, {size_px[0]}x{size_px[1]}; "
        f"servers: {', '.join(s.label for s in specs)}"
    )
    print_table(
        runs,
        f"load: {title}\ningest-to-ack ms over the run; acked/s, CPU (ms per acked frame, % of "
        "one core, server and devices) over the window; errors include unanswered frames",
    )
    verdicts = targets(runs, saturate=args.saturate, sightings=args.sightings)
    document = {
        "bench": "load",
        "machine": machine(),
        "scene": args.scene,
        "size_px": list(size_px),
        "fps_per_device": args.fps,
        "seconds": args.seconds,
        "saturate": args.saturate,
        "sightings": args.sightings,
        "max_in_flight_per_device": None if args.saturate else PACED_MAX_IN_FLIGHT,
        "upstream_bytes_per_frame": float(np.mean([len(f) for f in walk.whole])),
        "servers": [
            {
                "label": s.label,
                "checkout": str(s.checkout),
                "python": s.python,
                "commit": s.commit,
                "local_changes": s.local_changes,
            }
            for s in specs
        ],
        "runs": runs,
        "targets": verdicts,
    }
    write_outputs(args.out, "load", document)
    plot(runs, specs, args.out, title)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
