"""Device-side figures (issue 4): upstream bandwidth by depth ratio, and device CPU.

    python -m bench.device [--frames 150] [--seconds 20] [--no-quality] [--out out/]

- Upstream Mbps at 5 fps, 640x480, for depth downsampling ratios 1-5 (JPEG q85 RGB, zstd
  uint16 depth, zstd detections), with the semanticxr F-mIoU at each ratio (eval on the
  same scene) so the bandwidth saving is read next to its quality cost.
- Device CPU seconds per second of streaming at 5 fps (our stand-in for device power): the
  emulated device encodes, sends, follows the updates stream and applies deltas to its local
  map while a `semanticxr serve` process maps; frames are rendered before the clock starts,
  since rendering the synthetic world is not device work.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import sys
import tempfile
import time

import numpy as np

from bench.common import check, machine, save_plot, write_outputs
from bench.server import Server
from client_sim.sources.base import FrameSource, SourceFrame

STREAM_FPS = 5.0


class PrerenderedSource(FrameSource):
    """Frames rendered once, replayed from memory."""

    def __init__(self, frames: list[SourceFrame]):
        self._frames = frames
        self.name = "prerendered"

    def __len__(self) -> int:
        return len(self._frames)

    def frame(self, index: int) -> SourceFrame:
        return self._frames[self._check_index(index)]


def upstream_by_ratio(frames: list[SourceFrame]) -> dict[int, dict]:
    from client_sim.encoder import FrameEncoder

    out = {}
    for ratio in range(1, 6):
        encoder = FrameEncoder(ratio)
        sizes = {"rgb": [], "depth": [], "detections": [], "total": []}
        for f in frames:
            enc = encoder.encode_source_frame(f)
            for kind in sizes:
                sizes[kind].append(enc.bytes_by_kind.get(kind, 0))
        mean = {k: float(np.mean(v)) for k, v in sizes.items()}
        out[ratio] = {"bytes_per_frame": mean, "mbps_at_5fps": mean["total"] * 8 * STREAM_FPS / 1e6}
        print(
            f"  depth ÷{ratio}: {out[ratio]['mbps_at_5fps']:.2f} Mbps at 5 fps "
            f"(rgb {mean['rgb'] / 1e3:.1f} kB, depth {mean['depth'] / 1e3:.1f} kB, "
            f"detections {mean['detections'] / 1e3:.1f} kB per frame)"
        )
    return out


def upstream_by_codec(frames: list[SourceFrame], ratio: int = 5) -> list[dict]:
    """Upstream at one depth ratio for JPEG qualities x depth codecs (what else can shrink)."""
    from client_sim.encoder import FrameEncoder

    rows = []
    for depth_codec in ("zstd", "png"):
        for quality in (85, 75, 60, 50):
            encoder = FrameEncoder(ratio, jpeg_quality=quality, depth_codec=depth_codec)
            total = np.mean([encoder.encode_source_frame(f).bytes_by_kind["total"] for f in frames])
            mbps = float(total) * 8 * STREAM_FPS / 1e6
            rows.append({"jpeg_quality": quality, "depth_codec": depth_codec, "mbps_at_5fps": mbps})
            print(f"  depth ÷{ratio} {depth_codec:4s} JPEG q{quality}: {mbps:.2f} Mbps at 5 fps")
    return rows


def quality_by_ratio(scene: str, frames: int) -> dict[int, float]:
    from app.config import Knobs
    from app.semantics import get_text_encoder
    from client_sim.evaluation import EvalConfig, run_eval

    encoder = get_text_encoder()
    out = {}
    for ratio in range(1, 6):
        cfg = EvalConfig(
            scene=scene,
            frames=frames,
            modes=("semanticxr",),
            knobs=Knobs(depth_downsampling_ratio=ratio),
        )
        result = run_eval(cfg, encoder, progress=lambda _: None)
        out[ratio] = result["modes"]["semanticxr"]["F_mIoU"]
        print(f"  depth ÷{ratio}: F-mIoU {out[ratio]:.1f}")
    return out


async def device_cpu(server: Server, source: FrameSource, seconds: float) -> dict:
    from app.config import Knobs
    from client_sim.streaming import DeviceClient

    sid, token, _ = await DeviceClient.create_session(server.url, name="cpu-bench")
    device = DeviceClient(server.url, sid, token, knobs=Knobs(), on_log=lambda m: None)
    follower = asyncio.create_task(device.follow_updates())
    n = min(len(source), int(seconds * STREAM_FPS))
    cpu0, wall0 = time.process_time(), time.perf_counter()
    await device.stream(source, fps=STREAM_FPS, limit=n)
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    await device.stop()
    follower.cancel()
    s = device.stats
    return {
        "frames": s.frames_sent,
        "wall_s": wall,
        "cpu_s": cpu,
        "cpu_s_per_s": cpu / wall,
        "objects_held": len(device.local_map),
        "local_map_bytes": device.local_map.memory_bytes(),
        "bytes_up": sum(s.bytes_up_by_kind.values()),
        "bytes_down": s.bytes_down,
    }


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--scene", default="apartment")
    parser.add_argument("--frames", type=int, default=150, help="frames rendered for the streams")
    parser.add_argument("--eval-frames", type=int, default=400, help="frames of each quality eval")
    parser.add_argument("--no-quality", action="store_true", help="skip the F-mIoU per ratio")
    parser.add_argument("--out", default="out")
    args = parser.parse_args(argv)

    from client_sim.sources.synthetic import SyntheticSource

    print(f"rendering {args.frames} frames...", file=sys.stderr)
    source = SyntheticSource(args.scene, n_frames=args.frames)
    frames = list(source.frames())
    print("upstream bandwidth by depth ratio:")
    upstream = upstream_by_ratio(frames)
    print("upstream at depth ÷5 by JPEG quality and depth codec:")
    by_codec = upstream_by_codec(frames[::3])
    quality = {} if args.no_quality else quality_by_ratio(args.scene, args.eval_frames)
    with tempfile.TemporaryDirectory() as data_dir:
        server = Server(data_dir)
        try:
            cpu = asyncio.run(
                device_cpu(server, PrerenderedSource(frames), args.frames / STREAM_FPS)
            )
        finally:
            server.stop()
    print(
        f"device CPU: {cpu['cpu_s_per_s']:.3f} CPU-s per s of streaming at 5 fps "
        f"({cpu['frames']} frames, {cpu['objects_held']} objects held)"
    )
    targets = [
        check("upstream at depth ÷5, 5 fps", upstream[5]["mbps_at_5fps"], "<=", 1.25, " Mbps")
    ]
    if quality:
        targets.append(check("F-mIoU drop ÷1 -> ÷5", quality[1] - quality[5], "<=", 2.5, " pts"))
    write_outputs(
        args.out,
        "device",
        {
            "bench": "device",
            "machine": machine(),
            "scene": args.scene,
            "upstream": upstream,
            "upstream_by_codec": by_codec,
            "f_miou_by_ratio": quality,
            "device_cpu": cpu,
            "targets": targets,
        },
    )
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.5))
    ratios = sorted(upstream)
    ax.bar(
        [str(r) for r in ratios], [upstream[r]["mbps_at_5fps"] for r in ratios], color="tab:blue"
    )
    ax.set_xlabel("depth downsampling ratio")
    ax.set_ylabel("upstream Mbps at 5 fps")
    if quality:
        ax2 = ax.twinx()
        ax2.plot([str(r) for r in ratios], [quality[r] for r in ratios], "o-", color="tab:red")
        ax2.set_ylabel("F-mIoU (semanticxr)", color="tab:red")
    save_plot(fig, args.out, "device_upstream")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
