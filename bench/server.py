"""Server benchmarks through the real stack (a `semanticxr serve` process on loopback).

    python -m bench.server [--frames 150] [--seconds 20] [--out out/]

The server runs as `app.server.runner.ServerProcess` (`python -m app.cli serve`); every call
goes through the API client (app.client). Measures (issue 3): ingest-to-ack latency per keyframe and per plain frame; frames per
second sustained by 1 and 4 concurrent device streams (640x480, depth ÷5); bytes per
downstream update in `semanticxr` vs `baseline` mode on the standard synthetic scene.
"""

from __future__ import annotations

import asyncio
import sys
import tempfile
import time

import msgpack
import numpy as np

from app.client import create_session, open_websocket
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


def main(argv: list[str] | None = None) -> int:
    parser = bench_parser(__doc__)
    parser.add_argument("--scene", default="apartment", help="synthetic scene of the streamed walk")
    parser.add_argument("--frames", type=int, default=300, help="frames of the walk to pre-encode")
    parser.add_argument(
        "--seconds", type=float, default=15.0, help="duration of each sustained run"
    )
    parser.add_argument("--out", default="out", help="folder for server.json and the plot")
    args = parser.parse_args(argv)

    print("encoding frames...", file=sys.stderr)
    frames, keyframes = encode_frames(args.frames, args.scene)
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
        finally:
            server.stop()

    plateau = {m: float(np.mean(s[len(s) // 2 :])) if s else 0.0 for m, s in updates.items()}
    ratio = 100.0 * plateau["semanticxr"] / max(plateau["baseline"], 1.0)
    print(
        f"bytes/update at plateau: semanticxr {plateau['semanticxr']:.0f}, baseline {plateau['baseline']:.0f} "
        f"({ratio:.1f}%)"
    )
    targets = [
        check("1 stream sustains 30 fps input", runs[0]["fps_total"], ">=", 30.0, " fps"),
        check("downstream bytes/update vs baseline at plateau", ratio, "<=", 10.0, "%"),
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
