"""`semanticxr eval`: the full pipeline in process, scored against the synthetic ground truth.

world -> device encoder (JPEG, depth ÷ratio, detections) -> server decode -> mapping engine
-> map, once per system organisation on identical input, then semantic quality (DESIGN.md
"Evaluation definitions"), per-keyframe mapping latency and paraphrase-query accuracy.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import msgpack
import numpy as np

from app.config import MODES, Knobs, Mode
from app.mapping.engine import MappingEngine
from app.mapping.evaluation import assign_classes_by_text, majority_gt_class, semantic_scores
from app.mapping.publish import update_message
from app.protocol import parse_frame
from app.semantics import TextEncoder
from client_sim.encoder import FrameEncoder
from client_sim.sources.synthetic import SyntheticSource
from client_sim.world.categories import BACKGROUND_CLASSES, CATEGORIES
from client_sim.world.gt import gt_point_cloud
from client_sim.world.render import default_camera

Progress = Callable[[str], None]


def _stderr(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


@dataclass
class EvalConfig:
    scene: str = "apartment"
    """Synthetic scene name (client_sim.world.scene.SCENE_NAMES)."""
    seed: int = 0
    """Scene, trajectory and noise seed."""
    frames: int = 400
    """Input frames of the walk; every `knobs.keyframe_interval`-th one is mapped."""
    width: int = 640
    height: int = 480
    noise: str = "standard"
    """Detection noise profile: none | standard."""
    modes: tuple[str, ...] = MODES
    knobs: Knobs = field(default_factory=Knobs)
    encoder_options: dict = field(default_factory=dict)
    """FrameEncoder options besides the depth ratio (which comes from the knobs); unset
    ones keep the device's defaults."""


def _percentiles(values: list[float]) -> dict[str, float]:
    arr = np.asarray(values) if values else np.zeros(1)
    return {
        "p50": float(np.percentile(arr, 50)),
        "p95": float(np.percentile(arr, 95)),
        "mean": float(arr.mean()),
    }


def _encode_keyframes(
    cfg: EvalConfig, ratios: list[int], progress: Progress
) -> tuple[dict[int, list], object, dict]:
    """Render the keyframes once and encode them at each depth ratio; every organisation at
    one ratio maps the same bytes. Returns (messages by ratio, scene, upstream bytes at the
    configured ratio)."""
    source = SyntheticSource(
        cfg.scene,
        n_frames=cfg.frames,
        camera=default_camera(cfg.width, cfg.height),
        noise=cfg.noise,
        seed=cfg.seed,
    )
    encoders = {ratio: FrameEncoder(ratio, **cfg.encoder_options) for ratio in ratios}
    messages: dict[int, list] = {ratio: [] for ratio in ratios}
    upstream = {"rgb": 0, "depth": 0, "detections": 0, "total": 0}
    interval = cfg.knobs.keyframe_interval
    n_keyframes = len(range(0, cfg.frames, interval))
    for i, frame in enumerate(source.frames(every=interval)):
        for ratio, encoder in encoders.items():
            encoded = encoder.encode_source_frame(frame)
            messages[ratio].append(encoded.message)
            if ratio == cfg.knobs.depth_downsampling_ratio:
                for kind in upstream:
                    upstream[kind] += encoded.bytes_by_kind.get(kind, 0)
        if (i + 1) % 20 == 0 or i + 1 == n_keyframes:
            progress(f"[eval] rendered and encoded {i + 1}/{n_keyframes} keyframes")
    return messages, source.scene, upstream


def _labels_of(messages: list[dict]) -> list[str]:
    """The distinct detection labels in encoded frames, in first-seen order."""
    labels = (
        inst["label"]
        for message in messages
        for inst in message.get("detections", {}).get("instances", [])
    )
    return list(dict.fromkeys(labels))


@dataclass
class MappedRun:
    """What mapping the keyframes cost one engine."""

    latencies_ms: list[float] = field(default_factory=list)
    """Per keyframe: decode + mapping + the downstream update."""
    update_bytes: list[int] = field(default_factory=list)
    """Size of each downstream update."""
    stages_ms: dict[str, list[float]] = field(default_factory=dict)
    """Per keyframe, by stage: "decode", the engine's own stages (IntegrationStats.timings_ms
    but its "total") and "update" (0 on keyframes without one)."""

    def add_stage(self, stage: str, ms: float) -> None:
        self.stages_ms.setdefault(stage, []).append(ms)


def map_keyframes(
    messages: dict[str, list[dict]], engines: dict[str, MappingEngine], progress: Progress
) -> dict[str, MappedRun]:
    """Feed each engine its wire messages through decode + mapping + the downstream update
    (DESIGN.md "Mapping latency"). The engines take turns keyframe by keyframe, so a change
    in machine load during the run affects every organisation alike."""
    n_keyframes = len(next(iter(messages.values()), []))
    runs = {name: MappedRun() for name in engines}
    published = dict.fromkeys(engines, 0)
    for i in range(n_keyframes):
        for name, engine in engines.items():
            run = runs[name]
            t0 = time.perf_counter()
            frame = parse_frame(messages[name][i], engine.backend.needs_rgb)
            t1 = time.perf_counter()
            stats = engine.integrate(frame)
            t2 = time.perf_counter()
            if stats.keyframe % engine.knobs.local_map_update_frequency == 0:
                update = update_message(engine, published[name])
                run.update_bytes.append(len(msgpack.packb(update)))
                published[name] = update["seq"]
            t3 = time.perf_counter()
            run.latencies_ms.append((t3 - t0) * 1e3)
            run.add_stage("decode", (t1 - t0) * 1e3)
            for stage, ms in stats.timings_ms.items():
                if stage != "total":
                    run.add_stage(stage, ms)
            run.add_stage("update", (t3 - t2) * 1e3)
        if (i + 1) % 20 == 0 or i + 1 == n_keyframes:
            progress(
                f"[eval] mapped {i + 1}/{n_keyframes} keyframes: "
                + ", ".join(
                    f"{name} p50 {np.median(runs[name].latencies_ms):.1f} ms" for name in engines
                )
            )
    return runs


def score_map(engine: MappingEngine, gt, encoder: TextEncoder, categories: list[str]) -> dict:
    """mAcc / F-mIoU of the confirmed map, and paraphrase top-1 accuracy."""
    objects = engine.confirmed_objects()
    class_names = gt.class_names
    if objects:
        class_text = encoder.encode(class_names)
        object_class = assign_classes_by_text(np.stack([o.embedding for o in objects]), class_text)
        map_points = np.concatenate([o.points for o in objects])
        map_class = np.repeat(object_class, [len(o.points) for o in objects])
    else:
        map_points, map_class = np.zeros((0, 3), np.float32), np.zeros(0, int)
    scores = semantic_scores(
        map_points,
        map_class,
        gt.points,
        gt.class_idx,
        class_names,
        ignore_classes=BACKGROUND_CLASSES,
    )

    true_class = majority_gt_class([o.points for o in objects], gt.points, gt.class_idx)
    by_id = {o.id: c for o, c in zip(objects, true_class, strict=True)}
    asked = correct = 0
    failures = []
    for name in categories:
        for text in CATEGORIES[name].paraphrases:
            asked += 1
            hits = engine.query(text, k=1)
            got = (
                class_names[by_id[hits[0].object.id]]
                if hits and by_id[hits[0].object.id] >= 0
                else None
            )
            if got == name:
                correct += 1
            else:
                failures.append({"query": text, "expected": name, "got": got})
    return {
        "mAcc": scores.mAcc,
        "F_mIoU": scores.F_mIoU,
        "objects": len(objects),
        "query_top1": 100.0 * correct / max(asked, 1),
        "query_failures": failures,
        "per_class": scores.per_class,
    }


def run_eval(
    cfg: EvalConfig,
    encoder: TextEncoder,
    progress: Progress = _stderr,
    keep_latencies: bool = False,
    variants: dict[str, tuple[Mode, Knobs]] | None = None,
) -> dict:
    """Run the pipeline for each mode in `cfg.modes`; the DESIGN.md `eval --json` document.

    variants: extra engines by name, (mode, knobs) each (say, another point cap, or the
    baseline at another depth ratio: keyframes are encoded at each ratio the engines use),
    mapped in the same interleaved loop and reported under "variants".
    """
    variants = variants or {}
    clash = variants.keys() & set(cfg.modes)
    if clash:
        raise ValueError(f"variant names must differ from the modes, got {sorted(clash)}")
    started = time.perf_counter()
    knobs_of = {mode: (mode, cfg.knobs) for mode in cfg.modes} | variants
    ratio = cfg.knobs.depth_downsampling_ratio
    ratios = sorted({ratio, *(knobs.depth_downsampling_ratio for _, knobs in knobs_of.values())})
    by_ratio, scene, upstream = _encode_keyframes(cfg, ratios, progress)
    n_keyframes = len(by_ratio[ratio])
    gt = gt_point_cloud(scene)
    categories = scene.categories_present
    # Label embeddings are computed once per process and cached (a long-running server has
    # them all): warm the cache with every label the keyframes carry, outside the timed loop.
    encoder.encode([*gt.class_names, *_labels_of(by_ratio[ratio])])

    result: dict = {
        "scene": cfg.scene,
        "seed": cfg.seed,
        "frames": cfg.frames,
        "keyframes": n_keyframes,
        "noise": cfg.noise,
        "resolution": [cfg.width, cfg.height],
        "depth_downsampling_ratio": cfg.knobs.depth_downsampling_ratio,
        "upstream_bytes_per_keyframe": {k: v / max(n_keyframes, 1) for k, v in upstream.items()},
        "modes": {},
    }
    engines = {
        name: MappingEngine(encoder, knobs, mode) for name, (mode, knobs) in knobs_of.items()
    }
    mapped = map_keyframes(
        {name: by_ratio[knobs.depth_downsampling_ratio] for name, (_, knobs) in knobs_of.items()},
        engines,
        progress,
    )
    if variants:
        result["variants"] = {}
    for mode, engine in engines.items():
        run = mapped[mode]
        latencies, update_bytes = run.latencies_ms, run.update_bytes
        scored = score_map(engine, gt, encoder, categories)
        scored["latency_ms"] = _percentiles(latencies)
        scored["stages_ms"] = {stage: _percentiles(ms) for stage, ms in run.stages_ms.items()}
        scored["downstream_bytes_per_update"] = _percentiles(update_bytes) if update_bytes else None
        scored["downstream_bytes_total"] = int(sum(update_bytes))
        if keep_latencies:
            scored["latencies_ms"] = latencies
        result["variants" if mode in variants else "modes"][mode] = scored
        progress(
            f"[eval] {mode}: mAcc {scored['mAcc']:.1f}  F-mIoU {scored['F_mIoU']:.1f}  "
            f"objects {scored['objects']}  p50 {scored['latency_ms']['p50']:.1f} ms  "
            f"query top-1 {scored['query_top1']:.1f}%"
        )
    if {"semanticxr", "baseline"} <= result["modes"].keys():
        result["speedup_p50"] = result["modes"]["baseline"]["latency_ms"]["p50"] / max(
            result["modes"]["semanticxr"]["latency_ms"]["p50"], 1e-9
        )
    result["wall_s"] = time.perf_counter() - started
    return result
