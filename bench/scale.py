"""Scale bench: the same paced devices through a gateway in front of 1, 2 and 4 map
shards on a local Ray, over PostgreSQL; and the shard hop on its own.

    python -m bench.scale --store postgresql://USER:PASSWORD@HOST/DB [--shards 1,2,4]
                          [--devices 16] [--seconds 20] [--saturate] [--out out/]

For each shard count: the shards start as detached Ray actors (`app.cluster.shards`, each a
SemanticXR server with `shard_name`), one gateway runs as `semanticxr gateway` in a child
process, and `bench.load`'s devices (the same pre-encoded apartment walk, whole frames, one
session each, paced at --fps) stream through the gateway for --seconds. CPU per acked frame
and RSS are summed over the gateway and every shard (/proc). With one shard, two devices
also stream through the gateway and straight to the shard, alternated: the difference of
keyframe ack p50 is the shard hop (the gateway's relay: one more loopback socket each way).

Per-session cost: the shards' RSS over the resident sessions (each device's session is
resident while it streams) beside the RSS of the idle shards; CPU ms per frame. The
estimate for M machines divides a machine's cores by the CPU a device costs (5 fps × ms per
frame), less what one gateway costs; it assumes the store keeps up.

On this machine (2 cores) every shard, the gateway, Ray and the devices share the same two
cores: more shards add parallel Python (each process has its own GIL) but no cores, so
frames/s stays capped by the machine, and what the runs show is that the design spreads the
work and what each hop costs, not a speed-up. The JSON says so beside the figures.
"""

from __future__ import annotations

import asyncio
import math
import os
import secrets
import subprocess
import sys
import time
from dataclasses import dataclass, field

import httpx

from app.server.runner import free_port
from app.server.settings import ServerSettings
from bench.common import bench_parser, machine, save_plot, write_outputs
from bench.load import cpu_s, encode_walk, load_run, warm_up
from bench.server import rss_mb

LEASE_S = 5.0


@dataclass
class Endpoint:
    """What `bench.load.load_run` streams to: a URL and the processes to measure."""

    url: str
    pids: list[int] = field(default_factory=list)

    @property
    def ws_url(self) -> str:
        return "ws" + self.url.removeprefix("http")

    @property
    def pid(self) -> int:
        return self.pids[0]


def start_gateway(store: str, api_key: str) -> tuple[subprocess.Popen, Endpoint]:
    port = free_port()
    child = subprocess.Popen(
        [sys.executable, "-m", "app.cli", "gateway", "--store", store, "--port", str(port),
         "--api-key", api_key, "--log-level", "warning", "--shard-lease-s", str(LEASE_S)],
        stdout=subprocess.DEVNULL,
    )  # fmt: skip
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 120
    while True:
        try:
            if httpx.get(f"{url}/healthz", timeout=2).status_code == 200:
                return child, Endpoint(url, [child.pid])
        except httpx.HTTPError:
            pass
        if child.poll() is not None or time.monotonic() > deadline:
            raise RuntimeError(f"the gateway did not start (exit {child.poll()})")
        time.sleep(0.2)


def shard_processes(n: int) -> tuple[list[int], list[str]]:
    """The pids and addresses of mapshard-0..n-1."""
    import ray

    from app.cluster.shards import NAMESPACE, shard_names

    actors = [ray.get_actor(name, namespace=NAMESPACE) for name in shard_names(n)]
    pids = ray.get([a.pid.remote() for a in actors])
    addresses = ray.get([a.address.remote() for a in actors])
    return pids, addresses


def run_shards(n: int, args, walk, api_key: str) -> tuple[list[dict], dict | None]:
    """The load run through the gateway in front of `n` shards; with one shard, also the
    shard hop (`measure_hop`)."""
    from app.cluster.shards import start_shards, stop_shards

    settings = ServerSettings(
        host="127.0.0.1", port=0, store=args.store, shards=n, api_key=api_key,
        log_level="warning", shard_lease_s=LEASE_S,
    )  # fmt: skip
    print(f"{n} shards: starting", file=sys.stderr)
    start_shards(settings)
    gateway, endpoint = start_gateway(args.store, api_key)
    hop = None
    try:
        pids, addresses = shard_processes(n)
        endpoint.pids += pids
        # One warm-up session a shard: the gateway creates sessions round robin, and a
        # shard's first keyframes pay its one-time costs (the text encoder's first batch).
        for _ in range(n):
            asyncio.run(warm_up(endpoint, walk, api_key))
        idle_rss = sum(map(rss_mb, pids))
        cpu0, gateway0 = sum(map(cpu_s, endpoint.pids)), cpu_s(gateway.pid)
        run = asyncio.run(
            load_run(
                endpoint, walk, args.devices, api_key=api_key, seconds=args.seconds,
                fps=args.fps, saturate=args.saturate, sightings=False, seed=n,
            )
        )  # fmt: skip
        result = {
            "shards": n,
            "route": "gateway",
            **{k: v for k, v in run.items() if k != "per_device"},
            "shards_idle_rss_mb": idle_rss,
            "mb_per_resident_session": (sum(map(rss_mb, pids)) - idle_rss) / args.devices,
            "cpu_s_whole_run": sum(map(cpu_s, endpoint.pids)) - cpu0,
            "gateway_cpu_ms_per_frame": 1e3
            * (cpu_s(gateway.pid) - gateway0)
            / max(1, run["frames_acked"]),
        }
        print(
            f"  {n} shards: {run['acked_per_s']:.1f} frames/s acked, keyframe ack p50/p95 "
            f"{run['keyframe_ack_ms']['p50']:.0f}/{run['keyframe_ack_ms']['p95']:.0f} ms, "
            f"{run['server_cpu_ms_per_acked_frame']:.1f} ms CPU a frame",
            file=sys.stderr,
        )
        if n == 1 and not args.saturate:
            hop = measure_hop(endpoint, Endpoint(addresses[0], list(pids)), walk, args, api_key)
    finally:
        gateway.terminate()
        gateway.wait(30)
        stop_shards(n)
    return [result], hop


HOP_DEVICES = 2
HOP_SECONDS = 10.0


def measure_hop(gateway: Endpoint, direct: Endpoint, walk, args, api_key: str) -> dict:
    """Keyframe ack p50 of HOP_DEVICES devices (a light load, so queues do not hide it)
    through the gateway and straight to its one shard, alternated (gateway, direct, direct,
    gateway); the hop is the difference of the means of the two p50s."""
    p50s: dict[str, list[float]] = {"gateway": [], "direct": []}
    plain: dict[str, list[float]] = {"gateway": [], "direct": []}
    # The same seeds for both routes: a seed sets the devices' phases, so how often their
    # keyframes meet, which moves p50 more than the hop does.
    for route, target, seed in [
        ("gateway", gateway, 100), ("direct", direct, 100),
        ("direct", direct, 101), ("gateway", gateway, 101),
    ]:  # fmt: skip
        run = asyncio.run(
            load_run(
                target, walk, HOP_DEVICES, api_key=api_key, seconds=HOP_SECONDS, fps=args.fps,
                saturate=False, sightings=False, seed=seed,
            )
        )  # fmt: skip
        p50s[route].append(run["keyframe_ack_ms"]["p50"])
        plain[route].append(run["frame_ack_ms"]["p50"])

    def hop_of(values: dict[str, list[float]]) -> float:
        return (sum(values["gateway"]) - sum(values["direct"])) / len(values["gateway"])

    hop = {
        "keyframe_ack_p50_ms": p50s,
        "frame_ack_p50_ms": plain,
        "hop_ms": hop_of(p50s),
        "plain_frame_hop_ms": hop_of(plain),
    }
    print(
        f"  shard hop: keyframes {hop['hop_ms']:.1f} ms ({p50s}), plain frames "
        f"{hop['plain_frame_hop_ms']:.1f} ms",
        file=sys.stderr,
    )
    return hop


def estimate(runs: list[dict], fps: float) -> dict:
    """Devices a machine of C cores holds, from the measured CPU per frame at the most shards."""
    widest = max((r for r in runs if r["route"] == "gateway"), key=lambda r: r["shards"])
    ms = widest["server_cpu_ms_per_acked_frame"]
    device_cores = fps * ms / 1e3
    return {
        "cpu_ms_per_frame": ms,
        "cores_per_device": device_cores,
        "devices_per_core": 1 / device_cores,
        "devices_on_m_machines_of_c_cores": "M × C / cores_per_device (the store keeping up)",
        "example_4_machines_of_8_cores": math.floor(4 * 8 / device_cores),
    }


def plot(runs: list[dict], out_dir: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    through = [r for r in runs if r["route"] == "gateway"]
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 3.8))
    shards = [r["shards"] for r in through]
    left.plot(shards, [r["acked_per_s"] for r in through], "o-")
    left.set(xlabel="map shards", ylabel="frames acked / s", title="throughput (2 cores)")
    for key, label in (("p50", "keyframe ack p50"), ("p95", "keyframe ack p95")):
        right.plot(shards, [r["keyframe_ack_ms"][key] for r in through], "o-", label=label)
    right.set(xlabel="map shards", ylabel="ms", title="latency through the gateway")
    right.legend()
    save_plot(fig, out_dir, "scale")


def main(argv: list[str] | None = None) -> int:
    parser = bench_parser(__doc__)
    parser.add_argument("--store", default=os.environ.get("SEMANTICXR_STORE"),
                        help="the cluster's postgresql:// store (or SEMANTICXR_STORE)")  # fmt: skip
    parser.add_argument("--shards", default="1,2,4", metavar="N,N,...", help="shard counts")
    parser.add_argument("--devices", type=int, default=16, help="paced devices in every run")
    parser.add_argument("--seconds", type=float, default=20.0, help="measured window of a run")
    parser.add_argument("--fps", type=float, default=5.0, help="frames per second per device")
    parser.add_argument(
        "--saturate", action="store_true", help="closed loop: what the shards can take"
    )
    parser.add_argument("--out", default="out", help="folder for scale.json and scale.png")
    args = parser.parse_args(argv)
    if not args.store or not args.store.startswith(("postgresql:", "postgres:")):
        parser.error("--store: give the cluster's postgresql:// URL (or SEMANTICXR_STORE)")
    try:
        counts = [int(n) for n in args.shards.split(",") if n.strip()]
    except ValueError:
        parser.error(f"--shards N,N,...: got {args.shards!r}")
    if not counts or min(counts) < 1 or not 1 <= args.devices <= 64:
        parser.error("--shards counts must be at least 1; --devices within 1..64")

    from app.cluster.shards import connect

    connect("auto")
    api_key = secrets.token_urlsafe(16)
    n_frames = math.ceil(args.seconds * args.fps - 1e-9)
    print(f"encoding {n_frames} frames...", file=sys.stderr)
    walk = encode_walk(n_frames, args.fps, sightings=False)
    runs, hop = [], None
    for n in counts:
        shard_runs, shard_hop = run_shards(n, args, walk, api_key)
        runs += shard_runs
        hop = hop or shard_hop
    document = {
        "machine": machine(),
        "devices": args.devices,
        "fps": args.fps,
        "saturate": args.saturate,
        "seconds": args.seconds,
        "runs": runs,
        "shard_hop": hop,
        "estimate": estimate(runs, args.fps),
        "caveat": (
            f"{os.cpu_count()} cores shared by every shard, the gateway, Ray and the devices: "
            "shards add processes, not cores"
        ),
    }
    write_outputs(args.out, "scale", document)
    plot(runs, args.out)
    if hop is not None:
        print(f"shard hop (keyframe ack p50, gateway - direct, 1 shard): {hop['hop_ms']:.1f} ms")
    for r in runs:
        print(
            f"{r['shards']} shards: {r['acked_per_s']:6.1f} frames/s, keyframe "
            f"p50/p95 {r['keyframe_ack_ms']['p50']:.0f}/{r['keyframe_ack_ms']['p95']:.0f} ms, "
            f"{r['server_cpu_ms_per_acked_frame']:.1f} ms CPU/frame, "
            f"(gateway {r['gateway_cpu_ms_per_frame']:.1f}), "
            f"{r['mb_per_resident_session']:.1f} MB/session, {r['stalled_sockets']} stalled"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
