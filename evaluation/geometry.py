"""The geometry scenario (`semanticxr eval --scenario geometry`): are the map's boxes and
points the size and shape of the things they stand for?

The walk scenario (evaluation/walk.py) maps a synthetic scene; its semantic figures (F-mIoU,
over every ground-truth point and over the points some keyframe saw, and query top-1) are
kept in the same document so that no geometry gain hides a semantic loss.
Each organisation's map is then scored against the truth (docs/evaluation.md "Geometry"):

- truth: each scene object's surface as the walk's keyframes saw it (every keyframe
  rendered without noise and back-projected at full resolution, de-duplicated at
  TRUTH_VOXEL_M), and the box of that seen surface;
- each confirmed map object stands for the scene object most of its points lie on (nearest
  seen true surface within MATCH_RADIUS_M); one that lies mostly on background or nowhere
  is counted apart (`unmatched`);
- per object: box IoU against the seen surface's box, extent ratio (largest per-axis ratio
  of box sides, map / truth), volume ratio, and the fraction of its points within
  NEAR_SURFACE_M of its own thing's seen surface;
- in three states of the map: `walk` (as the walk left it), `settled` (after
  `MappingEngine.settle`, what the server does when a stream closes) and `device` (the
  client-capped copy of the settled map a device holds, `client_points`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from app.config import MODES, Knobs
from app.mapping.engine import MappingEngine
from app.mapping.geometry import EMPTY_POINTS, backproject, voxel_downsample
from app.mapping.publish import client_points
from app.semantics import TextEncoder
from client_sim.sources.synthetic import SyntheticSource
from evaluation.pipeline import Progress, stderr_progress
from evaluation.report import Report
from evaluation.walk import EvalConfig, run_eval, walk_keyframes, walk_source
from world.scene import Scene

TRUTH_VOXEL_M = 0.01
"""The seen true surface is kept one point per centimetre voxel."""
MATCH_RADIUS_M = 0.05
"""A map point lies on a thing when its nearest seen true surface point is this close."""
NEAR_SURFACE_M = 0.03
"""A map point is on its thing's surface within this distance."""
MIN_SIDE_M = 0.02
"""Box sides are taken at least this long (about their centre) for IoU and volume: a flat
thing (a picture, a rug) still has a volume, and depth noise on it is not a blow-up."""
SMALL_EXTENT_M = 0.3
"""A small thing: the largest side of its seen surface's box is under this."""
OVERSIZE_VOLUME_RATIO = 2.0
"""A box over this many times its thing's true volume is counted as oversize."""
STATES: tuple[str, ...] = ("walk", "settled", "device")


@dataclass
class GeometryConfig:
    scene: str = "apartment"
    """Synthetic scene name (world.scene.SCENE_NAMES)."""
    seed: int = 0
    """Scene, trajectory and noise seed."""
    frames: int = 400
    """Input frames of the walk."""
    width: int = 640
    height: int = 480
    noise: str = "standard"
    """Detection noise profile (world.noise.NOISE_PROFILES)."""
    modes: tuple[str, ...] = MODES
    knobs: Knobs = field(default_factory=Knobs)
    sightings: bool = True
    """Hand the engines the non-keyframes' detections as sightings (as the walk does)."""


@dataclass
class SeenTruth:
    """The scene's surfaces as the walk's keyframes saw them.

    points:       float32 [N, 3] world metres, one per TRUTH_VOXEL_M voxel per instance
    instance_ids: int32 [N] the scene instance of each point
    """

    points: np.ndarray
    instance_ids: np.ndarray

    def of(self, instance_id: int) -> np.ndarray:
        return self.points[self.instance_ids == instance_id]


def seen_truth(scene: Scene, source: SyntheticSource, keyframes: list[int]) -> SeenTruth:
    """Every keyframe rendered without noise, each pixel back-projected with its true depth
    and labelled with the instance it shows (full resolution)."""
    camera = source.camera
    u, v = np.meshgrid(np.arange(camera.width), np.arange(camera.height))
    by_instance: dict[int, list[np.ndarray]] = {}
    for index in keyframes:
        pose = source.poses[index]
        view = source.renderer.render(pose, camera)
        hit = (view.depth_m > 0) & (view.instance_ids > 0)
        points = backproject(u[hit], v[hit], view.depth_m[hit], camera.intrinsics, pose)
        ids = view.instance_ids[hit]
        for iid in np.unique(ids):
            by_instance.setdefault(int(iid), []).append(points[ids == iid])
    points, ids = [EMPTY_POINTS], [np.zeros(0, np.int32)]
    for iid, parts in sorted(by_instance.items()):
        kept = voxel_downsample(np.concatenate(parts), TRUTH_VOXEL_M)
        points.append(kept)
        ids.append(np.full(len(kept), iid, np.int32))
    return SeenTruth(np.concatenate(points), np.concatenate(ids))


def _box(points: np.ndarray) -> np.ndarray:
    """[x0, y0, z0, x1, y1, z1] of points [N >= 1, 3], each side at least MIN_SIDE_M."""
    lo, hi = points.min(axis=0).astype(np.float64), points.max(axis=0).astype(np.float64)
    grow = np.maximum(MIN_SIDE_M - (hi - lo), 0.0) / 2
    return np.concatenate([lo - grow, hi + grow])


def _volume(box: np.ndarray) -> float:
    return float(np.prod(box[3:] - box[:3]))


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    inter = np.prod(np.clip(np.minimum(a[3:], b[3:]) - np.maximum(a[:3], b[:3]), 0, None))
    return float(inter / (_volume(a) + _volume(b) - inter))


def score_object(points: np.ndarray, truth_points: np.ndarray) -> dict:
    """The figures of one map object's points [N >= 1, 3] against its thing's seen surface
    [M >= 1, 3]: box IoU, extent ratio, volume ratio, fraction within NEAR_SURFACE_M."""
    box, true_box = _box(points), _box(truth_points)
    sides, true_sides = box[3:] - box[:3], true_box[3:] - true_box[:3]
    distance, _ = cKDTree(truth_points).query(points, k=1)
    return {
        "box_iou": _iou(box, true_box),
        "extent_ratio": float((sides / true_sides).max()),
        "volume_ratio": _volume(box) / _volume(true_box),
        "near_surface": float(np.mean(distance <= NEAR_SURFACE_M)),
        "points": len(points),
    }


def _summary(rows: list[dict]) -> dict:
    """Medians and counts over scored objects."""
    if not rows:
        return {"objects": 0}
    return {
        "objects": len(rows),
        "median_box_iou": float(np.median([r["box_iou"] for r in rows])),
        "median_extent_ratio": float(np.median([r["extent_ratio"] for r in rows])),
        "median_volume_ratio": float(np.median([r["volume_ratio"] for r in rows])),
        "median_near_surface": float(np.median([r["near_surface"] for r in rows])),
        "near_surface_pooled": float(
            sum(r["near_surface"] * r["points"] for r in rows) / sum(r["points"] for r in rows)
        ),
        "oversize": sum(r["volume_ratio"] > OVERSIZE_VOLUME_RATIO for r in rows),
        "max_volume_ratio": float(max(r["volume_ratio"] for r in rows)),
    }


def score_geometry(
    clouds: dict[int, np.ndarray], truth: SeenTruth, scene: Scene
) -> dict[str, object]:
    """Score map objects' clouds {object id: float32 [N, 3]} against the seen truth: per
    object, per category, small things apart, and the summary over all."""
    tree = cKDTree(truth.points)
    rows: list[dict] = []
    unmatched = []
    for oid, points in sorted(clouds.items()):
        if len(points) == 0:
            continue
        distance, nearest = tree.query(points, k=1, distance_upper_bound=MATCH_RADIUS_M)
        on = np.isfinite(distance)
        instances = truth.instance_ids[nearest[on]]
        if len(instances) == 0:
            unmatched.append(oid)
            continue
        values, counts = np.unique(instances, return_counts=True)
        instance = int(values[counts.argmax()])
        thing = scene.object_by_id(instance)
        if thing.is_background or counts.max() < 0.5 * len(points):
            unmatched.append(oid)
            continue
        true_points = truth.of(instance)
        true_box = _box(true_points)
        row = score_object(points, true_points)
        row |= {
            "id": oid,
            "instance": instance,
            "category": thing.category,
            "small": bool((true_box[3:] - true_box[:3]).max() < SMALL_EXTENT_M),
        }
        rows.append(row)
    categories = sorted({r["category"] for r in rows})
    return {
        "all": _summary(rows),
        "small": _summary([r for r in rows if r["small"]]),
        "per_category": {c: _summary([r for r in rows if r["category"] == c]) for c in categories},
        "unmatched": len(unmatched),
        "objects": rows,
    }


def _clouds(engine: MappingEngine, state: str) -> dict[int, np.ndarray]:
    """The confirmed objects' clouds in a state of the map (`STATES`)."""
    objects = engine.confirmed_objects()
    if state != "device":
        return {o.id: o.points for o in objects}
    cap = (
        None if engine.organisation.whole_map_downstream else engine.knobs.max_object_points_client
    )
    return {o.id: client_points(o, cap) for o in objects}


def run_geometry(
    cfg: GeometryConfig, encoder: TextEncoder, progress: Progress = stderr_progress
) -> dict:
    """Map the walk (`run_eval`, semantic figures kept), settle each map, score the
    geometry of each state; the `eval --scenario geometry --json` document."""
    walk_cfg = EvalConfig(
        scene=cfg.scene,
        seed=cfg.seed,
        frames=cfg.frames,
        width=cfg.width,
        height=cfg.height,
        noise=cfg.noise,
        modes=cfg.modes,
        knobs=cfg.knobs,
        sightings=cfg.sightings,
    )
    engines: dict[str, MappingEngine] = {}
    walk = run_eval(walk_cfg, encoder, progress, engines_out=engines)
    source = walk_source(walk_cfg)
    keyframes = walk_keyframes(walk_cfg)
    truth = seen_truth(source.scene, source, keyframes)
    progress(f"[geometry] seen truth: {len(truth.points)} points over {len(keyframes)} keyframes")
    result: dict = {
        "scene": cfg.scene,
        "seed": cfg.seed,
        "frames": cfg.frames,
        "keyframes": len(keyframes),
        "noise": cfg.noise,
        "max_object_points_client": cfg.knobs.max_object_points_client,
        "modes": {},
    }
    for mode, engine in engines.items():
        scored: dict = {
            "semantic": {
                key: walk["modes"][mode][key]
                for key in (
                    "F_mIoU",
                    "F_mIoU_seen",
                    "mAcc",
                    "mAcc_seen",
                    "gt_points_seen",
                    "gt_points",
                    "query_top1",
                    "query_top1_observed",
                    "objects",
                )
            }
        }
        scored["walk"] = score_geometry(_clouds(engine, "walk"), truth, source.scene)
        engine.settle()
        scored["settled"] = score_geometry(_clouds(engine, "settled"), truth, source.scene)
        scored["device"] = score_geometry(_clouds(engine, "device"), truth, source.scene)
        result["modes"][mode] = scored
        for state in STATES:
            s = scored[state]["all"]
            progress(
                f"[geometry] {mode} {state}: median box IoU {s.get('median_box_iou', 0):.2f}, "
                f"oversize {s.get('oversize', 0)}/{s['objects']}"
            )
    return result


def run(cfg: GeometryConfig, encoder: TextEncoder, progress: Progress = stderr_progress) -> Report:
    """The geometry scenario (`run_geometry`) as a `Report`: its document and table."""
    return Report("geometry", run_geometry(cfg, encoder, progress), format_geometry_table)


def format_geometry_table(result: dict) -> str:
    """The stdout table of `semanticxr eval --scenario geometry`: a row per organisation
    and state of the map, small things apart, then the semantic figures of the same run."""
    lines = [
        f"scene {result['scene']} (seed {result['seed']}): {result['keyframes']} keyframes of "
        f"{result['frames']} frames, noise {result['noise']}; device copy capped at "
        f"{result['max_object_points_client']} points",
        f"{'mode':<11} {'state':<8} {'objects':>7} {'IoU p50':>8} {'small IoU':>9} "
        f"{'vol p50':>8} {'>2x vol':>8} {'max vol':>9} {'<=3cm':>7}",
    ]
    for mode, m in result["modes"].items():
        for state in STATES:
            a, s = m[state]["all"], m[state]["small"]
            if not a["objects"]:
                lines.append(f"{mode:<11} {state:<8} {0:7d}")
                continue
            lines.append(
                f"{mode:<11} {state:<8} {a['objects']:7d} {a['median_box_iou']:8.2f} "
                f"{s.get('median_box_iou', float('nan')):9.2f} "
                f"{a['median_volume_ratio']:8.2f} {a['oversize']:8d} "
                f"{a['max_volume_ratio']:9.1f} {100 * a['near_surface_pooled']:6.1f}%"
            )
    for mode, m in result["modes"].items():
        sem = m["semantic"]
        lines.append(
            f"{mode}: F-mIoU {sem['F_mIoU']:.1f} (seen surfaces {sem['F_mIoU_seen']:.1f}), "
            f"mAcc {sem['mAcc']:.1f} (seen {sem['mAcc_seen']:.1f}), query top-1 "
            f"{sem['query_top1']:.1f}% ({sem['query_top1_observed']:.1f}% observed)"
        )
    return "\n".join(lines)
