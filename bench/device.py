"""Device-side figures: upstream bandwidth by path, depth ratio and encoding,
device CPU.

    python -m bench.device [--frames 150] [--no-quality] [--real DIR] [--out out/]

- Upstream Mbps at 5 fps, 640x480, depth ÷5, encoder defaults, on both paths (target:
  <= 0.5 Mbps with the extension, docs/evaluation.md "Targets"): a plain v1 device sending every frame whole,
  and the sightings extension (app/protocol/sighting.py), keyframes whole (the shared
  selector, app.keyframes) and a coarse sighting of each frame between them.
- Upstream Mbps at 5 fps, 640x480, for depth downsampling ratios 1-5 with the encoder's
  defaults (client_sim/encoder.py), with the semanticxr F-mIoU at each ratio (eval on the
  same scene) so the bandwidth saving is read next to its quality cost.
- Upstream at depth ÷5 over a grid of JPEG quality x depth codec x depth step (the frame's
  depth.scale), bytes per kind, on the synthetic frames and on real 7-Scenes frames (--real;
  skipped if the folder is missing), with the RGB's PSNR against the source image at each
  JPEG quality, and a few single-lever variations of the defaults.
- F-mIoU at depth ÷5 by depth step, against the full-precision reference (÷1, 1 mm units):
  the target allows a drop of at most 2.5 points.
- Device CPU seconds per second of streaming at 5 fps (our stand-in for device power): the
  emulated device encodes, sends, follows the updates stream and applies deltas to its local
  map while a `semanticxr serve` process maps; frames are rendered before the clock starts,
  since rendering the synthetic world is not device work.
"""

from __future__ import annotations

import asyncio
import os
import sys
import tempfile
import time

import numpy as np

from app.server.runner import ServerProcess
from bench.common import bench_parser, check, machine, save_plot, write_outputs
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


def upstream_by_path(frames: list[SourceFrame], ratio: int = 5) -> dict[str, dict]:
    """Upstream at 5 fps for the frames in order, encoder defaults at depth ÷`ratio`: every
    frame whole ("whole frames"), and keyframes whole with sightings between them ("sightings
    extension"), keyframes picked by the shared selector at the default interval."""
    from app.config import Knobs
    from app.keyframes import is_keyframe
    from client_sim.encoder import FrameEncoder

    encoder = FrameEncoder(ratio)
    interval = Knobs().keyframe_interval
    whole, keyframes, sightings = [], [], []
    for f in frames:
        total = encoder.encode_source_frame(f).bytes_by_kind["total"]
        whole.append(total)
        if is_keyframe(f.index, interval):
            keyframes.append(total)
        else:
            sightings.append(encoder.encode_source_frame_as_sighting(f).bytes_by_kind["total"])
    out = {
        "whole frames": {
            "bytes_per_frame": float(np.mean(whole)),
            "mbps_at_5fps": mbps_at_5fps(float(np.mean(whole))),
        },
        "sightings extension": {
            "bytes_per_keyframe": float(np.mean(keyframes)),
            "bytes_per_sighting": float(np.mean(sightings)),
            "mbps_at_5fps": mbps_at_5fps((sum(keyframes) + sum(sightings)) / len(frames)),
        },
    }
    ext = out["sightings extension"]
    print(
        f"  whole frames: {out['whole frames']['mbps_at_5fps']:.3f} Mbps "
        f"({out['whole frames']['bytes_per_frame'] / 1e3:.1f} kB a frame); sightings "
        f"extension: {ext['mbps_at_5fps']:.3f} Mbps (keyframes {ext['bytes_per_keyframe'] / 1e3:.1f}"
        f" kB, 1 in {interval}; sightings {ext['bytes_per_sighting'] / 1e3:.2f} kB)"
    )
    return out


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
        # The target is the mean rate; the busiest second of the walk says how far peaks go.
        per_second = np.convolve(sizes["total"], np.ones(int(STREAM_FPS)), mode="valid")
        out[ratio] = {
            "bytes_per_frame": mean,
            "mbps_at_5fps": mean["total"] * 8 * STREAM_FPS / 1e6,
            "busiest_second_mbps": float(per_second.max()) * 8 / 1e6 if per_second.size else None,
        }
        print(
            f"  depth ÷{ratio}: {out[ratio]['mbps_at_5fps']:.2f} Mbps at 5 fps "
            f"(rgb {mean['rgb'] / 1e3:.1f} kB, depth {mean['depth'] / 1e3:.1f} kB, "
            f"detections {mean['detections'] / 1e3:.1f} kB per frame; busiest second "
            f"{out[ratio]['busiest_second_mbps'] or float('nan'):.2f} Mbps)"
        )
    return out


GRID_JPEG_QUALITIES = (85, 75, 60, 50, 40)
GRID_DEPTH_CODECS = ("zstd", "png")
GRID_DEPTH_STEPS_MM = (1, 2, 4, 5, 10)
KINDS = ("rgb", "depth", "detections", "total")
REAL_DEFAULT = "/work/shared/data/7scenes-redkitchen/data"


def mean_bytes(encoder, frames: list[SourceFrame]) -> dict[str, float]:
    """Mean bytes per frame by kind ("total" = the whole msgpack frame message)."""
    sizes = {kind: [] for kind in KINDS}
    for f in frames:
        encoded = encoder.encode_source_frame(f)
        for kind in KINDS:
            sizes[kind].append(encoded.bytes_by_kind.get(kind, 0))
    return {kind: float(np.mean(values)) for kind, values in sizes.items()}


def mbps_at_5fps(total_bytes: float) -> float:
    return total_bytes * 8 * STREAM_FPS / 1e6


def upstream_grid(frames: list[SourceFrame], ratio: int = 5) -> list[dict]:
    """Upstream at one depth ratio for JPEG qualities x depth codecs x depth steps; every
    other encoder setting at its default."""
    from client_sim.encoder import FrameEncoder

    rows = []
    print(f"  {'JPEG':>5} {'codec':>5} {'step':>6} | {'rgb':>7} {'depth':>7} {'det':>6} "
          f"{'total':>7} kB | Mbps")  # fmt: skip
    for quality in GRID_JPEG_QUALITIES:
        for depth_codec in GRID_DEPTH_CODECS:
            for step_mm in GRID_DEPTH_STEPS_MM:
                encoder = FrameEncoder(
                    ratio,
                    jpeg_quality=quality,
                    depth_codec=depth_codec,
                    depth_scale_m=step_mm / 1000,
                )
                mean = mean_bytes(encoder, frames)
                row = {
                    "jpeg_quality": quality,
                    "depth_codec": depth_codec,
                    "depth_step_mm": step_mm,
                    "bytes_per_frame": mean,
                    "mbps_at_5fps": mbps_at_5fps(mean["total"]),
                }
                rows.append(row)
                print(
                    f"  q{quality:>4} {depth_codec:>5} {step_mm:>4g}mm | {mean['rgb'] / 1e3:7.1f} "
                    f"{mean['depth'] / 1e3:7.1f} {mean['detections'] / 1e3:6.1f} "
                    f"{mean['total'] / 1e3:7.1f}    | {row['mbps_at_5fps']:.2f}"
                )
    return rows


def upstream_levers(frames: list[SourceFrame], ratio: int = 5) -> list[dict]:
    """The defaults, then one setting changed at a time, then the settings before the upstream
    defaults were chosen."""
    from client_sim.encoder import FrameEncoder

    variations = {
        "defaults": {},
        "JPEG without optimised Huffman tables": {"jpeg_optimize": False},
        "zstd level 3 (the codec module's level)": {"zstd_level": 3},
        "detections as png": {"detections_codec": "png"},
        "depth as zstd": {"depth_codec": "zstd"},
        "before the upstream defaults (q85, zstd-3 1 mm depth, zstd-3 detections)": {
            "jpeg_quality": 85,
            "jpeg_optimize": False,
            "depth_codec": "zstd",
            "depth_scale_m": 0.001,
            "zstd_level": 3,
        },
    }
    rows = []
    for name, options in variations.items():
        mean = mean_bytes(FrameEncoder(ratio, **options), frames)
        rows.append(
            {
                "variation": name,
                "options": options,
                "bytes_per_frame": mean,
                "mbps_at_5fps": mbps_at_5fps(mean["total"]),
            }
        )
        print(
            f"  {name}: {mbps_at_5fps(mean['total']):.2f} Mbps (rgb {mean['rgb'] / 1e3:.1f}, "
            f"depth {mean['depth'] / 1e3:.1f}, detections {mean['detections'] / 1e3:.1f}, "
            f"total {mean['total'] / 1e3:.1f} kB)"
        )
    return rows


def rgb_psnr_by_quality(frames: list[SourceFrame]) -> dict[int, float]:
    """Mean PSNR (dB) of the decoded JPEG against the source image, by JPEG quality."""
    from app.codecs import decode_jpeg
    from client_sim.encoder import DEFAULT_JPEG_OPTIMIZE, encode_rgb_jpeg

    out = {}
    for quality in GRID_JPEG_QUALITIES:
        psnr = []
        for f in frames:
            decoded = decode_jpeg(encode_rgb_jpeg(f.rgb, quality, DEFAULT_JPEG_OPTIMIZE))
            mse = np.mean((decoded.astype(np.float64) - f.rgb.astype(np.float64)) ** 2)
            psnr.append(10 * np.log10(255.0**2 / max(mse, 1e-12)))
        out[quality] = float(np.mean(psnr))
    print("  RGB PSNR vs source: " + ", ".join(f"q{q} {v:.1f} dB" for q, v in out.items()))
    return out


def upstream_on(name: str, frames: list[SourceFrame]) -> dict:
    print(f"upstream at depth ÷5 on {name} ({len(frames)} frames), Mbps at 5 fps:")
    return {
        "frames": len(frames),
        "grid": upstream_grid(frames),
        "levers": upstream_levers(frames),
        "rgb_psnr_db": rgb_psnr_by_quality(frames),
    }


def real_frames(path: str, count: int) -> list[SourceFrame] | None:
    """`count` evenly spaced frames of a 7-Scenes folder, or None if it is not there."""
    from client_sim.sources import make_source

    try:
        source = make_source(f"7scenes:{path}")
    except (OSError, ValueError) as exc:
        print(f"(no real frames: {exc})", file=sys.stderr)
        return None
    every = max(1, len(source) // count)
    return list(source.frames(every=every, limit=count * every))[:count]


def semanticxr_f_miou(scene: str, frames: int, ratio: int, **encoder_options) -> float:
    """F-mIoU of the semanticxr organisation (evaluation.walk.run_eval) with the
    device encoder at `ratio` and `encoder_options` (unset ones: FrameEncoder defaults)."""
    import evaluation.walk as evaluation
    from app.config import Knobs
    from app.semantics import get_text_encoder

    cfg = evaluation.EvalConfig(
        scene=scene,
        frames=frames,
        modes=("semanticxr",),
        knobs=Knobs(depth_downsampling_ratio=ratio),
        encoder_options=encoder_options,
    )
    result = evaluation.run_eval(cfg, get_text_encoder(), progress=lambda _: None)
    return result["modes"]["semanticxr"]["F_mIoU"]


def quality_by_ratio(scene: str, frames: int) -> dict[int, float]:
    """F-mIoU at depth ratios 1-5 with the encoder's defaults."""
    out = {}
    for ratio in range(1, 6):
        out[ratio] = semanticxr_f_miou(scene, frames, ratio)
        print(f"  depth ÷{ratio} (defaults): F-mIoU {out[ratio]:.1f}")
    return out


def quality_by_depth_step(scene: str, frames: int) -> tuple[float, dict[int, float]]:
    """(F-mIoU at the reference ÷1 with 1 mm units, F-mIoU at ÷5 by depth step in mm)."""
    reference = semanticxr_f_miou(scene, frames, 1, depth_scale_m=0.001)
    print(f"  reference ÷1, 1 mm: F-mIoU {reference:.1f}")
    by_step = {}
    for step_mm in GRID_DEPTH_STEPS_MM:
        by_step[step_mm] = semanticxr_f_miou(scene, frames, 5, depth_scale_m=step_mm / 1000)
        print(f"  ÷5, {step_mm} mm: F-mIoU {by_step[step_mm]:.1f}")
    return reference, by_step


async def device_cpu(
    server: ServerProcess, source: FrameSource, seconds: float, sightings: bool = True
) -> dict:
    """A device streaming to a real server at 5 fps: its CPU and what it sent (with the
    sightings extension, or every frame whole)."""
    from app.client import create_session
    from app.config import Knobs
    from client_sim.streaming import DeviceClient

    sid, token, _ = await create_session(server.url, name="cpu-bench")
    device = DeviceClient(
        server.url, sid, token, knobs=Knobs(), sightings=sightings, on_log=lambda m: None
    )
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
        "sightings_sent": s.sightings_sent,
        "bytes_up": s.bytes_up_by_kind["total"],
        "upstream_mbps": s.bytes_up_by_kind["total"] * 8 / wall / 1e6,
        "bytes_down": s.bytes_down,
    }


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    parser = bench_parser(__doc__)
    parser.add_argument("--scene", default="apartment", help="synthetic scene of the streams")
    parser.add_argument("--frames", type=int, default=150, help="frames rendered for the streams")
    parser.add_argument(
        "--grid-frames", type=int, default=30, help="frames (evenly spaced) of each encoding grid"
    )
    parser.add_argument(
        "--real",
        default=REAL_DEFAULT,
        metavar="DIR",
        help="a 7-Scenes sequence folder for the grid on real frames (skipped if missing)",
    )
    parser.add_argument("--eval-frames", type=int, default=400, help="frames of each quality eval")
    parser.add_argument(
        "--no-quality", action="store_true", help="skip the F-mIoU evals (by ratio and depth step)"
    )
    parser.add_argument("--out", default="out", help="folder for device.json and the plots")
    args = parser.parse_args(argv)

    from client_sim.encoder import FrameEncoder
    from client_sim.sources.synthetic import SyntheticSource

    defaults = FrameEncoder()
    print(
        f"encoder defaults: JPEG q{defaults.jpeg_quality} (optimised Huffman "
        f"{defaults.jpeg_optimize}), depth {defaults.depth_codec} in "
        f"{defaults.depth_scale_m * 1000:g} mm units, detections {defaults.detections_codec}, "
        f"zstd level {defaults.zstd_level}"
    )
    print(f"rendering {args.frames} frames...", file=sys.stderr)
    source = SyntheticSource(args.scene, n_frames=args.frames)
    frames = list(source.frames())
    print(f"upstream by path at 5 fps, 640x480, depth ÷5 ({len(frames)} frames of {args.scene}):")
    by_path = upstream_by_path(frames)
    print("upstream bandwidth by depth ratio (encoder defaults):")
    upstream = upstream_by_ratio(frames)
    grid_every = max(1, len(frames) // args.grid_frames)
    by_source = {"synthetic": upstream_on(f"synthetic {args.scene}", frames[::grid_every])}
    real = real_frames(args.real, args.grid_frames)
    if real:
        by_source["7scenes"] = upstream_on(f"7-Scenes {args.real} (no detections)", real)

    quality: dict[int, float] = {}
    reference, by_step = None, {}
    if not args.no_quality:
        print("semanticxr F-mIoU by depth ratio, encoder defaults:")
        quality = quality_by_ratio(args.scene, args.eval_frames)
        print("semanticxr F-mIoU by depth step:")
        reference, by_step = quality_by_depth_step(args.scene, args.eval_frames)

    with tempfile.TemporaryDirectory() as data_dir:
        server = ServerProcess(data_dir, quiet=False).start()
        try:
            cpu_by_path = {
                name: asyncio.run(
                    device_cpu(
                        server, PrerenderedSource(frames), args.frames / STREAM_FPS, sightings
                    )
                )
                for name, sightings in (("whole frames", False), ("sightings extension", True))
            }
        finally:
            server.stop()
    for name, run in cpu_by_path.items():
        print(
            f"device streaming to a server at 5 fps, {name}: {run['cpu_s_per_s']:.3f} CPU-s per "
            f"s, upstream {run['upstream_mbps']:.3f} Mbps measured ({run['frames']} frames, "
            f"{run['sightings_sent']} of them sightings, {run['objects_held']} objects held)"
        )
    cpu = cpu_by_path["sightings extension"]
    targets = [
        check(
            "6. upstream with the sightings extension, 5 fps, 640x480 (defaults, synthetic)",
            by_path["sightings extension"]["mbps_at_5fps"],
            "<=",
            0.5,
            " Mbps",
        ),
        check(
            "upstream at depth ÷5, 5 fps (defaults, synthetic)",
            upstream[5]["mbps_at_5fps"],
            "<=",
            1.25,
            " Mbps",
        ),
    ]
    if "7scenes" in by_source:
        levers = by_source["7scenes"]["levers"]
        real_defaults = next(row for row in levers if row["variation"] == "defaults")
        targets.append(
            check(
                "upstream at depth ÷5, 5 fps (defaults, 7-Scenes, no detections)",
                real_defaults["mbps_at_5fps"],
                "<=",
                1.25,
                " Mbps",
            )
        )
    if quality:
        targets.append(
            check(
                "F-mIoU drop ÷1 at 1 mm -> ÷5 (defaults)",
                reference - quality[5],
                "<=",
                2.5,
                " pts",
            )
        )
    write_outputs(
        args.out,
        "device",
        {
            "bench": "device",
            "machine": machine(),
            "scene": args.scene,
            "encoder_defaults": {
                "jpeg_quality": defaults.jpeg_quality,
                "jpeg_optimize": defaults.jpeg_optimize,
                "depth_codec": defaults.depth_codec,
                "depth_scale_m": defaults.depth_scale_m,
                "detections_codec": defaults.detections_codec,
                "zstd_level": defaults.zstd_level,
            },
            "upstream_by_path": by_path,
            "upstream": upstream,
            "upstream_grid": by_source,
            "f_miou_by_ratio": quality,
            "f_miou_reference_ratio1_1mm": reference,
            "f_miou_by_depth_step_mm": by_step,
            "device_cpu": cpu,
            "device_cpu_by_path": cpu_by_path,
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
    ax.axhline(1.25, color="grey", linestyle=":", label="target at ÷5")
    ax.set_xlabel("depth downsampling ratio (encoder defaults)")
    ax.set_ylabel("upstream Mbps at 5 fps")
    if quality:
        ax2 = ax.twinx()
        ax2.plot([str(r) for r in ratios], [quality[r] for r in ratios], "o-", color="tab:red")
        ax2.set_ylabel("F-mIoU (semanticxr)", color="tab:red")
    save_plot(fig, args.out, "device_upstream")
    plot_grid(plt, by_source, args.out)
    return 0


def plot_grid(plt, by_source: dict, out_dir: str) -> None:
    """Mbps at ÷5 against JPEG quality, one line per depth codec and step, one panel per source."""
    fig, axes = plt.subplots(1, len(by_source), figsize=(5.5 * len(by_source), 3.8), squeeze=False)
    for ax, (name, result) in zip(axes[0], by_source.items(), strict=True):
        for i, step_mm in enumerate(GRID_DEPTH_STEPS_MM):
            for depth_codec, style in (("png", "-"), ("zstd", "--")):
                rows = [
                    r
                    for r in result["grid"]
                    if r["depth_codec"] == depth_codec and r["depth_step_mm"] == step_mm
                ]
                ax.plot(
                    [r["jpeg_quality"] for r in rows],
                    [r["mbps_at_5fps"] for r in rows],
                    style,
                    marker="o",
                    markersize=3,
                    color=plt.cm.viridis(i / len(GRID_DEPTH_STEPS_MM)),
                    label=f"{depth_codec} {step_mm} mm",
                )
        ax.axhline(1.25, color="grey", linestyle=":")
        ax.set_title(f"{name}, depth ÷5")
        ax.set_xlabel("JPEG quality")
        ax.set_ylabel("upstream Mbps at 5 fps")
    axes[0][-1].legend(fontsize=7, ncol=2)
    save_plot(fig, out_dir, "device_upstream_grid")


if __name__ == "__main__":
    raise SystemExit(main())
