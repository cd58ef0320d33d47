"""`semanticxr eval`: map a synthetic scene in process and score it (the scenarios: evaluation/)."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from app.cli.common import scene_name, write_json
from app.config import MODES
from app.flags import add_knob_flags, knobs_from_args, positive_int

DEFAULT_SEEDS = {"revisit": 5, "relations": 3}
"""--seeds by scenario."""
DEFAULT_FRAMES = {"walk": 400, "relations": 300, "geometry": 400}
"""--frames by scenario (revisit walks --walk-frames twice)."""


def noise_profile(text: str) -> str:
    """argparse type: one of the detection noise profiles (world.noise.NOISE_PROFILES)."""
    from world.noise import NOISE_PROFILES  # here: the world loads open3d

    if text not in NOISE_PROFILES:
        raise argparse.ArgumentTypeError(
            f"unknown noise profile {text!r}; valid profiles: {', '.join(NOISE_PROFILES)}"
        )
    return text


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "eval",
        help="map a synthetic scene in process and score it (mAcc, F-mIoU, latency, queries)",
        description="Run the full pipeline (render, encode, decode, map) on a synthetic scene "
        "for one or both system organisations and report semantic quality and speed.",
    )
    parser.add_argument(
        "--scene",
        default="apartment",
        type=scene_name,
        help="synthetic scene: living_room, kitchen, office, bedroom or apartment (default: %(default)s)",
    )
    parser.add_argument(
        "--scenario",
        default="walk",
        choices=("walk", "revisit", "relations", "geometry"),
        help="walk: one walk, semantic quality and speed; revisit: walk, change the room by a "
        "script, walk again 10 min later, and score how the map follows (changes, stale "
        "answers, last-seen places, the cost of negative evidence); relations: walk round "
        "rooms of same-category duplicates in distinct relations (semanticxr mode; --scene "
        "and --mode do not apply), then ask generated questions about how things stand "
        "('the mug on the desk', 'what is on the desk'), negatives and plain paraphrases, "
        "and score the answers against the rooms' geometry; geometry: the walk, then each "
        "object's box and points against the true surface the keyframes saw, as the walk "
        "left the map, settled after it and in the device's capped copy, with the walk's "
        "semantic figures (default: %(default)s)",
    )
    parser.add_argument(
        "--seed",
        type=int,
        default=0,
        help="scene, trajectory and noise seed (default: %(default)s)",
    )
    parser.add_argument(
        "--seeds",
        type=positive_int,
        default=None,
        metavar="N",
        help="revisit and relations: seeds --seed .. --seed+N-1, results pooled (default: "
        f"{DEFAULT_SEEDS['revisit']} for revisit, {DEFAULT_SEEDS['relations']} for relations)",
    )
    parser.add_argument(
        "--walk-frames",
        type=positive_int,
        default=500,
        help="revisit: frames of each of the two walks at 5 fps (default: %(default)s)",
    )
    parser.add_argument(
        "--frames",
        type=positive_int,
        default=None,
        help="input frames of the walk (default: "
        f"{DEFAULT_FRAMES['walk']}; {DEFAULT_FRAMES['relations']} per room for relations)",
    )
    parser.add_argument(
        "--width", type=positive_int, default=640, help="RGB width in pixels (default: %(default)s)"
    )
    parser.add_argument(
        "--height",
        type=positive_int,
        default=480,
        help="RGB height in pixels (default: %(default)s)",
    )
    parser.add_argument(
        "--noise",
        default="standard",
        type=noise_profile,
        help="detection noise: none, standard, or bleed (standard with masks dilated onto "
        "what lies behind and depth smeared across edges) (default: %(default)s)",
    )
    parser.add_argument(
        "--mode",
        default="both",
        choices=(*MODES, "both"),
        help="system organisation (default: %(default)s)",
    )
    parser.add_argument("--json", metavar="PATH", help="write the results as JSON here")
    parser.add_argument(
        "--no-sightings",
        dest="sightings",
        action="store_false",
        help="map the keyframes only: do not count the other frames' detections as "
        "sightings towards confirmation (MappingEngine.sight, which the server does)",
    )
    parser.add_argument(
        "--upstream",
        default="frames",
        choices=("frames", "sightings"),
        help="what the device sends between keyframes: every frame whole (any v1 client), or "
        "the sightings extension's coarse sightings (default: %(default)s)",
    )
    parser.add_argument(
        "--queries",
        metavar="FILE",
        help='JSON {"category": ["phrase", ...]} replacing the built-in paraphrases for '
        "query top-1 (categories of the scene missing from it are not asked)",
    )
    parser.add_argument(
        "--text-tower",
        choices=("minilm", "static"),
        default="minilm",
        help="the text tower labels and questions are embedded with: the packaged MiniLM, or "
        "the static tower distilled from it (default: %(default)s)",
    )
    parser.add_argument(
        "--static-tower",
        metavar="FILE",
        help="with --text-tower static: this tower file (default: the tower cache's, "
        "distilled there on first use)",
    )
    add_knob_flags(parser)
    parser.set_defaults(func=run)
    return parser


def _encoder(args: argparse.Namespace):
    from app.answering.towers import text_tower

    return text_tower(args.text_tower, args.static_tower)


def _modes(args: argparse.Namespace) -> tuple[str, ...]:
    return tuple(MODES) if args.mode == "both" else (args.mode,)


def _seeds(args: argparse.Namespace) -> tuple[int, ...]:
    return tuple(range(args.seed, args.seed + (args.seeds or DEFAULT_SEEDS[args.scenario])))


def _report(args: argparse.Namespace, scenario: Any, cfg: Any, banner: str) -> int:
    """Print `banner`, run the scenario module's `run(cfg, encoder)`, write its document to
    --json (first: an hour of mapping is kept whatever printing does), print its table."""
    print(banner, file=sys.stderr)
    report = scenario.run(cfg, _encoder(args))
    if args.json:
        write_json(args.json, report.document)
    print(report.table())
    return 0


def run(args: argparse.Namespace) -> int:
    from evaluation import walk

    if args.scenario == "revisit":
        return run_revisit_scenario(args)
    if args.scenario == "relations":
        return run_relations_scenario(args)
    if args.scenario == "geometry":
        return run_geometry_scenario(args)

    queries = None
    if args.queries:
        try:
            queries = walk.load_queries(args.queries)
        except ValueError as exc:
            print(f"semanticxr eval: error: --queries {exc}", file=sys.stderr)
            return 2
    cfg = walk.EvalConfig(
        scene=args.scene,
        seed=args.seed,
        frames=args.frames or DEFAULT_FRAMES["walk"],
        width=args.width,
        height=args.height,
        noise=args.noise,
        modes=_modes(args),
        knobs=knobs_from_args(args),
        queries=queries,
        sightings=args.sightings,
        upstream=args.upstream,
    )
    banner = (
        f"[eval] scene {cfg.scene} (seed {cfg.seed}), {cfg.frames} frames at "
        f"{cfg.width}x{cfg.height}, depth ÷{cfg.knobs.depth_downsampling_ratio}, "
        f"noise {cfg.noise}, modes {', '.join(cfg.modes)}"
    )
    return _report(args, walk, cfg, banner)


def run_revisit_scenario(args: argparse.Namespace) -> int:
    from evaluation import revisit

    cfg = revisit.RevisitConfig(
        scene=args.scene,
        seeds=_seeds(args),
        walk_frames=args.walk_frames,
        width=args.width,
        height=args.height,
        noise=args.noise,
        modes=_modes(args),
        knobs=knobs_from_args(args),
        sightings=args.sightings,
    )
    banner = (
        f"[revisit] scene {cfg.scene}, seeds {list(cfg.seeds)}, two walks of "
        f"{cfg.walk_frames} frames at 5 fps {cfg.gap_s:g} s apart, modes {', '.join(cfg.modes)}"
    )
    return _report(args, revisit, cfg, banner)


def run_relations_scenario(args: argparse.Namespace) -> int:
    from evaluation import relations

    cfg = relations.RelationsConfig(
        seeds=_seeds(args),
        frames=args.frames or DEFAULT_FRAMES["relations"],
        width=args.width,
        height=args.height,
        noise=args.noise,
        knobs=knobs_from_args(args),
    )
    banner = (
        f"[relations] relation rooms, seeds {list(cfg.seeds)}, {cfg.frames} frames each at "
        f"{cfg.width}x{cfg.height}, noise {cfg.noise}"
    )
    return _report(args, relations, cfg, banner)


def run_geometry_scenario(args: argparse.Namespace) -> int:
    from evaluation import geometry

    cfg = geometry.GeometryConfig(
        scene=args.scene,
        seed=args.seed,
        frames=args.frames or DEFAULT_FRAMES["geometry"],
        width=args.width,
        height=args.height,
        noise=args.noise,
        modes=_modes(args),
        knobs=knobs_from_args(args),
        sightings=args.sightings,
    )
    banner = (
        f"[geometry] scene {cfg.scene} (seed {cfg.seed}), {cfg.frames} frames at "
        f"{cfg.width}x{cfg.height}, noise {cfg.noise}, modes {', '.join(cfg.modes)}"
    )
    return _report(args, geometry, cfg, banner)
