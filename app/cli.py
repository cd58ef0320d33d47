"""The `semanticxr` command: one entry point, one subcommand per job.

Knob flags are generated from app.config.Knobs, so each knob is documented once.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
from pathlib import Path
from typing import Any

from app.config import MODES, KnobError, Knobs, knob_docs, updated_knobs
from app.server.settings import SettingsError


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def server_url(text: str) -> str:
    """argparse type: a server URL, http(s):// or ws(s)://host:port."""
    from client_sim.streaming import http_base_url

    try:
        http_base_url(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def scene_name(text: str) -> str:
    """argparse type: one of the synthetic scenes."""
    from client_sim.world.scene import SCENE_NAMES

    if text not in SCENE_NAMES:
        raise argparse.ArgumentTypeError(
            f"unknown scene {text!r}; valid names: {', '.join(SCENE_NAMES)}"
        )
    return text


def add_knob_flags(parser: argparse.ArgumentParser) -> None:
    """One --flag per knob, help text from the knob's docstring."""
    group = parser.add_argument_group("knobs (DESIGN.md, paper Table 3)")
    docs = knob_docs()
    for f in dataclasses.fields(Knobs):
        default = getattr(Knobs(), f.name)
        group.add_argument(
            f"--{f.name.replace('_', '-')}",
            dest=f"knob_{f.name}",
            default=None,
            metavar="LIST" if isinstance(default, list) else "N",
            help=f"{docs.get(f.name, '')} (default: {default})",
        )


def knobs_from_args(args: argparse.Namespace) -> Knobs:
    changes: dict[str, Any] = {}
    for f in dataclasses.fields(Knobs):
        value = getattr(args, f"knob_{f.name}", None)
        if value is not None:
            changes[f.name] = value
    return updated_knobs(Knobs(), changes)


def write_json(path: str, document: dict) -> None:
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text(json.dumps(document, indent=2, sort_keys=False) + "\n")
    print(f"wrote {target}", file=sys.stderr)


def cmd_eval(args: argparse.Namespace) -> int:
    from app.semantics import get_text_encoder
    from client_sim.evaluation import EvalConfig, run_eval

    cfg = EvalConfig(
        scene=args.scene,
        seed=args.seed,
        frames=args.frames,
        width=args.width,
        height=args.height,
        noise=args.noise,
        modes=tuple(MODES) if args.mode == "both" else (args.mode,),
        knobs=knobs_from_args(args),
    )
    print(
        f"[eval] scene {cfg.scene} (seed {cfg.seed}), {cfg.frames} frames at "
        f"{cfg.width}x{cfg.height}, depth ÷{cfg.knobs.depth_downsampling_ratio}, "
        f"noise {cfg.noise}, modes {', '.join(cfg.modes)}",
        file=sys.stderr,
    )
    result = run_eval(cfg, get_text_encoder())
    print(format_eval_table(result))
    if args.json:
        write_json(args.json, result)
    return 0


def cmd_serve(args: argparse.Namespace) -> int:
    import logging

    from uvicorn import Server

    from app.server.app import create_app
    from app.server.runner import uvicorn_config
    from app.server.settings import ServerSettings

    settings = ServerSettings.from_env(
        host=args.host,
        port=args.port,
        data_dir=args.data_dir,
        api_key=args.api_key,
        max_message_bytes=args.max_message_bytes,
        mapping_workers=args.mapping_workers,
        log_level=args.log_level,
    )
    logging.basicConfig(
        level=settings.log_level.upper(), format="%(levelname)s %(name)s: %(message)s"
    )
    print(f"SemanticXR on http://{settings.host}:{settings.port}  (data in {settings.data_dir})")
    Server(uvicorn_config(create_app(settings), settings)).run()
    return 0


def format_eval_table(result: dict) -> str:
    lines = [
        f"scene {result['scene']}: {result['keyframes']} keyframes of {result['frames']} frames, "
        f"noise {result['noise']}",
        f"{'mode':<11} {'mAcc':>6} {'F-mIoU':>7} {'objects':>8} {'p50 ms':>7} {'p95 ms':>7} "
        f"{'query@1':>8}",
    ]
    for mode, m in result["modes"].items():
        lat = m["latency_ms"]
        lines.append(
            f"{mode:<11} {m['mAcc']:6.1f} {m['F_mIoU']:7.1f} {m['objects']:8d} {lat['p50']:7.1f} "
            f"{lat['p95']:7.1f} {m['query_top1']:7.1f}%"
        )
    if "speedup_p50" in result:
        lines.append(f"speed-up (baseline p50 / semanticxr p50): {result['speedup_p50']:.2f}x")
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="semanticxr",
        description="Real-time, open-vocabulary 3D semantic mapping for XR devices.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    ev = sub.add_parser(
        "eval",
        help="map a synthetic scene in process and score it (mAcc, F-mIoU, latency, queries)",
        description="Run the full pipeline (render, encode, decode, map) on a synthetic scene "
        "for one or both system organisations and report semantic quality and speed.",
    )
    ev.add_argument(
        "--scene",
        default="apartment",
        type=scene_name,
        help="synthetic scene: living_room, kitchen, office, bedroom or apartment",
    )
    ev.add_argument("--seed", type=int, default=0, help="scene, trajectory and noise seed")
    ev.add_argument("--frames", type=positive_int, default=400, help="input frames of the walk")
    ev.add_argument("--width", type=positive_int, default=640, help="RGB width in pixels")
    ev.add_argument("--height", type=positive_int, default=480, help="RGB height in pixels")
    ev.add_argument(
        "--noise", default="standard", choices=("none", "standard"), help="detection noise"
    )
    ev.add_argument("--mode", default="both", choices=(*MODES, "both"), help="system organisation")
    ev.add_argument("--json", metavar="PATH", help="write the results as JSON here")
    add_knob_flags(ev)
    ev.set_defaults(func=cmd_eval)

    sv = sub.add_parser(
        "serve",
        help="run the SemanticXR server (REST + WebSockets, wire protocol v1)",
        description="Serve the wire protocol v1. Flags override SEMANTICXR_* environment variables.",
    )
    sv.add_argument("--host", help="interface to listen on (default 127.0.0.1)")
    sv.add_argument("--port", type=int, help="TCP port (default 8000)")
    sv.add_argument("--data-dir", help="folder of the SQLite database (default ./data)")
    sv.add_argument(
        "--api-key", help="key required to create/list sessions (env SEMANTICXR_API_KEY)"
    )
    sv.add_argument(
        "--max-message-bytes", type=int, help="largest WebSocket message (default 8 MiB)"
    )
    sv.add_argument("--mapping-workers", type=int, help="threads that decode and map (default 2)")
    sv.add_argument("--log-level", help="uvicorn log level (default info)")
    sv.set_defaults(func=cmd_serve)

    from client_sim.demo import add_demo_parser
    from client_sim.device import add_device_parser

    add_device_parser(sub)
    add_demo_parser(sub)

    from viewer.app import add_viewer_parser

    add_viewer_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (KnobError, SettingsError) as exc:
        parser.error(str(exc))
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
