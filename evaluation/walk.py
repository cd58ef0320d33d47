"""The walk scenario (`semanticxr eval`, `--scenario walk`): the full pipeline in process,
scored against the synthetic ground truth.

world -> device encoder (JPEG, depth ÷ratio, detections) -> server decode -> mapping engine
-> map, once per system organisation on identical input, then semantic quality
(docs/evaluation.md "Evaluation definitions"), per-keyframe mapping latency and
paraphrase-query accuracy.

"In view": a category is in view on a frame of the walk when the noise-free detector
(noise profile "none": every visible non-background object with at least its minimum pixel
count) reports an object of that category on that frame. Every frame of the walk counts,
keyframe or not. `query_top1_observed` is the query top-1 over the categories in view for at
least IN_VIEW_MIN_FRAMES frames; the others are `unobserved_categories`.
"""

from __future__ import annotations

import bisect
import json
import time
from dataclasses import dataclass, field

import msgpack
import numpy as np

from app.config import MODES, Knobs, Mode
from app.keyframes import is_keyframe
from app.mapping.engine import MappingEngine, make_perception
from app.protocol.frame import (
    DEPTH_FIELD,
    DEPTH_PATCHES_FIELD,
    DETECTIONS_FIELD,
    LABEL_FIELD,
    RGB_FIELD,
)
from app.semantics import TextEncoder
from client_sim.encoder import FrameEncoder, session_encoder_options
from client_sim.sources.synthetic import SyntheticSource
from evaluation.pipeline import (
    Progress,
    Sighting,
    SightingMessage,
    labels_of,
    map_keyframes,
    stderr_progress,
)
from evaluation.report import Report
from evaluation.semantic_scores import assign_classes_by_text, majority_gt_class, semantic_scores
from world.categories import BACKGROUND_CLASSES, CATEGORIES
from world.gt import gt_point_cloud
from world.noise import DetectionModel
from world.render import Camera, default_camera

IN_VIEW_MIN_FRAMES = 8
"""A category counts as observed when the noise-free detector reports it on at least this
many frames of the walk (1.6 s at 5 fps)."""
SEEN_DEPTH_M = 0.02
"""A ground-truth point is seen by a keyframe when it projects into the image no more than
this far behind the true surface the keyframe's pixel shows (docs/evaluation.md "Geometry":
F-mIoU over the seen surfaces)."""
IN_VIEW_DEFINITION = (
    f"the noise-free detector reports an object of the category in at least "
    f"{IN_VIEW_MIN_FRAMES} frames of the walk (every frame counts, keyframe or not)"
)


@dataclass
class EvalConfig:
    scene: str = "apartment"
    """Synthetic scene name (world.scene.SCENE_NAMES)."""
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
    ones are the device's for these knobs (`session_encoder_options`)."""
    sightings: bool = True
    """Also hand the engines every non-keyframe's detections as sightings towards
    confirmation (`MappingEngine.sight`), as the server does with a device that sends every
    frame whole or sends sightings between its keyframes (docs/architecture.md "Rules the
    code keeps": keyframes). False: keyframes only."""
    upstream: str = "frames"
    """What the device sends between keyframes (with `sightings`): "frames", every frame
    whole (any v1 client); "sightings", the sightings extension's coarse `sighting`
    messages (app/protocol/sighting.py), parsed and validated as the server does."""
    queries: dict[str, list[str]] | None = None
    """{category: [phrase, ...]} replacing the built-in paraphrases (`load_queries`); None:
    each category's `paraphrases`. Categories of the scene missing here are not asked."""


def load_queries(path: str) -> dict[str, list[str]]:
    """A query file for `semanticxr eval --queries`: JSON `{category: [phrase, ...]}`.

    Raises ValueError with a message naming the file and what is wrong: not JSON, not an
    object, an unknown category, or a value that is not a non-empty list of non-empty
    strings."""
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
    except OSError as exc:
        raise ValueError(f"{path}: cannot read the query file ({exc.strerror or exc})") from exc
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from exc
    if not isinstance(data, dict) or not data:
        raise ValueError(
            f'{path}: expected a non-empty JSON object {{"category": ["phrase", ...]}}'
        )
    unknown = sorted(k for k in data if k not in CATEGORIES)
    if unknown:
        raise ValueError(
            f"{path}: unknown categories {unknown}; known ones: {', '.join(sorted(CATEGORIES))}"
        )
    for name, phrases in data.items():
        if (
            not isinstance(phrases, list)
            or not phrases
            or not all(isinstance(p, str) and p.strip() for p in phrases)
        ):
            raise ValueError(f"{path}: {name!r} must map to a non-empty list of non-empty strings")
    return {name: [p.strip() for p in phrases] for name, phrases in data.items()}


def _percentiles(values: list[float]) -> dict[str, float]:
    arr = np.asarray(values) if values else np.zeros(1)
    return {
        "p50": float(np.percentile(arr, 50)),
        "p95": float(np.percentile(arr, 95)),
        "mean": float(arr.mean()),
    }


def _in_view(detector: DetectionModel, view, frame_index: int) -> set[str]:
    """The categories the noise-free detector reports on one rendered view."""
    found = detector.detect(view, frame_index)
    return {inst[LABEL_FIELD] for inst in found.instances}


UPSTREAMS: tuple[str, ...] = ("frames", "sightings")


def seen_by_view(
    points: np.ndarray, depth_m: np.ndarray, pose: np.ndarray, camera: Camera
) -> np.ndarray:
    """bool [N]: which of `points` (float [N, 3] world metres) one view shows, from its true
    (noise-free, rendered) z-depth `depth_m` [H, W] (0 = no surface) at `pose` (4x4
    camera-to-world, OpenCV axes): the point lies in front of the camera, projects onto a
    pixel of the image, and lies at most SEEN_DEPTH_M behind the deepest surface the 3x3
    pixels around it show (a pixel that hits nothing hides nothing), so that a point on a
    silhouette edge or on a face seen edge-on, where depth jumps from pixel to pixel, counts.
    A point behind a wall, under a table top or outside the view is not seen."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if depth_m.shape != (camera.height, camera.width):
        raise ValueError(
            f"depth_m is {list(depth_m.shape)}, the camera's image is "
            f"[{camera.height}, {camera.width}]"
        )
    pose = np.asarray(pose, dtype=np.float64)
    local = (points - pose[:3, 3]) @ pose[:3, :3]  # world -> camera: R^T (p - t)
    z = local[:, 2]
    seen = np.zeros(len(points), bool)
    ahead = z > 1e-6
    fx, fy, cx, cy = camera.intrinsics
    u = np.rint(fx * local[ahead, 0] / z[ahead] + cx)
    v = np.rint(fy * local[ahead, 1] / z[ahead] + cy)
    inside = (u >= 0) & (u < camera.width) & (v >= 0) & (v < camera.height)
    rows = np.flatnonzero(ahead)[inside]
    deepest = np.where(depth_m > 0, depth_m, np.inf)
    deepest = np.pad(deepest, 1, mode="edge")
    deepest = np.max(
        [
            deepest[dv : dv + camera.height, du : du + camera.width]
            for dv in range(3)
            for du in range(3)
        ],
        axis=0,
    )
    surface = deepest[v[inside].astype(np.int64), u[inside].astype(np.int64)]
    seen[rows] = z[rows] <= surface + SEEN_DEPTH_M
    return seen


def walk_source(cfg: EvalConfig) -> SyntheticSource:
    """The synthetic source of the walk `cfg` describes (scene, frames, camera, noise, seed)."""
    return SyntheticSource(
        cfg.scene,
        n_frames=cfg.frames,
        camera=default_camera(cfg.width, cfg.height),
        noise=cfg.noise,
        seed=cfg.seed,
    )


def walk_keyframes(cfg: EvalConfig) -> list[int]:
    """The indices of the walk's keyframes (every `knobs.keyframe_interval`-th frame)."""
    return [index for index in range(cfg.frames) if is_keyframe(index, cfg.knobs.keyframe_interval)]


@dataclass
class SeenSurface:
    """Ground-truth points and which of them some keyframe of the walk showed
    (`seen_by_view` on each keyframe's true depth).

    points: float [N, 3] world metres; seen: bool [N], filled by `look`."""

    points: np.ndarray
    seen: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        self.seen = np.zeros(len(self.points), bool)

    def look(self, depth_m: np.ndarray, pose: np.ndarray, camera: Camera) -> None:
        """Mark the points one view shows (its noise-free depth at its pose)."""
        rest = np.flatnonzero(~self.seen)
        self.seen[rest[seen_by_view(self.points[rest], depth_m, pose, camera)]] = True


def encode_keyframes(
    cfg: EvalConfig, ratios: list[int], progress: Progress, surface: SeenSurface | None = None
) -> tuple[
    dict[int, list], object, dict, dict[str, int], dict[int, list[Sighting | SightingMessage]]
]:
    """Render the keyframes once and encode them at each depth ratio; every organisation at
    one ratio maps the same bytes. Every other frame of the walk is ray cast for the
    visibility count and, with `cfg.sightings`, its detections. `surface`, if given, is
    marked with what each keyframe's true depth shows. Returns (messages by ratio,
    scene, upstream bytes at the configured ratio, frames in view by category: see the
    module docstring, the non-keyframes by the keyframe they follow)."""
    source = walk_source(cfg)
    options = session_encoder_options(cfg.knobs, cfg.encoder_options)
    encoders = {ratio: FrameEncoder(ratio, **options) for ratio in ratios}
    messages: dict[int, list] = {ratio: [] for ratio in ratios}
    upstream = dict.fromkeys(
        (RGB_FIELD, DEPTH_FIELD, DETECTIONS_FIELD, DEPTH_PATCHES_FIELD, "total"), 0
    )  # payload bytes by message part, and the whole messages
    interval = cfg.knobs.keyframe_interval
    keyframes = walk_keyframes(cfg)
    n_keyframes = len(keyframes)
    noise_free = DetectionModel(source.scene, "none", cfg.seed)
    in_view: dict[str, int] = dict.fromkeys(source.scene.categories_present, 0)
    sightings: dict[int, list[Sighting | SightingMessage]] = {}
    """By the keyframe (its position) they follow."""
    device = encoders[cfg.knobs.depth_downsampling_ratio]
    for index in range(cfg.frames):
        if is_keyframe(index, interval):
            continue
        after = bisect.bisect_right(keyframes, index) - 1  # the keyframe it follows
        if cfg.sightings and cfg.upstream == "sightings":
            frame = source.frame(index)
            view = frame.view
            message = device.encode_source_frame_as_sighting(frame).message
            sightings.setdefault(after, []).append(
                SightingMessage(msgpack.packb(message, use_bin_type=True))
            )
        elif cfg.sightings:
            frame = source.frame(index)
            view = frame.view
            sightings.setdefault(after, []).append(Sighting.of(frame, encoders))
        else:
            view = source.renderer.render(source.poses[index], source.camera)
        for name in _in_view(noise_free, view, index):
            in_view[name] = in_view.get(name, 0) + 1
    for i, frame in enumerate(source.frame(index) for index in keyframes):
        for name in _in_view(noise_free, frame.view, frame.index):
            in_view[name] = in_view.get(name, 0) + 1
        if surface is not None:
            surface.look(frame.view.depth_m, frame.pose, source.camera)
        for ratio, encoder in encoders.items():
            encoded = encoder.encode_source_frame(frame)
            messages[ratio].append(encoded.message)
            if ratio == cfg.knobs.depth_downsampling_ratio:
                for kind in upstream:
                    upstream[kind] += encoded.bytes_by_kind.get(kind, 0)
        if (i + 1) % 20 == 0 or i + 1 == n_keyframes:
            progress(f"[eval] rendered and encoded {i + 1}/{n_keyframes} keyframes")
    return messages, source.scene, upstream, in_view, sightings


def score_map(
    engine: MappingEngine,
    gt,
    encoder: TextEncoder,
    categories: list[str],
    observed: set[str] | None = None,
    queries: dict[str, list[str]] | None = None,
    seen: np.ndarray | None = None,
) -> dict:
    """mAcc / F-mIoU of the confirmed map, and paraphrase top-1 accuracy.

    seen: bool [len(gt)], the ground-truth points some keyframe showed (`SeenSurface`);
    given, `F_mIoU_seen` and `mAcc_seen` score the map against those points only, beside
    the standard figures over every ground-truth point.

    observed: the categories in view (module docstring); query_top1_observed is over their
    queries only (None: every category). queries: phrases by category replacing the
    built-in paraphrases."""
    observed = set(categories) if observed is None else observed
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

    seen_scores = None
    if seen is not None:
        if len(seen) != len(gt.points):
            raise ValueError(f"seen has {len(seen)} entries for {len(gt.points)} GT points")
        seen_scores = semantic_scores(
            map_points,
            map_class,
            gt.points[seen],
            gt.class_idx[seen],
            class_names,
            ignore_classes=BACKGROUND_CLASSES,
        )

    true_class = majority_gt_class([o.points for o in objects], gt.points, gt.class_idx)
    by_id = {o.id: c for o, c in zip(objects, true_class, strict=True)}
    asked = correct = asked_observed = correct_observed = 0
    failures = []
    per_category: dict[str, float] = {}
    for name in categories:
        phrases = CATEGORIES[name].paraphrases if queries is None else queries.get(name, [])
        hits_here = 0
        for text in phrases:
            asked += 1
            asked_observed += name in observed
            hits = engine.query(text, k=1)
            got = (
                class_names[by_id[hits[0].object.id]]
                if hits and by_id[hits[0].object.id] >= 0
                else None
            )
            if got == name:
                correct += 1
                correct_observed += name in observed
                hits_here += 1
            else:
                failures.append({"query": text, "expected": name, "got": got})
        if phrases:
            per_category[name] = 100.0 * hits_here / len(phrases)
    seen_figures = {}
    if seen_scores is not None:
        seen_figures = {
            "mAcc_seen": seen_scores.mAcc,
            "F_mIoU_seen": seen_scores.F_mIoU,
            "gt_points_seen": int(seen.sum()),
            "gt_points": len(gt.points),
        }
    return {
        "mAcc": scores.mAcc,
        "F_mIoU": scores.F_mIoU,
        **seen_figures,
        "objects": len(objects),
        "query_top1": 100.0 * correct / max(asked, 1),
        "query_top1_observed": 100.0 * correct_observed / max(asked_observed, 1),
        "queries_asked": asked,
        "queries_asked_observed": asked_observed,
        "query_top1_per_category": per_category,
        "categories_mapped": sorted({class_names[c] for c in true_class if c >= 0}),
        "query_failures": failures,
        "per_class": scores.per_class,
    }


def label_ceiling(
    encoder: TextEncoder, names: list[str], queries: dict[str, list[str]] | None = None
) -> dict:
    """The query top-1 a perfect map would score: one object per category of `names`, each
    carrying its category's name as its only label. An object's embedding is its labels'
    text embedding, so the queries this misses are lost between label texts, where no
    mapping can win them back.

    queries: phrases by category (None: the built-in paraphrases); those of categories
    outside `names` are not asked. Returns {"query_top1_observed": %, "queries_asked",
    "query_failures": [{"query", "expected", "got"}]}."""
    names = sorted(names)
    asked = [
        (text, name)
        for name in names
        for text in (CATEGORIES[name].paraphrases if queries is None else queries.get(name, []))
    ]
    failures = []
    if names and asked:
        phrases = np.stack([encoder.encode_query(text) for text, _ in asked])  # as a map query
        best = (phrases @ encoder.encode(names).T).argmax(1)
        failures = [
            {"query": text, "expected": name, "got": names[k]}
            for (text, name), k in zip(asked, best, strict=True)
            if names[k] != name
        ]
    return {
        "query_top1_observed": 100.0 * (len(asked) - len(failures)) / max(len(asked), 1),
        "queries_asked": len(asked),
        "query_failures": failures,
    }


def run_eval(
    cfg: EvalConfig,
    encoder: TextEncoder,
    progress: Progress = stderr_progress,
    keep_latencies: bool = False,
    variants: dict[str, tuple[Mode, Knobs]] | None = None,
    engines_out: dict[str, MappingEngine] | None = None,
) -> dict:
    """Run the pipeline for each mode in `cfg.modes`; the `eval --json` document
    (docs/evaluation.md "Machine-readable outputs").

    variants: extra engines by name, (mode, knobs) each (say, another point cap, or the
    baseline at another depth ratio: keyframes are encoded at each ratio the engines use),
    mapped in the same interleaved loop and reported under "variants".
    engines_out: filled with the engines by name as the walk left them (for a scenario that
    scores their maps further: evaluation/geometry.py).
    """
    if cfg.upstream not in UPSTREAMS:
        raise ValueError(f"upstream must be one of {', '.join(UPSTREAMS)}, got {cfg.upstream!r}")
    variants = variants or {}
    clash = variants.keys() & set(cfg.modes)
    if clash:
        raise ValueError(f"variant names must differ from the modes, got {sorted(clash)}")
    started = time.perf_counter()
    knobs_of = {mode: (mode, cfg.knobs) for mode in cfg.modes} | variants
    ratio = cfg.knobs.depth_downsampling_ratio
    ratios = sorted({ratio, *(knobs.depth_downsampling_ratio for _, knobs in knobs_of.values())})
    gt = gt_point_cloud(walk_source(cfg).scene)
    surface = SeenSurface(gt.points)
    by_ratio, scene, upstream, in_view, sightings = encode_keyframes(cfg, ratios, progress, surface)
    n_keyframes = len(by_ratio[ratio])
    categories = scene.categories_present
    observed = {name for name in categories if in_view.get(name, 0) >= IN_VIEW_MIN_FRAMES}
    # Label embeddings are computed once per process and cached (a long-running server has
    # them all): warm the cache with every label the keyframes carry, outside the timed loop.
    encoder.encode([*gt.class_names, *labels_of(by_ratio[ratio])])

    result: dict = {
        "scene": cfg.scene,
        "seed": cfg.seed,
        "frames": cfg.frames,
        "keyframes": n_keyframes,
        "noise": cfg.noise,
        "resolution": [cfg.width, cfg.height],
        "depth_downsampling_ratio": cfg.knobs.depth_downsampling_ratio,
        "upstream_bytes_per_keyframe": {k: v / max(n_keyframes, 1) for k, v in upstream.items()},
        "queries": "built-in paraphrases" if cfg.queries is None else "file",
        "sightings": cfg.sightings,
        "upstream": cfg.upstream,
        "in_view_definition": IN_VIEW_DEFINITION,
        "frames_in_view": {name: in_view.get(name, 0) for name in categories},
        "unobserved_categories": sorted(set(categories) - observed),
        "label_ceiling": label_ceiling(encoder, sorted(observed), cfg.queries),
        "modes": {},
    }
    engines = {
        name: MappingEngine(encoder, knobs, mode, backend=make_perception(mode=mode))
        for name, (mode, knobs) in knobs_of.items()
    }
    mapped = map_keyframes(
        {name: by_ratio[knobs.depth_downsampling_ratio] for name, (_, knobs) in knobs_of.items()},
        engines,
        progress,
        sightings,
        {name: knobs.depth_downsampling_ratio for name, (_, knobs) in knobs_of.items()},
    )
    if engines_out is not None:
        engines_out.update(engines)
    if variants:
        result["variants"] = {}
    for mode, engine in engines.items():
        run = mapped[mode]
        latencies, update_bytes = run.latencies_ms, run.update_bytes
        scored = score_map(engine, gt, encoder, categories, observed, cfg.queries, surface.seen)
        scored["latency_ms"] = _percentiles(latencies)
        scored["mapping_total_ms"] = float(sum(latencies))
        scored["sightings_ms"] = _percentiles(run.sightings_ms) if run.sightings_ms else None
        scored["stages_ms"] = {stage: _percentiles(ms) for stage, ms in run.stages_ms.items()}
        scored["downstream_bytes_per_update"] = _percentiles(update_bytes) if update_bytes else None
        scored["downstream_bytes_total"] = int(sum(update_bytes))
        scored["changes_concluded"] = {
            kind: sum(c.kind == kind for c in run.standing_changes())
            for kind in ("added", "moved", "removed")
        }
        if keep_latencies:
            scored["latencies_ms"] = latencies
        result["variants" if mode in variants else "modes"][mode] = scored
        progress(
            f"[eval] {mode}: mAcc {scored['mAcc']:.1f}  F-mIoU {scored['F_mIoU']:.1f} "
            f"(seen surfaces {scored['F_mIoU_seen']:.1f})  "
            f"objects {scored['objects']}  p50 {scored['latency_ms']['p50']:.1f} ms  "
            f"query top-1 {scored['query_top1']:.1f}% "
            f"({scored['query_top1_observed']:.1f}% over observed categories)"
        )
    if {"semanticxr", "baseline"} <= result["modes"].keys():
        result["speedup_p50"] = result["modes"]["baseline"]["latency_ms"]["p50"] / max(
            result["modes"]["semanticxr"]["latency_ms"]["p50"], 1e-9
        )
    result["wall_s"] = time.perf_counter() - started
    return result


def run(
    cfg: EvalConfig,
    encoder: TextEncoder,
    progress: Progress = stderr_progress,
    keep_latencies: bool = False,
    variants: dict[str, tuple[Mode, Knobs]] | None = None,
) -> Report:
    """The walk scenario (`run_eval`) as a `Report`: its document and table."""
    return Report(
        "walk", run_eval(cfg, encoder, progress, keep_latencies, variants), format_eval_table
    )


def format_eval_table(result: dict) -> str:
    """The stdout table of `semanticxr eval` (the walk): one row per organisation."""
    lines = [
        f"scene {result['scene']}: {result['keyframes']} keyframes of {result['frames']} frames, "
        f"noise {result['noise']}",
        f"{'mode':<11} {'mAcc':>6} {'F-mIoU':>7} {'seen':>6} {'objects':>8} {'p50 ms':>7} "
        f"{'p95 ms':>7} {'mean ms':>8} {'query@1':>8} {'observed':>9}",
    ]
    for mode, m in result["modes"].items():
        lat = m["latency_ms"]
        lines.append(
            f"{mode:<11} {m['mAcc']:6.1f} {m['F_mIoU']:7.1f} {m.get('F_mIoU_seen', float('nan')):6.1f} "
            f"{m['objects']:8d} {lat['p50']:7.1f} "
            f"{lat['p95']:7.1f} {lat['mean']:8.1f} {m['query_top1']:7.1f}% "
            f"{m['query_top1_observed']:8.1f}%"
        )
    unobserved = result.get("unobserved_categories", [])
    lines.append(
        "F-mIoU over every ground-truth point; seen: over the points some keyframe showed "
        f"(true depth, {100 * SEEN_DEPTH_M:g} cm)"
    )
    lines.append(
        "query@1 over every category of the scene; observed: over those in view "
        f"(not in view: {', '.join(unobserved) or 'none'})"
    )
    if "label_ceiling" in result:
        lines.append(format_label_ceiling(result["label_ceiling"]))
    if "speedup_p50" in result:
        lines.append(f"speed-up (baseline p50 / semanticxr p50): {result['speedup_p50']:.2f}x")
    return "\n".join(lines)


def format_label_ceiling(ceiling: dict) -> str:
    """One line for the document's `label_ceiling` (as `label_ceiling` computes it)."""
    lost = ", ".join(f"{f['expected']} -> {f['got']}" for f in ceiling["query_failures"])
    return (
        f"label-text ceiling: {ceiling['query_top1_observed']:.1f}% of the observed queries "
        "for a perfect map (one object per category in view, labelled with its name)"
        + (f"; lost between labels: {lost}" if lost else "")
    )
