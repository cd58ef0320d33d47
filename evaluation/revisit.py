"""`semanticxr eval --scenario revisit`: does the map follow a changed world?

For each seed, the synthetic apartment is walked, changed by a script (things moved, taken
away, added, others hidden behind something new: `world.changes`) and walked
again along the same path ten minutes later, at 5 fps (`t` advances 0.2 s a frame). Every
organisation maps the same encoded keyframes (and the frames between them as sightings,
as the server counts them), with negative evidence on and, for the mapping cost, off.

Scoring (docs/evaluation.md "Measured honestly"; pooled over seeds, `evaluation.change_scores`):

- Each map object's identity is the ground-truth instance most of its points lie on: objects
  present after the first walk against the first scene (a moved or removed object keeps its
  id, so its change is judged by what it was), new ones against the second scene.
- A change counts when object and kind are right; `added` is scored apart.
- Time to update: from the first frame of the second walk that showed the evidence (the
  old place without the thing, the new place with it), keyframe or not, as a person watching
  the stream would count it, to the change's `t`. Beside it, the walk's bound (how long after
  that the walk's regular keyframes had shown enough for the rules to conclude: a removal
  needs `removal_min_evidence` keyframes showing the empty place) and the map's delay beyond
  that bound.
- False removals under occlusion: removed or moved changes of a hidden object.
- Stale answers: after the second walk, a query for a moved or removed thing's category
  whose top-1 is the map's object for that thing still at its old place (within
  STALE_RADIUS_M of it, and nearer it than the new place); apart, those about things whose
  old place the walk showed at least STALE_MIN_SHOWINGS times (regular keyframes, one a
  second, that showed it: the rest the walk barely glimpsed).
- Last-seen errors: "where did I last see X" for each removed thing whose category has no
  other instance left (else the question is ambiguous), ranked over present and removed
  objects (`include=removed`): the top-1's distance to where X was and its `last_seen_t`
  against the last first-walk keyframe that showed X.
- Mapping cost: mean keyframe latency with negative evidence against without, same walk.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from app.config import MODES, Knobs
from app.keyframes import is_keyframe
from app.mapping.engine import MappingEngine, make_perception
from app.mapping.object import MapObject
from app.semantics import TextEncoder
from client_sim.encoder import FrameEncoder, session_encoder_options
from client_sim.keyframe_pick import KeyframePick
from client_sim.sources.revisit import RevisitSource
from evaluation.change_scores import ConcludedChange, TrueChange, score_changes
from evaluation.pipeline import (
    MappedRun,
    Progress,
    Sighting,
    labels_of,
    map_keyframe,
    stderr_progress,
)
from evaluation.report import Report
from world.changes import DEFAULT_GAP_S, DEFAULT_WALK_FRAMES, RevisitScenario
from world.gt import gt_point_cloud
from world.render import default_camera

SEEN_PX = 400
"""A frame shows a thing (or its place) when it covers this many pixels at 640 x 480."""
PLACE_VISIBLE_FRACTION = 0.7
"""A frame shows an old place when this fraction of the pixels the first walk saw the
thing at (from the same pose) now show something at or behind where it was, within the range
negative evidence reads (`absence_min_depth_m`..`absence_max_depth_m`: farther, depth is too
coarse): the empty place itself in view, not merely in the frustum behind an occluder."""
PLACE_GRID_PX = 4
"""The first walk's pixels of a watched thing are kept on a grid of one pixel in 4 x 4 (the
fraction above, read on every frame of the walk, in bounded memory)."""
STALE_MIN_SHOWINGS = 2
"""A stale answer counts apart when the walk's regular keyframes (one a second) showed the old
place at least this many times."""
IDENTITY_RADIUS_M = 0.05
"""Map points farther than this from every ground-truth point vote for no instance."""
STALE_RADIUS_M = 0.5
NO_EVIDENCE = "_no_evidence"
"""Suffix of the engines mapped with negative evidence off (for the mapping cost)."""


@dataclass
class RevisitConfig:
    scene: str = "apartment"
    seeds: tuple[int, ...] = (0, 1, 2, 3, 4)
    walk_frames: int = DEFAULT_WALK_FRAMES
    gap_s: float = DEFAULT_GAP_S
    width: int = 640
    height: int = 480
    noise: str = "standard"
    modes: tuple[str, ...] = tuple(MODES)
    knobs: Knobs = field(default_factory=Knobs)
    sightings: bool = True
    """Hand the frames between keyframes to `sight`, as the server does."""
    doubt_keyframes: bool = True
    """The device also makes a keyframe of a frame showing a place the map doubts
    (`client_sim.keyframe_pick`, from the newest keyframe's doubted places); else only the
    shared selector's keyframes."""


@dataclass
class _Walks:
    """One seed's encoded walks and what the ground truth needs from the renders."""

    scenario: RevisitScenario
    old_place_shown_t: dict[int, list[float]] = field(default_factory=dict)
    """Instance -> t of every walk-2 regular keyframe (`is_keyframe`) showing its old place
    without it."""
    new_place_seen_t: dict[int, float] = field(default_factory=dict)
    """Instance -> t of the first walk-2 regular keyframe showing it (at its new place)."""
    old_place_first_frame_t: dict[int, float] = field(default_factory=dict)
    """Instance -> t of the first walk-2 frame (any) showing its old place without it."""
    new_place_first_frame_t: dict[int, float] = field(default_factory=dict)
    """Instance -> t of the first walk-2 frame (any) showing it at its new place."""
    last_seen_walk1_t: dict[int, float] = field(default_factory=dict)
    """Instance -> t of the last walk-1 keyframe showing it."""
    new_place_frames: dict[int, list[dict]] = field(default_factory=dict)
    """Instance -> the walk-2 frames showing it (SEEN_PX or more): t, keyframe, its pixels, the
    share of them its device's detector covered, the share with sensed depth."""
    old_place_frames: dict[int, list[dict]] = field(default_factory=dict)
    """Instance -> the walk-2 frames in range of its old place with some of it visible: t,
    keyframe, the share of its walk-1 pixels now showing what lies at or behind it."""


@dataclass
class _MapTrace:
    """When one engine's map doubted, first saw and confirmed its objects on walk 2 (device
    time of the keyframe), read after each keyframe: where a change's time goes."""

    doubted_t: dict[int, float] = field(default_factory=dict)
    """Object id -> first keyframe t with negative evidence standing for it."""
    depth_doubted_t: dict[int, float] = field(default_factory=dict)
    """Object id -> first keyframe t with depth evidence (seen through) standing for it."""
    first_seen: dict[int, tuple[float, str, list[float]]] = field(default_factory=dict)
    """New object id -> (t, label, centroid) of the keyframe it appeared in."""
    confirmed_t: dict[int, float] = field(default_factory=dict)
    """Object id -> t of the keyframe it was confirmed (published) at."""
    picks_t: list[float] = field(default_factory=list)
    """t of the frames the device picked for a doubted place."""

    def read(self, engine: MappingEngine, t: float, walk2: bool) -> None:
        """Note what the engine's map holds after the keyframe at `t`."""
        for oid, obj in engine.objects.items():
            if oid not in self.first_seen:
                self.first_seen[oid] = (t if walk2 else -1.0, obj.label, obj.centroid.tolist())
            if obj.confirmed and oid not in self.confirmed_t:
                self.confirmed_t[oid] = t if walk2 else -1.0
        if not walk2:
            return
        for oid, evidence in engine.changes.suspects.items():
            self.doubted_t.setdefault(oid, t)
            if any(e.kind == "depth" for e in evidence):
                self.depth_doubted_t.setdefault(oid, t)


def _walk_and_map(
    cfg: RevisitConfig,
    seed: int,
    engines: dict[str, MappingEngine],
    at_walk2: Callable[[RevisitScenario], None],
    progress: Progress,
) -> tuple[_Walks, dict[str, MappedRun], dict[str, KeyframePick]]:
    """Render both walks frame by frame, note what each frame shows of the changes (the
    ground truth's clock), and map each frame in every engine as its device would send it:
    whole when its `KeyframePick` picks it (decode + mapping + the downstream update timed,
    as `map_keyframes` does), else as a sighting. Each engine's device reads the doubted
    places of that engine's newest keyframe. `at_walk2` runs between the walks."""
    source = RevisitSource(
        cfg.scene,
        seed=seed,
        walk_frames=cfg.walk_frames,
        gap_s=cfg.gap_s,
        camera=default_camera(cfg.width, cfg.height),
        noise=cfg.noise,
    )
    scenario = source.scenario
    ratio = cfg.knobs.depth_downsampling_ratio
    encoder = FrameEncoder(ratio, **session_encoder_options(cfg.knobs))
    interval = cfg.knobs.keyframe_interval
    seen_px = SEEN_PX * cfg.width * cfg.height / (640 * 480)
    watched = {c.instance_id for c in scenario.changes} | set(scenario.occluded_ids)
    walks = _Walks(scenario)
    runs = {name: MappedRun() for name in engines}
    published = dict.fromkeys(engines, 0)
    picks = {
        name: KeyframePick(interval, cfg.knobs.absence_min_depth_m, cfg.knobs.absence_max_depth_m)
        for name in engines
    }
    traces = {name: _MapTrace() for name in engines if engines[name].knobs.negative_evidence}
    first_walk_pixels: dict[int, dict[int, tuple[np.ndarray, np.ndarray]]] = {}
    """Walk-1 frame index -> instance -> (its pixels on the PLACE_GRID_PX grid, its depth
    there)."""
    for index in range(len(scenario)):
        keyframe = is_keyframe(index, interval)
        frame = source.frame(index)
        walk = scenario.walk_of(index)
        if index == scenario.walk1_frames:
            at_walk2(scenario)
        ids_image = frame.view.instance_ids
        counts = np.bincount(ids_image.ravel(), minlength=1)
        ids = ids_image[::PLACE_GRID_PX, ::PLACE_GRID_PX].ravel()
        depth = frame.view.depth_m[::PLACE_GRID_PX, ::PLACE_GRID_PX].ravel()
        shown = [i for i in watched if i < len(counts) and counts[i] >= seen_px]
        if walk == 1:
            pixels = {}
            for instance in shown:
                where = np.flatnonzero(ids == instance)
                if len(where):
                    pixels[instance] = (where, depth[where])
                    if keyframe:
                        walks.last_seen_walk1_t[instance] = frame.t
            first_walk_pixels[index] = pixels
        else:
            same_pose = index - scenario.walk1_frames
            sources = frame.detections.sources if frame.detections is not None else {}
            detected_ids = [d for d, src in sources.items() if src in shown]
            for instance in shown:
                walks.new_place_first_frame_t.setdefault(instance, frame.t)
                if keyframe:
                    walks.new_place_seen_t.setdefault(instance, frame.t)
                mask = ids_image == instance
                dets = [d for d in detected_ids if sources[d] == instance]
                det = np.isin(frame.detections.instance_ids, dets) if dets else None
                walks.new_place_frames.setdefault(instance, []).append(
                    {
                        "t": round(frame.t, 2),
                        "keyframe": keyframe,
                        "px": int(counts[instance]),
                        "detected": 0.0 if det is None else round(float(det[mask].mean()), 2),
                        "depth": round(float((frame.depth_m[mask] > 0).mean()), 2),
                    }
                )
            for instance, (where, before) in first_walk_pixels.get(same_pose, {}).items():
                now = depth[where]
                behind = (now >= before - 0.05) & (ids[where] != instance)
                in_range = (
                    cfg.knobs.absence_min_depth_m
                    <= float(np.median(before))
                    <= cfg.knobs.absence_max_depth_m
                )
                if in_range and behind.mean() >= 0.3:
                    walks.old_place_frames.setdefault(instance, []).append(
                        {
                            "t": round(frame.t, 2),
                            "keyframe": keyframe,
                            "visible": round(float(behind.mean()), 2),
                            "px": int(len(where) * PLACE_GRID_PX * PLACE_GRID_PX),
                        }
                    )
                if in_range and behind.mean() >= PLACE_VISIBLE_FRACTION:
                    walks.old_place_first_frame_t.setdefault(instance, frame.t)
                    if keyframe:
                        walks.old_place_shown_t.setdefault(instance, []).append(frame.t)
        height, width = frame.rgb.shape[:2]
        whole = {
            name: pick.pick(
                frame.index, frame.t, frame.pose, frame.intrinsics, (width, height), frame.depth_m
            )
            for name, pick in picks.items()
        }
        message = encoder.encode_source_frame(frame).message if any(whole.values()) else None
        sighting = (
            Sighting.of(frame, {ratio: encoder})
            if cfg.sightings and not all(whole.values())
            else None
        )
        if message is not None:
            # label embeddings are cached per process (a server has them all): warm the
            # cache outside the timed mapping, as `run_eval` does
            next(iter(engines.values())).encoder.encode(labels_of([message]))
        for name, engine in engines.items():
            if whole[name]:
                map_keyframe(engine, message, runs[name], published, name)
                if name in traces:
                    traces[name].read(engine, frame.t, walk == 2)
                    if walk == 2 and not keyframe:
                        traces[name].picks_t.append(frame.t)
                if cfg.doubt_keyframes and engine.knobs.negative_evidence:
                    picks[name].doubted = engine.changes.doubted_places()
            elif sighting is not None:
                t0 = time.perf_counter()
                engine.sight(*sighting.decode(engine, ratio))  # type: ignore[arg-type]
                runs[name].sightings_ms.append((time.perf_counter() - t0) * 1e3)
        if (index + 1) % 100 == 0:
            progress(
                f"[revisit] seed {seed}: walked {index + 1}/{len(scenario)} frames; keyframes "
                + ", ".join(f"{name} {len(run.latencies_ms)}" for name, run in runs.items())
            )
    return walks, runs, picks, traces


def _timeline(
    walks: _Walks,
    change,
    trace: _MapTrace,
    before_identity: dict[int, int],
    concluded: list,
    t_walk2: float,
) -> dict:
    """Where one scripted change's time went on one engine's map (device times, walk 2 from
    `t_walk2`): the first frame that showed its evidence and how well (pixels, detector
    cover, depth cover), the first regular keyframe that did, when the map doubted the
    thing's old place, when a candidate appeared and was confirmed near its new place, and
    what the map concluded when."""
    i = change.instance_id

    def rel(t):
        return None if t is None or t < 0 else round(t - t_walk2, 2)

    mine = sorted(oid for oid, inst in before_identity.items() if inst == i)
    out: dict = {
        "instance": i,
        "kind": change.kind,
        "category": change.category,
        "t_evidence_old": rel(walks.old_place_first_frame_t.get(i)),
        "t_evidence_new": rel(walks.new_place_first_frame_t.get(i)),
        "t_keyframe_old": rel((walks.old_place_shown_t.get(i) or [None])[0]),
        "old_place_keyframes": len(walks.old_place_shown_t.get(i, [])),
        "t_keyframe_new": rel(walks.new_place_seen_t.get(i)),
        "map_ids": mine,
        "t_doubted": rel(
            min((trace.doubted_t[o] for o in mine if o in trace.doubted_t), default=None)
        ),
        "t_depth_doubted": rel(
            min(
                (trace.depth_doubted_t[o] for o in mine if o in trace.depth_doubted_t), default=None
            )
        ),
        "concluded": [
            {"id": c.id, "kind": c.kind, "t": rel(c.t)} for c in concluded if c.id in mine
        ],
        "old_place_frames": [
            {**f, "t": rel(f["t"])} for f in walks.old_place_frames.get(i, [])[:12]
        ],
        "new_place_frames": [
            {**f, "t": rel(f["t"])} for f in walks.new_place_frames.get(i, [])[:12]
        ],
    }
    if change.to_xyz is not None:
        to = np.asarray(change.to_xyz)
        out["candidates"] = [
            {
                "id": oid,
                "label": label,
                "t_first_seen": rel(t),
                "t_confirmed": rel(trace.confirmed_t.get(oid)),
                "distance_m": round(float(np.linalg.norm(np.asarray(c) - to)), 2),
            }
            for oid, (t, label, c) in sorted(trace.first_seen.items())
            if t >= 0 and float(np.linalg.norm(np.asarray(c) - to)) <= STALE_RADIUS_M
        ]
    return out


def _true_change(walks: _Walks, change, key: int, min_evidence: int) -> TrueChange:
    """A scripted change with the times its evidence was shown: the first frame (any) that
    showed it. A removal's bound is the `min_evidence`-th regular keyframe showing the empty
    place (keyframes are 1 s apart, so the span rule holds by then); a move or an addition
    can be concluded once both places were shown (a suspect old place and a new candidate
    confirmed from sightings). No evidence frame: no time (the walk never showed it)."""
    i = change.instance_id
    old = walks.old_place_shown_t.get(i, [])
    new = walks.new_place_seen_t.get(i)
    old_first = walks.old_place_first_frame_t.get(i)
    new_first = walks.new_place_first_frame_t.get(i)
    if change.kind == "removed":
        t_evidence = old_first
        t_bound = old[min_evidence - 1] if len(old) >= min_evidence else None
        if t_evidence is not None and t_bound is None:
            t_bound = old[-1] if old else t_evidence  # shown fewer times: its last showing
    elif change.kind == "added":
        t_evidence, t_bound = new_first, new
    else:
        t_evidence = None if old_first is None or new_first is None else max(old_first, new_first)
        t_bound = None if not old or new is None else max(old[0], new)
    if t_evidence is not None and t_bound is not None:
        t_bound = max(t_bound, t_evidence)
    return TrueChange(key + i, change.kind, t_evidence, t_bound)


def _identities(objects: list[MapObject], tree: cKDTree, instance_of_point: np.ndarray):
    """Object id -> the ground-truth instance most of its points lie on (0: none)."""
    out: dict[int, int] = {}
    for obj in objects:
        if not len(obj.points):
            out[obj.id] = 0
            continue
        dist, nearest = tree.query(obj.points, distance_upper_bound=IDENTITY_RADIUS_M)
        hit = dist < np.inf
        votes = instance_of_point[nearest[hit]]
        out[obj.id] = int(np.bincount(votes).argmax()) if len(votes) else 0
    return out


def _top1(
    engine: MappingEngine, encoder: TextEncoder, text: str, removed: list[MapObject]
) -> MapObject | None:
    """The best object for `text` among the present map and `removed` ones."""
    query = encoder.encode_query(text)
    hits = [(h.score, h.object) for h in engine.query_embedding(query, 1)]
    hits += [(float(o.embedding @ query), o) for o in removed]
    return max(hits, key=lambda h: h[0])[1] if hits else None


def run_revisit(
    cfg: RevisitConfig, encoder: TextEncoder, progress: Progress = stderr_progress
) -> dict:
    """The `eval --scenario revisit` document: per organisation, the changes' figures."""
    started = time.perf_counter()
    concluded: dict[str, list[ConcludedChange]] = {m: [] for m in cfg.modes}
    truth: list[TrueChange] = []
    latencies: dict[str, list[float]] = {}
    sightings_ms: dict[str, list[float]] = {}
    occluded_removals = dict.fromkeys(cfg.modes, 0)
    stale = dict.fromkeys(cfg.modes, 0)
    stale_shown_enough = dict.fromkeys(cfg.modes, 0)
    """Stale answers about things whose old place the walk showed often enough to conclude."""
    stale_cases: dict[str, list[dict]] = {m: [] for m in cfg.modes}
    stale_asked = 0
    last_seen_m: dict[str, list[float]] = {m: [] for m in cfg.modes}
    last_seen_s: dict[str, list[float]] = {m: [] for m in cfg.modes}
    per_seed = []
    doubt_keyframes: dict[str, int] = {}
    """Keyframes the devices made of frames showing a doubted place, by engine."""
    off_knobs = Knobs(**{**cfg.knobs.__dict__, "negative_evidence": False})
    on_knobs = Knobs(**{**cfg.knobs.__dict__, "negative_evidence": True})
    for seed in cfg.seeds:
        key = seed * 1_000_000  # instances of different seeds never match each other
        engines = {
            m: MappingEngine(encoder, on_knobs, m, backend=make_perception(mode=m))
            for m in cfg.modes
        }
        engines |= {
            m + NO_EVIDENCE: MappingEngine(encoder, off_knobs, m, backend=make_perception(mode=m))
            for m in cfg.modes
        }
        walk1_identity: dict[str, dict[int, int]] = {}

        def identify_walk1(scenario: RevisitScenario, engines=engines, out=walk1_identity):
            """Each map object's instance after walk 1, against the first scene."""
            gt = gt_point_cloud(scenario.before)
            tree = cKDTree(gt.points)
            for name, engine in engines.items():
                out[name] = _identities(
                    engine.confirmed_objects(), tree, gt.instance_ids.astype(np.int64)
                )

        walks, runs, picks, traces = _walk_and_map(cfg, seed, engines, identify_walk1, progress)
        scenario = walks.scenario
        after_gt = gt_point_cloud(scenario.after)
        after_tree = cKDTree(after_gt.points)
        for name in engines:
            latencies.setdefault(name, []).extend(runs[name].latencies_ms)
            sightings_ms.setdefault(name, []).extend(runs[name].sightings_ms)
            doubt_keyframes[name] = doubt_keyframes.get(name, 0) + picks[name].doubt_picks
        for change in scenario.changes:
            truth.append(_true_change(walks, change, key, cfg.knobs.removal_min_evidence))
        seed_report: dict = {"seed": seed, "changes": len(scenario.changes), "modes": {}}
        removed_truth = [c for c in scenario.changes if c.kind == "removed"]
        remaining = set(scenario.after.categories_present)
        stale_asked += sum(c.kind in ("moved", "removed") for c in scenario.changes)
        for mode in cfg.modes:
            engine = engines[mode]
            run = runs[mode].standing_changes()
            retired = runs[mode].retired
            present = engine.confirmed_objects()
            after_identity = _identities(
                present + retired, after_tree, after_gt.instance_ids.astype(np.int64)
            )
            before_identity = walk1_identity[mode]
            for change in run:
                if change.kind == "added":
                    instance = after_identity.get(change.id, 0)
                else:
                    instance = before_identity.get(change.id, 0)
                concluded[mode].append(
                    ConcludedChange(key + instance if instance else None, change.kind, change.t)
                )
                if change.kind != "added" and instance in scenario.occluded_ids:
                    occluded_removals[mode] += 1
            by_id = {o.id: o for o in present}
            for change in scenario.changes:
                if change.kind not in ("moved", "removed"):
                    continue
                top = _top1(engine, encoder, change.category, [])
                if top is None or top.id not in by_id:
                    continue
                to_old = float(np.linalg.norm(top.centroid - np.asarray(change.from_xyz)))
                to_new = (
                    np.inf
                    if change.to_xyz is None
                    else float(np.linalg.norm(top.centroid - np.asarray(change.to_xyz)))
                )
                near_old = to_old <= STALE_RADIUS_M and to_old < to_new
                # stale: the map's object for the changed thing, still at the old place
                if near_old and before_identity.get(top.id) == change.instance_id:
                    shown = len(walks.old_place_shown_t.get(change.instance_id, []))
                    stale[mode] += 1
                    stale_shown_enough[mode] += shown >= STALE_MIN_SHOWINGS
                    stale_cases[mode].append(
                        {
                            "seed": seed,
                            "asked": change.category,
                            "kind": change.kind,
                            "top1": {"id": top.id, "label": top.label},
                            "top1_was_instance": before_identity.get(top.id),
                            "old_place_shown_keyframes": shown,
                        }
                    )
            for change in removed_truth:
                if change.category in remaining:
                    continue  # another one is still there: "the last place" is ambiguous
                top = _top1(engine, encoder, f"where did I last see the {change.category}", retired)
                if top is None:
                    continue
                last_seen_m[mode].append(
                    float(np.linalg.norm(top.centroid - np.asarray(change.from_xyz)))
                )
                truth_t = walks.last_seen_walk1_t.get(change.instance_id)
                if truth_t is not None and top.last_seen_t is not None:
                    last_seen_s[mode].append(abs(top.last_seen_t - truth_t))
            seed_report["modes"][mode] = {
                kind: sum(c.kind == kind for c in run) for kind in ("added", "moved", "removed")
            }
            t_walk2 = scenario.t_of(scenario.walk1_frames)
            seed_report.setdefault("timelines", {})[mode] = [
                _timeline(walks, change, traces[mode], before_identity, run, t_walk2)
                for change in scenario.changes
                if change.kind != "added"
            ]
        per_seed.append(seed_report)
        progress(
            f"[revisit] seed {seed}: {len(scenario.changes)} scripted changes; concluded "
            + "; ".join(f"{m} {seed_report['modes'][m]}" for m in cfg.modes)
        )

    result: dict = {
        "scenario": "revisit",
        "scene": cfg.scene,
        "seeds": list(cfg.seeds),
        "walk_frames": cfg.walk_frames,
        "gap_s": cfg.gap_s,
        "fps": 5.0,
        "keyframe_interval": cfg.knobs.keyframe_interval,
        "doubt_keyframes": cfg.doubt_keyframes,
        "noise": cfg.noise,
        "scripted_changes": len(truth),
        "per_seed": per_seed,
        "modes": {},
    }
    for mode in cfg.modes:
        scores = score_changes(concluded[mode], truth)
        with_ms = float(np.mean(latencies[mode]))
        without_ms = float(np.mean(latencies[mode + NO_EVIDENCE]))
        scores["false_removals_occluded"] = occluded_removals[mode]
        scores["stale_answers"] = stale[mode]
        scores["stale_answers_shown_enough"] = stale_shown_enough[mode]
        scores["stale_questions"] = stale_asked
        scores["stale_cases"] = stale_cases[mode]
        scores["last_seen_error_m"] = {
            "p50": float(np.median(last_seen_m[mode])) if last_seen_m[mode] else None
        }
        scores["last_seen_error_s"] = {
            "p50": float(np.median(last_seen_s[mode])) if last_seen_s[mode] else None
        }
        with_total = float(np.sum(latencies[mode]))
        without_total = float(np.sum(latencies[mode + NO_EVIDENCE]))
        # the change work's cost over the same walks: its keyframes' mapping and the
        # keyframes its doubted places added
        scores["mapping_cost_pct"] = 100.0 * (with_total / without_total - 1.0)
        scores["mapping_cost_per_keyframe_pct"] = 100.0 * (with_ms / without_ms - 1.0)
        scores["latency_ms"] = {"with_evidence_mean": with_ms, "without_evidence_mean": without_ms}
        # beside it, what the change work adds to the frames between keyframes (sightings)
        on, off = sightings_ms.get(mode, []), sightings_ms.get(mode + NO_EVIDENCE, [])
        scores["sightings_ms"] = {
            "with_evidence_mean": float(np.mean(on)) if on else None,
            "without_evidence_mean": float(np.mean(off)) if off else None,
            "cost_pct": 100.0 * (sum(on) / sum(off) - 1.0) if on and sum(off) > 0 else None,
        }
        scores["keyframes"] = {
            "with_evidence": len(latencies[mode]),
            "without_evidence": len(latencies[mode + NO_EVIDENCE]),
            "doubted_place_picks": doubt_keyframes.get(mode, 0),
        }
        result["modes"][mode] = {"changes": scores}
    result["seconds"] = time.perf_counter() - started
    return result


def format_revisit_table(result: dict) -> str:
    """The revisit figures as a small table (targets from docs/evaluation.md beside them)."""
    lines = [
        f"revisit of {result['scene']}: seeds {result['seeds']}, {result['scripted_changes']} "
        f"scripted changes, walks of {result['walk_frames']} frames {result['gap_s']:g} s apart",
        f"{'mode':<11} {'prec':>5} {'(low)':>6} {'recall':>6} {'(low)':>6} {'t2u p95 s':>9} "
        f"{'walk':>5} {'beyond':>6} "
        f"{'occl':>4} {'stale':>5} {'seen m':>6} {'seen s':>6} {'cost %':>6} "
        f"{'added p/r':>10}",
    ]
    for mode, m in result["modes"].items():
        c = m["changes"]

        def fmt(value, spec=".2f"):
            return "-" if value is None else format(value, spec)

        lines.append(
            f"{mode:<11} {c['precision']:5.2f} {fmt(c['precision_wilson_low']):>6} "
            f"{c['recall']:6.2f} {fmt(c['recall_wilson_low']):>6} "
            f"{fmt(c['time_to_update_s']['p95'], '.1f'):>9} "
            f"{fmt(c['walk_bound_s']['p95'], '.1f'):>5} "
            f"{fmt(c['beyond_walk_bound_s']['p95'], '.1f'):>6} {c['false_removals_occluded']:4d} "
            f"{c['stale_answers']:2d}/{c['stale_answers_shown_enough']:<2d} "
            f"{fmt(c['last_seen_error_m']['p50']):>6} "
            f"{fmt(c['last_seen_error_s']['p50'], '.1f'):>6} {c['mapping_cost_pct']:6.1f} "
            f"{c['added']['precision']:4.2f}/{c['added']['recall']:4.2f}"
        )
    lines.append(
        "(t2u, walk, beyond: p95 of the time to update, of the walk's share of it, of the map's "
        "delay beyond the walk's bound; stale: all / about things the walk showed enough)"
    )
    lines.append(
        "targets: precision >= 0.95, recall >= 0.9, time to update p95 <= 3 s, 0 false removals "
        "under occlusion, 0 stale answers, last seen p50 <= 0.3 m, cost <= +15 %"
    )
    return "\n".join(lines)


def run(cfg: RevisitConfig, encoder: TextEncoder, progress: Progress = stderr_progress) -> Report:
    """The revisit scenario (`run_revisit`) as a `Report`: its document and table."""
    return Report("revisit", run_revisit(cfg, encoder, progress), format_revisit_table)
