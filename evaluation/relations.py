"""`semanticxr eval --scenario relations`: questions about how things stand, asked of a map.

For each seed, a relation room (`world.relation_scenes`: duplicates of a category
in distinct relations) is walked round and mapped in process as `semanticxr eval` does it
(render, encode, decode, map; the frames between keyframes as sightings; semanticxr mode),
the device's local map following the engine's update messages. Then every question of the
generated set (`world.relation_queries`: relational, "what is on ...", negatives
and the categories' plain paraphrases, each with its ground truth from the scene's geometry)
is asked three ways:

- of the map as the server answers it (`Session.relational_query`): the grammar reads the
  question; a relational reading is answered by `app.answering.ask` over the
  confirmed objects and a `RelationIndex` of the points a device holds of them
  (`held_points` of the client-capped points), up as the session infers it, the asker at the
  walk's last camera, `match` by `relational.is_match`; anything else (or an anchor the map
  cannot ground) by today's ranking, rated by `app.answering.relevance`;
- of the device's local map (`LocalMap.relational_query`, LQ), compared with the server's
  answer (LQ = SQ: the same top-1, relation kind, anchors and match, degrees within 0.02);
- of a perfect map of the room (one object per instance, labelled with its category, its
  visible surface as points): what the relation code makes of the question with nothing
  lost in mapping, so a failure can be put down to the map or to the question's reading.

Each map object's identity is the ground-truth instance most of its points lie on. A
relational top-1 is right when its identity is the question's answer ("what is on the desk":
any thing on it); a plain one when its identity's category is the one asked for; a negative
when `match` is false. Failures are told apart by why: the grammar read another relation
(parse), the answer or an anchor is not in the map, an anchor phrase grounded to no
confident object (fallback to the plain ranking), the top-1 is a piece of the anchor itself
(the anchor split into several map objects), the top-1 is of another category (target
grounding), the answer was weighed against the wrong anchor (anchor grounding), the target
phrase rates the answer's label below confident (weakly grounded), the map holds only part
of the answer or its anchor (partial geometry) or points well outside the thing (stray
points: the floor round it, through dilated masks), both only when the perfect map answers
right, or the geometry rated it lower (relation degree).

The relation index is brought up to date after every keyframe with the objects it changed
(as the server's is on a query: by object version) and timed: the update and computing every
stale pair (`settle`), so the time is an upper bound of what a keyframe costs the index.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from app.answering.ask import ask
from app.answering.label_knowledge import SERVED_LABEL_TEXTS, served_texts
from app.answering.relevance import CONFIDENT, rate_hits
from app.answering.things import MapThing, RelationalHit, is_match
from app.config import Knobs
from app.keyframes import is_keyframe
from app.mapping.engine import MappingEngine, make_perception
from app.mapping.geometry import cap_points
from app.mapping.held import held_points
from app.mapping.places import DEFAULT_UP, UpInference, up_vector
from app.mapping.publish import MIN_CAP_RESOLUTION_M, client_points, update_message
from app.protocol import parse_frame
from app.protocol.delta import SEQ_FIELD
from app.relations.bodies import Z_UP
from app.relations.grammar import Reading, is_relational, parse
from app.relations.index import ObjectGeometry, RelationIndex
from app.semantics import TextEncoder
from client_sim.encoder import FrameEncoder, session_encoder_options
from client_sim.local_map import LocalMap
from client_sim.sources.synthetic import SyntheticSource
from evaluation.pipeline import Progress, Sighting, stderr_progress
from evaluation.relations_summary import (
    POSITIVE_FAMILIES,
    format_relations_table,
    pct,
    share,
    summarize,
)
from evaluation.report import Report
from world.categories import CATEGORIES
from world.gt import gt_point_cloud
from world.relation_queries import (
    Question,
    named,
    plain_questions,
    relational_questions,
)
from world.relation_scenes import make_relation_scene, relation_walk
from world.render import default_camera

ANSWER_K = 5
"""Hits per answer (the REST query's default k); `match` of a plain answer is over them."""
IDENTITY_RADIUS_M = 0.05
"""Map points farther than this from every ground-truth point vote for no instance."""
GRAMMAR_KIND = {"closest_to": "closest"}
"""A question kind the grammar names otherwise (a superlative from an anchor)."""
SUPERLATIVE_KINDS = frozenset({"closest", "farthest", "biggest", "smallest", "highest", "lowest"})


@dataclass
class RelationsConfig:
    seeds: tuple[int, ...] = (0, 1, 2)
    """One relation room per seed (scene, walk, detection noise and questions); pooled."""
    frames: int = 300
    """Frames of each walk round the room at 30 fps; every `knobs.keyframe_interval`-th is
    mapped, the others are sightings."""
    width: int = 640
    height: int = 480
    noise: str = "standard"
    """Detection noise profile: none | standard."""
    knobs: Knobs = field(default_factory=Knobs)
    phrasings: int = 3
    """Phrasings per ground truth (relation_queries.relational_questions)."""


@dataclass
class _Answer:
    """One question's answer as the server gives it."""

    relational: bool
    """Answered by the relation path (else by today's ranking)."""
    top_id: int | None
    match: bool
    hits: list[RelationalHit] | None = None
    """The relation path's whole ranking (every confirmed object), best first."""


@dataclass
class _Mapped:
    """A mapped walk and what answering questions of it needs."""

    engine: MappingEngine
    index: RelationIndex
    local_map: LocalMap
    viewer: np.ndarray
    """Where the asker stands: the walk's last camera, world metres."""
    up_inference: UpInference = field(default_factory=UpInference)
    """The session's up (`Session.up`): inferred from the keyframes' poses once settled."""
    index_ms: list[float] = field(default_factory=list)
    """Per keyframe that changed an object: update + settle."""
    update_ms: list[float] = field(default_factory=list)
    """Per such keyframe: the update alone (the stale pairs computed when read)."""
    changed: list[int] = field(default_factory=list)
    """Per such keyframe: how many objects changed."""
    keyframes: int = 0

    @property
    def up(self) -> np.ndarray:
        return up_vector(self.up_inference.settled or DEFAULT_UP)


def run_relations(
    cfg: RelationsConfig, encoder: TextEncoder, progress: Progress = stderr_progress
) -> dict:
    """The `eval --scenario relations` document (see docs/evaluation.md "Machine-readable outputs")."""
    started = time.perf_counter()
    records: list[dict] = []
    per_seed = []
    index_ms: list[float] = []
    update_ms: list[float] = []
    changed: list[int] = []
    keyframes = 0
    objects_at_end = []
    for seed in cfg.seeds:
        scene = make_relation_scene(seed)
        progress(f"[relations] seed {seed}: walking and mapping {cfg.frames} frames")
        mapped = _map_walk(cfg, scene, seed, encoder, progress)
        index_ms += mapped.index_ms
        update_ms += mapped.update_ms
        changed += mapped.changed
        keyframes += mapped.keyframes
        gt = gt_point_cloud(scene)
        identity = _identities(mapped.engine, gt)
        max_points = cfg.knobs.max_object_points_client
        view = _engine_view(mapped, identity, max_points)
        perfect = _perfect_view(scene, gt, encoder, mapped.viewer, max_points)
        questions = relational_questions(scene, mapped.viewer, seed, cfg.phrasings)
        questions += plain_questions(scene)
        category_of = {o.instance_id: o.category for o in scene.objects}
        bboxes = {o.instance_id: o.bbox for o in scene.objects}
        seed_records = [
            _score(q, view, perfect, encoder, category_of, bboxes, seed) for q in questions
        ]
        records += seed_records
        objects_at_end.append(len(mapped.engine.confirmed_objects()))
        mapped_ids = set(identity.values())
        per_seed.append(
            {
                "seed": seed,
                "things": sum(not o.is_background for o in scene.objects),
                "things_mapped": len(mapped_ids - {0}),
                "objects": objects_at_end[-1],
                "questions": len(questions),
                "top1": share(r["right"] for r in seed_records if r["family"] in POSITIVE_FAMILIES),
                "top1_perfect_map": share(
                    r["perfect_map_right"] for r in seed_records if r["family"] in POSITIVE_FAMILIES
                ),
            }
        )
        progress(
            f"[relations] seed {seed}: {per_seed[-1]['objects']} objects, "
            f"{per_seed[-1]['things_mapped']}/{per_seed[-1]['things']} things mapped, "
            f"{len(questions)} questions, relational top-1{pct(per_seed[-1]['top1'])}"
        )
    return {
        "scenario": "relations",
        "scene": "relations",
        "seeds": list(cfg.seeds),
        "frames": cfg.frames,
        "keyframes": keyframes,
        "noise": cfg.noise,
        "resolution": [cfg.width, cfg.height],
        "per_seed": per_seed,
        "relations": summarize(records, index_ms, update_ms, changed, objects_at_end),
        "wall_s": time.perf_counter() - started,
    }


# --- mapping -----------------------------------------------------------------------------------


def _map_walk(
    cfg: RelationsConfig, scene, seed: int, encoder: TextEncoder, progress: Progress
) -> _Mapped:
    """Walk round the room, map it (keyframes and sightings) and keep the relation index and
    the device's local map up to date keyframe by keyframe."""
    source = SyntheticSource(
        scene,
        n_frames=cfg.frames,
        camera=default_camera(cfg.width, cfg.height),
        noise=cfg.noise,
        seed=seed,
    )
    source.poses = relation_walk(scene, cfg.frames, seed)
    knobs = cfg.knobs
    ratio = knobs.depth_downsampling_ratio
    device = FrameEncoder(ratio, **session_encoder_options(knobs))
    engine = MappingEngine(encoder, knobs, "semanticxr", backend=make_perception(mode="semanticxr"))
    local_map = LocalMap(dim=encoder.dim, max_points_per_object=knobs.max_object_points_client)
    mapped = _Mapped(engine, RelationIndex(Z_UP), local_map, source.poses[-1][:3, 3].copy())
    published = 0
    for index in range(cfg.frames):
        frame = source.frame(index)
        if not is_keyframe(index, knobs.keyframe_interval):
            engine.sight(*Sighting.of(frame, {ratio: device}).decode(engine, ratio))
            continue
        message = device.encode_source_frame(frame).message
        stats = engine.integrate(parse_frame(message, engine.backend.needs_rgb))
        mapped.keyframes += 1
        mapped.up_inference.observe(frame.pose)
        if stats.keyframe % knobs.local_map_update_frequency == 0:
            published = _publish(engine, local_map, published)
        _update_index(mapped, knobs.max_object_points_client)
        if mapped.keyframes % 20 == 0:
            progress(
                f"[relations] seed {seed}: mapped {mapped.keyframes} keyframes, "
                f"{len(engine.confirmed_objects())} objects"
            )
    _publish(engine, local_map, published)  # what the last keyframes changed (the flush)
    return mapped


def _publish(engine: MappingEngine, local_map: LocalMap, since: int) -> int:
    """Hand the device the engine's update since `since`; the new seq."""
    update = update_message(engine, since, served_texts)
    local_map.apply_delta(update)
    return update[SEQ_FIELD]


def _update_index(mapped: _Mapped, max_points: int) -> None:
    """Bring the relation index up to the confirmed objects (`RelationIndex.sync`, as the
    server does on a query) and time what the index costs: the sync and settling every stale
    pair, without preparing the changed objects' held points (the map's work)."""
    objects = [(o, o.version) for o in mapped.engine.confirmed_objects()]
    preparing_s = 0.0

    def held(o) -> ObjectGeometry:
        nonlocal preparing_s
        started = time.perf_counter()
        geometry = ObjectGeometry(o.label, held_points(client_points(o, max_points)))
        preparing_s += time.perf_counter() - started
        return geometry

    t0 = time.perf_counter()
    changed = mapped.index.sync(objects, mapped.up, held)
    if not changed:
        return
    t1 = time.perf_counter()
    mapped.index.settle()
    t2 = time.perf_counter()
    mapped.update_ms.append((t1 - t0 - preparing_s) * 1e3)
    mapped.index_ms.append((t2 - t0 - preparing_s) * 1e3)
    mapped.changed.append(changed)


def _identities(engine: MappingEngine, gt) -> dict[int, int]:
    """Map object id -> the ground-truth instance most of its points lie on (0: none)."""
    tree = cKDTree(gt.points)
    out: dict[int, int] = {}
    for obj in engine.confirmed_objects():
        dist, nearest = tree.query(obj.points, distance_upper_bound=IDENTITY_RADIUS_M)
        votes = gt.instance_ids[nearest[dist < np.inf]]
        out[obj.id] = int(np.bincount(votes).argmax()) if len(votes) else 0
    return out


# --- asking ------------------------------------------------------------------------------------


@dataclass
class _MapView:
    """A map as a question sees it: the things, their relation index, where the asker
    stands, today's ranking, and which ground-truth instance each thing is."""

    things: list[MapThing]
    index: RelationIndex
    viewer: np.ndarray
    rank: Callable[[np.ndarray, int], list[MapThing]]
    """Today's ranking: query embedding float [dim], k -> the top-k things, best first."""
    identity: dict[int, int]
    """Thing id -> ground-truth instance (0: none)."""
    points: dict[int, np.ndarray]
    """Thing id -> its points as the relation index holds them (float32 [N, 3])."""
    local_map: LocalMap | None = None
    """The device's local map of the same map (LQ), if any."""
    up: np.ndarray = field(default_factory=lambda: Z_UP.copy())
    """The session's up, which the device is told."""


def _engine_view(mapped: _Mapped, identity: dict[int, int], max_points: int) -> _MapView:
    """The mapped walk as the server answers from it (`Session.relational_query`)."""
    objects = mapped.engine.confirmed_objects()
    by_id = {o.id: MapThing(o.id, o.label, o.embedding) for o in objects}

    def rank(embedding: np.ndarray, k: int) -> list[MapThing]:
        return [by_id[h.object.id] for h in mapped.engine.query_embedding(embedding, k)]

    return _MapView(
        list(by_id.values()),
        mapped.index,
        mapped.viewer,
        rank,
        identity,
        {o.id: held_points(client_points(o, max_points)) for o in objects},
        mapped.local_map,
        mapped.up,
    )


def _perfect_view(scene, gt, encoder: TextEncoder, viewer: np.ndarray, max_points: int) -> _MapView:
    """A perfect map of the scene: one thing per ground-truth instance, labelled with its
    category, its embedding the category's text, its points the instance's visible surface
    capped as the device's are. What the relation code makes of the questions with nothing
    lost in mapping."""
    things, points = [], {}
    for obj in scene.objects:
        if obj.is_background:
            continue
        mine = gt.points[gt.instance_ids == obj.instance_id]
        if not len(mine):
            continue
        points[obj.instance_id] = held_points(cap_points(mine, max_points, MIN_CAP_RESOLUTION_M)[0])
        embedding = encoder.encode_labels([obj.category])[0]
        things.append(MapThing(obj.instance_id, obj.category, embedding))
    index = RelationIndex(Z_UP)
    index.update({t.id: ObjectGeometry(t.label, points[t.id]) for t in things})
    matrix = np.stack([t.embedding for t in things]).astype(np.float32)

    def rank(embedding: np.ndarray, k: int) -> list[MapThing]:
        order = np.argsort(-(matrix @ embedding.astype(np.float32)), kind="stable")[:k]
        return [things[i] for i in order]

    return _MapView(things, index, viewer, rank, {t.id: t.id for t in things}, points)


def _ask(text: str, view: _MapView, encoder: TextEncoder) -> _Answer:
    """The server's answer (`Session.relational_query`, else `Session.rated_query`)."""
    k = max(len(view.things), 1)  # the whole ranking, to tell why an answer lost
    hits = ask(text, view.things, view.index, encoder, view.viewer, k, SERVED_LABEL_TEXTS)
    if hits is not None:
        return _Answer(True, hits[0].id if hits else None, is_match(hits[:ANSWER_K]), hits)
    return _plain(text, view, encoder)


def _plain(text: str, view: _MapView, encoder: TextEncoder) -> _Answer:
    """Today's ranking and its rating (the plain path, whatever the question says)."""
    embedding = encoder.encode_query(text)
    hits = view.rank(embedding, ANSWER_K)
    rating = rate_hits(encoder, embedding, [h.label for h in hits], SERVED_LABEL_TEXTS)
    return _Answer(False, hits[0].id if hits else None, rating.match)


def _right(q: Question, got: _Answer, view: _MapView, category_of: dict[int, str]) -> bool:
    instance = view.identity.get(got.top_id, 0) if got.top_id is not None else 0
    if q.family == "plain":
        return category_of.get(instance) == q.category
    if q.family == "negative":
        return not got.match
    return instance in q.acceptable


def _score(
    q: Question,
    view: _MapView,
    perfect: _MapView,
    encoder: TextEncoder,
    category_of: dict[int, str],
    bboxes: dict[int, np.ndarray],
    seed: int,
) -> dict:
    """One question asked of the map (and of a perfect map) and judged: right or not,
    match, and why it failed."""
    got = _ask(q.text, view, encoder)
    perfect_got = _ask(q.text, perfect, encoder)
    got_instance = view.identity.get(got.top_id, 0) if got.top_id is not None else 0
    record = {
        "seed": seed,
        "question": q.text,
        "family": q.family,
        "kind": q.kind,
        "wording": _wording(q),
        "relational_path": got.relational,
        "match": got.match,
        "right": _right(q, got, view, category_of),
        "perfect_map_right": _right(q, perfect_got, perfect, category_of),
        "expected": _names(q.expected, category_of) if q.family != "plain" else q.category,
        "got": _described(got_instance, got.top_id, view, category_of),
    }
    if q.family == "plain":
        plain = _plain(q.text, view, encoder)
        record["plain_path_right"] = _right(q, plain, view, category_of)
        record["same_as_plain_path"] = plain.top_id == got.top_id
    elif view.local_map is not None:
        same, same_up_to_ties, detail = _lq_equals_sq(q.text, got, view, encoder)
        record["lq_equals_sq"], record["lq_up_to_ties"], record["lq_detail"] = (
            same,
            same_up_to_ties,
            detail,
        )
    if not record["right"]:
        reason, detail = _why(q, got, view, category_of, bboxes, record["perfect_map_right"])
        record["reason"], record["detail"] = reason, detail
    if not record["perfect_map_right"]:
        reason, detail = _why(q, perfect_got, perfect, category_of, bboxes, False)
        record["perfect_map_reason"], record["perfect_map_detail"] = reason, detail
    return record


LQ_DEGREE_TOLERANCE = 0.02
"""LQ = SQ: degrees may differ by this much (docs/evaluation.md "Relations")."""


def _lq_equals_sq(
    text: str, sq: _Answer, view: _MapView, encoder: TextEncoder
) -> tuple[bool, bool, str]:
    """Whether the device's local map answers a question as the server does: the same
    top-1, relation kind, anchors and match, degrees within LQ_DEGREE_TOLERANCE (both plain
    counts as the same); whether it does up to exact ties (LQ's top-1 is one of the objects
    tied with SQ's at its score: same-label copies whose cosines differ only in float noise,
    which the device's 8-bit embeddings do not keep); and how they differ."""
    assert view.local_map is not None
    lq = view.local_map.relational_query(text, encoder, view.viewer, view.up, ANSWER_K)
    if sq.hits is None or lq is None:
        if (sq.hits is None) == (lq is None):
            return True, True, ""
        detail = "SQ answered as plain, LQ relational" if lq else "LQ answered as plain"
        return False, False, detail
    if not sq.hits or not lq:
        same = not sq.hits and not lq
        return same, same, "no hits on one side"
    a, b = sq.hits[0], lq[0]
    tied = {h.id: h for h in sq.hits if h.score == a.score}
    if b.id in tied:  # compare LQ with SQ's hit for the same object
        tie_differences = _differences(tied[b.id], b, sq.hits, lq)
    else:
        tie_differences = ["a top-1 outside SQ's tied best"]
    differences = _differences(a, b, sq.hits, lq)
    return not differences, not tie_differences, "; ".join(differences)


def _differences(a: RelationalHit, b: RelationalHit, sq_hits, lq_hits) -> list[str]:
    """How LQ's hit `b` differs from SQ's `a` (LQ = SQ's terms)."""
    differences = []
    if a.id != b.id:
        differences.append(f"top-1 {a.id} (score {a.score:.3f}) vs {b.id} ({b.score:.3f})")
    if a.relation.kind != b.relation.kind:
        differences.append(f"kind {a.relation.kind} vs {b.relation.kind}")
    if [i for i, _ in a.relation.anchors] != [i for i, _ in b.relation.anchors]:
        differences.append(f"anchors {a.relation.anchors} vs {b.relation.anchors}")
    if is_match(sq_hits) != is_match(lq_hits):
        differences.append(f"match {is_match(sq_hits)} vs {is_match(lq_hits)}")
    if abs(a.relation.degree - b.relation.degree) > LQ_DEGREE_TOLERANCE:
        differences.append(f"degree {a.relation.degree:.3f} vs {b.relation.degree:.3f}")
    return differences


def _wording(q: Question) -> str:
    """Whether a question names its target and anchors by their categories' own names (the
    labels a perfect map carries) or by other names ("cup", "bag", "side table")."""
    phrases = [q.target, *q.anchor_phrases] if q.target else list(q.anchor_phrases)
    return "category names" if all(p in CATEGORIES for p in phrases) else "other names"


def _names(ids, category_of) -> str:
    return ", ".join(f"{category_of[i]}#{i}" for i in ids) or "nothing"


def _described(instance: int, thing_id: int | None, view: _MapView, category_of) -> str:
    if thing_id is None:
        return "no object"
    label = next((t.label for t in view.things if t.id == thing_id), "?")
    truth = f"{category_of[instance]}#{instance}" if instance else "no instance"
    return f"{truth} (object {thing_id} '{label}')"


def _why(
    q: Question,
    got: _Answer,
    view: _MapView,
    category_of: dict[int, str],
    bboxes: dict[int, np.ndarray],
    perfect_right: bool,
) -> tuple[str, str]:
    """(reason, detail) a question failed; the reasons in the module docstring."""
    if q.family == "plain":
        return "plain ranking", ""
    identity = view.identity
    parse_problem = _parse_problem(q, parse(q.text))
    if parse_problem:
        return "parse", parse_problem
    if not got.relational:
        return "fallback to plain", "an anchor phrase grounded to no confident object"
    hits = got.hits or []
    top = hits[0]
    if top.score > 0 and identity.get(top.id, 0) in q.anchors:  # the anchor, mapped twice
        return "anchor split in the map", _hit_detail(top, view, category_of, bboxes)
    if q.family == "negative":
        detail = _hit_detail(top, view, category_of, bboxes)
        fault, what = _geometry_faults(top, view, bboxes)
        if perfect_right and fault:
            return fault, f"{what}; {detail}"
        return f"{top.relation.kind} degree", detail
    by_instance: dict[int, list[int]] = {}
    for thing_id, instance in identity.items():
        by_instance.setdefault(instance, []).append(thing_id)
    if not any(i in by_instance for i in q.acceptable):
        return "answer not in the map", f"no map object is {_names(q.expected, category_of)}"
    if q.anchors and not any(a in by_instance for a in q.anchors):
        return "anchor not in the map", f"no map object is {_names(q.anchors, category_of)}"
    best = next(h for h in hits if identity.get(h.id, 0) in q.acceptable)
    detail = f"answer: {_hit_detail(best, view, category_of, bboxes)}; top-1: " + _hit_detail(
        top, view, category_of, bboxes
    )
    if q.target and best.relevance < CONFIDENT and best.score <= top.score:
        # a superlative weighs only confident targets; any score is relevance x degree
        return "target phrase weakly grounded", detail
    wrong_category = category_of.get(identity.get(top.id, 0)) not in named(q.target, loose=True)
    if q.target and wrong_category and best.score > 0:  # else the answer stands in nothing
        return "target grounding", detail
    anchors = {identity.get(a, 0) for a, _ in best.relation.anchors}
    top_anchors = {identity.get(a, 0) for a, _ in top.relation.anchors}
    if q.anchors and not anchors & set(q.anchors):
        return "anchor grounding", detail
    if q.anchors and top.score > best.score and not top_anchors & set(q.anchors):
        return "anchor grounding", detail  # another anchor reading outweighs the right one
    fault, what = _geometry_faults(best, view, bboxes)
    if not fault:
        fault, what = _geometry_faults(top, view, bboxes)
    if perfect_right and fault:
        return fault, f"{what}; {detail}"
    if best.relevance < top.relevance - 1e-9:
        return "target relevance", detail
    return f"{q.kind} degree", detail


PARTIAL_BOTTOM_M = 0.05
"""A map object whose lowest point is this far above its instance's bottom misses its base."""
PARTIAL_HEIGHT_SHARE = 0.7
"""...or one spanning less than this share of its instance's height misses part of it."""


def _partial(thing_id: int, view: _MapView, bboxes: dict[int, np.ndarray]) -> str:
    """What a map object misses of its ground-truth instance ("" if it looks whole)."""
    instance = view.identity.get(thing_id, 0)
    points = view.points.get(thing_id)
    if not instance or points is None or not len(points):
        return ""
    box = bboxes[instance]
    lo, hi = float(points[:, 2].min()), float(points[:, 2].max())
    height = max(box[5] - box[2], 1e-6)
    if lo - box[2] > PARTIAL_BOTTOM_M:
        return f"object {thing_id} starts {lo - box[2]:.2f} m above its bottom"
    if (min(hi, box[5]) - max(lo, box[2])) / height < PARTIAL_HEIGHT_SHARE:
        return f"object {thing_id} spans {(hi - lo) / height:.0%} of its height"
    return ""


STRAY_M = 0.3
"""A map object holding a point this far outside its instance's box carries stray points
(the floor round it through dilated masks, another thing's edge): closest-point relations
(near, next to, closest) read them."""


def _stray(thing_id: int, view: _MapView, bboxes: dict[int, np.ndarray]) -> str:
    """How far a map object reaches beyond its ground-truth instance ("" if it does not)."""
    instance = view.identity.get(thing_id, 0)
    points = view.points.get(thing_id)
    if not instance or points is None or not len(points):
        return ""
    box = bboxes[instance]
    outside = np.linalg.norm(np.maximum(np.maximum(box[:3] - points, points - box[3:]), 0), axis=1)
    far = outside > STRAY_M
    if not far.any():
        return ""
    return (
        f"object {thing_id} reaches {outside.max():.2f} m beyond its instance "
        f"({far.sum()} of {len(points)} points over {STRAY_M} m out)"
    )


def _geometry_faults(hit: RelationalHit, view: _MapView, bboxes) -> tuple[str, str]:
    """(reason, what) of the first fault of the hit's or its anchors' geometry in the map:
    stray points or missing parts; ("", "") when they look like their instances."""
    for thing_id in [hit.id, *(a for a, _ in hit.relation.anchors)]:
        stray = _stray(thing_id, view, bboxes)
        if stray:
            return "stray points in the map", stray
        partial = _partial(thing_id, view, bboxes)
        if partial:
            return "partial geometry in the map", partial
    return "", ""


def _parse_problem(q: Question, reading: Reading) -> str:
    """What the grammar read otherwise than the question means ("" if nothing)."""
    if not is_relational(reading):
        return "read as a plain question"
    kind = GRAMMAR_KIND.get(q.kind, q.kind)
    if kind in SUPERLATIVE_KINDS:
        sup = reading.superlative
        if sup is None or sup.kind != kind or reading.relations:
            return f"read as {_reading_text(reading)}"
        if len(sup.anchors) != len(q.anchor_phrases):
            return f"read as {_reading_text(reading)}"
        return ""
    clauses = reading.relations
    if len(clauses) != 1 or clauses[0].kind != kind or reading.superlative is not None:
        return f"read as {_reading_text(reading)}"
    expected_anchors = 2 if kind == "between" else 1
    if len(clauses[0].anchors) != expected_anchors:
        return f"read as {_reading_text(reading)}"
    return ""


def _reading_text(reading: Reading) -> str:
    parts = [f"target '{reading.target}'"]
    parts += [f"{c.kind} {c.anchors}" for c in reading.relations]
    if reading.superlative is not None:
        parts.append(f"{reading.superlative.kind} {reading.superlative.anchors}")
    return ", ".join(parts)


def _hit_detail(hit: RelationalHit, view: _MapView, category_of, bboxes) -> str:
    def named_instance(thing_id: int) -> str:
        instance = view.identity.get(thing_id, 0)
        return f"{category_of[instance]}#{instance}" if instance else "no instance"

    anchors = ", ".join(
        f"{label} {a} (is {named_instance(a)})" for a, label in hit.relation.anchors
    )
    return (
        f"object {hit.id} '{hit.label}' (is {named_instance(hit.id)}) score {hit.score:.2f} "
        f"relevance {hit.relevance:.2f} {hit.relation.kind} {hit.relation.degree:.2f}"
        + (f" to {anchors}" if anchors else "")
    )


def run(cfg: RelationsConfig, encoder: TextEncoder, progress: Progress = stderr_progress) -> Report:
    """The relations scenario (`run_relations`) as a `Report`: its document and table."""
    return Report("relations", run_relations(cfg, encoder, progress), format_relations_table)
