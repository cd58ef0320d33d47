"""Mapping speed and quality: semanticxr vs baseline on the same keyframes.

    python -m bench.mapping [--scene apartment] [--frames 400|1200] [--queries FILE] [--out out/]

The mapping and query targets (docs/evaluation.md "Targets"), at 640x480 RGB, depth ÷5, noise `standard`, both organisations
mapped side by side in one run (they take turns keyframe by keyframe, so machine load
drifts affect all alike):
  1. query top-1 over the categories in view (evaluation.walk: the noise-free detector
     reports them in at least 8 frames) >= 85 %, and never below the baseline's;
  2. F-mIoU of semanticxr within 1 point of the baseline's (or above);
  3. mean keyframe latency >= 3x lower than the baseline's, and semanticxr p95 <= 3x p50;
  4. a glance is enough: the categories in view for 8-15 frames only (1.6-3 s at 5 fps) are
     mapped (a proxy on the walk; the one-frame spurious detections are a test's matter).
Also reported, not targets: the point cap sweep, and a baseline fed full-resolution depth.
"""

from __future__ import annotations

import os

from bench.common import bench_parser, check, machine, save_plot, write_outputs

FULL_DEPTH_BASELINE = "baseline, depth ÷1"
GLANCE_MAX_FRAMES = 15
"""Target 4 on the walk: categories in view for at most this many frames (3 s at 5 fps)."""


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    parser = bench_parser(__doc__)
    parser.add_argument("--scene", default="apartment", help="synthetic scene to walk")
    parser.add_argument("--seed", type=int, default=0, help="scene, walk and noise seed")
    parser.add_argument(
        "--frames",
        type=int,
        default=400,
        help="input frames of the walk (the targets are set on 400- and 1,200-frame walks)",
    )
    parser.add_argument(
        "--noise", default="standard", help="detection noise profile (none or standard)"
    )
    parser.add_argument("--out", default="out", help="folder for mapping.json and mapping.png")
    parser.add_argument(
        "--no-sightings",
        dest="sightings",
        action="store_false",
        help="map the keyframes only: do not count the non-keyframes' detections as "
        "sightings towards confirmation (a glance is enough: MappingEngine.sight, which the "
        "server does)",
    )
    parser.add_argument(
        "--upstream",
        default="frames",
        choices=("frames", "sightings"),
        help="what the device sends between keyframes: every frame whole (any v1 client), or "
        "the sightings extension's coarse sightings (the upstream target)",
    )
    parser.add_argument(
        "--queries",
        metavar="FILE",
        help='JSON {"category": ["phrase", ...]} replacing the built-in paraphrases',
    )
    parser.add_argument(
        "--caps",
        default="1000,4000,8000",
        help="extra max_object_points_server values to map in semanticxr mode, side by side "
        "with the two organisations (quality/speed trade-off of the cap; empty for none)",
    )
    parser.add_argument(
        "--no-full-depth-baseline",
        dest="full_depth_baseline",
        action="store_false",
        help="skip the extra baseline that gets depth at full resolution (÷1), i.e. the "
        "device-cloud system without SemanticXR's depth co-design",
    )
    args = parser.parse_args(argv)

    from app.config import Knobs
    from app.semantics import get_text_encoder
    from evaluation.walk import (
        IN_VIEW_MIN_FRAMES,
        EvalConfig,
        format_label_ceiling,
        load_queries,
        run_eval,
    )

    try:
        queries = load_queries(args.queries) if args.queries else None
    except ValueError as exc:
        parser.error(f"--queries {exc}")
    cfg = EvalConfig(
        scene=args.scene,
        seed=args.seed,
        frames=args.frames,
        noise=args.noise,
        queries=queries,
        sightings=args.sightings,
        upstream=args.upstream,
    )
    caps = [int(c) for c in args.caps.split(",") if c.strip()]
    variants = {f"cap {cap}": ("semanticxr", Knobs(max_object_points_server=cap)) for cap in caps}
    if args.full_depth_baseline:
        variants[FULL_DEPTH_BASELINE] = ("baseline", Knobs(depth_downsampling_ratio=1))
    result = run_eval(cfg, get_text_encoder(), keep_latencies=True, variants=variants)
    sx, bl = result["modes"]["semanticxr"], result["modes"]["baseline"]
    print(
        f"mapping on {args.scene}: {result['keyframes']} keyframes, 640x480, depth ÷5, noise {args.noise}"
    )
    rows = [(cfg.knobs.max_object_points_server, sx)]
    rows += [(cap, result["variants"][f"cap {cap}"]) for cap in caps]
    sweep = [
        {
            "cap": cap,
            "F_mIoU": m["F_mIoU"],
            "gap": bl["F_mIoU"] - m["F_mIoU"],
            "p50_ms": m["latency_ms"]["p50"],
            "mean_ms": m["latency_ms"]["mean"],
            "speedup_p50": bl["latency_ms"]["p50"] / m["latency_ms"]["p50"],
            "speedup_mean": bl["latency_ms"]["mean"] / m["latency_ms"]["mean"],
        }
        for cap, m in sorted(rows, key=lambda row: row[0])
    ]
    sx_lat, bl_lat = sx["latency_ms"], bl["latency_ms"]
    glance = sorted(
        name
        for name, n in result["frames_in_view"].items()
        if IN_VIEW_MIN_FRAMES <= n <= GLANCE_MAX_FRAMES
    )
    glance_mapped = [name for name in glance if name in sx["categories_mapped"]]
    targets = [
        check(
            "1. query top-1 over observed categories (semanticxr)",
            sx["query_top1_observed"],
            ">=",
            85.0,
            " %",
        ),
        check(
            "1. query top-1 observed, semanticxr - baseline",
            sx["query_top1_observed"] - bl["query_top1_observed"],
            ">=",
            0.0,
            " pts",
        ),
        check(
            "2. F-mIoU gap (baseline - semanticxr)", bl["F_mIoU"] - sx["F_mIoU"], "<=", 1.0, " pts"
        ),
        check(
            "3. mean latency ratio (baseline / semanticxr)",
            bl_lat["mean"] / max(sx_lat["mean"], 1e-9),
            ">=",
            3.0,
            "x",
        ),
        check("3. semanticxr p95 / p50", sx_lat["p95"] / max(sx_lat["p50"], 1e-9), "<=", 3.0, "x"),
        check(
            f"4. glance categories mapped (in view {IN_VIEW_MIN_FRAMES}-{GLANCE_MAX_FRAMES} "
            f"frames: {len(glance)})",
            100.0 * len(glance_mapped) / len(glance) if glance else 100.0,
            ">=",
            100.0,
            " %",
        ),
    ]
    print("  side by side:            semanticxr    baseline")
    for label, key in (
        ("query top-1 observed %", "query_top1_observed"),
        ("query top-1 (all) %", "query_top1"),
        ("mAcc", "mAcc"),
        ("F-mIoU", "F_mIoU"),
        ("objects", "objects"),
    ):
        print(f"    {label:22s} {sx[key]:10.1f} {bl[key]:11.1f}")
    for stat in ("p50", "p95", "mean"):
        print(f"    latency {stat:4s} ms        {sx_lat[stat]:10.1f} {bl_lat[stat]:11.1f}")
    print(
        f"    mapping total s        {sx['mapping_total_ms'] / 1e3:10.1f} "
        f"{bl['mapping_total_ms'] / 1e3:11.1f}"
    )
    print(f"  {format_label_ceiling(result['label_ceiling'])}")
    print(
        f"  not in view ({len(result['unobserved_categories'])}): "
        f"{', '.join(result['unobserved_categories']) or 'none'}"
    )
    print(
        f"  glance categories: {', '.join(glance) or 'none'}; mapped: {', '.join(glance_mapped) or 'none'}"
    )
    print("  query top-1 per observed category (frames in view): semanticxr / baseline %")
    for name, n in sorted(result["frames_in_view"].items()):
        if n >= IN_VIEW_MIN_FRAMES and name in sx["query_top1_per_category"]:
            print(
                f"    {name:18s} {n:5d}  {sx['query_top1_per_category'][name]:5.0f} / "
                f"{bl['query_top1_per_category'][name]:5.0f}"
            )
    print("  per-stage p50 / mean in ms, semanticxr vs baseline:")
    for stage, sx_ms in sx["stages_ms"].items():
        bl_ms = bl["stages_ms"][stage]
        print(
            f"    {stage:10s} {sx_ms['p50']:6.2f} / {sx_ms['mean']:6.2f}   "
            f"{bl_ms['p50']:6.2f} / {bl_ms['mean']:6.2f}"
        )
    full = result.get("variants", {}).get(FULL_DEPTH_BASELINE)
    if full is not None:
        speedup = full["latency_ms"]["p50"] / sx["latency_ms"]["p50"]
        print(
            f"  not a target: against a baseline fed full-resolution depth (÷1, no depth "
            f"co-design): p50 {full['latency_ms']['p50']:.1f} ms, F-mIoU {full['F_mIoU']:.2f}; "
            f"semanticxr is {speedup:.2f}x faster at p50"
        )
    print(
        f"  point cap sweep, all mapped side by side (baseline F-mIoU {bl['F_mIoU']:.2f}, "
        f"p50 {bl['latency_ms']['p50']:.1f} ms, mean {bl['latency_ms']['mean']:.1f} ms):"
    )
    for row in sweep:
        print(
            f"    cap {row['cap']:6d}: F-mIoU {row['F_mIoU']:.2f} (gap {row['gap']:+.2f}), "
            f"p50 {row['p50_ms']:.1f} ms ({row['speedup_p50']:.2f}x), "
            f"mean {row['mean_ms']:.1f} ms ({row['speedup_mean']:.2f}x)"
        )
    document = {
        "bench": "mapping",
        "machine": machine(),
        "targets": targets,
        "eval": result,
        "cap_sweep": sweep,
    }
    write_outputs(args.out, "mapping", document)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.5))
    for mode, style in (("baseline", "tab:red"), ("semanticxr", "tab:blue")):
        ax.plot(result["modes"][mode]["latencies_ms"], color=style, label=mode, lw=1)
    ax.set_xlabel("keyframe")
    ax.set_ylabel("mapping latency (ms)")
    ax.set_title(
        f"{args.scene}: mean {sx_lat['mean']:.1f} vs {bl_lat['mean']:.1f} ms, "
        f"semanticxr p95/p50 {sx_lat['p95'] / max(sx_lat['p50'], 1e-9):.1f}"
    )
    ax.legend()
    save_plot(fig, args.out, "mapping")
    return 0 if all(t["ok"] for t in targets) else 1


if __name__ == "__main__":
    raise SystemExit(main())
