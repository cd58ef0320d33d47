"""`semanticxr models`: the `models` perception backend's weights.

`models tiny --out DIR` writes small randomly initialised models of the real architectures,
with processors and tokenizers, in the layout `serve --models-dir DIR` expects (offline, in
seconds; for tests and trying the plumbing: their detections and labels mean nothing).
`models list` says which models the backend needs and the commands that fetch them.
"""

from __future__ import annotations

import argparse
from typing import Any


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "models",
        help="weights of the `models` perception backend (tiny random ones for tests)",
        description="Weights of the `models` perception backend (serve --perception models).",
    )
    sub = parser.add_subparsers(dest="models_command", required=True, metavar="ACTION")
    tiny = sub.add_parser(
        "tiny",
        help="write small random models of the real architectures (offline, for tests)",
        description="Write small randomly initialised OWL-ViT and CLIP models, with their "
        "processors and tokenizers, in the layout --models-dir expects. Their outputs mean "
        "nothing: quality needs the real weights (`semanticxr models list`).",
    )
    tiny.add_argument("--out", required=True, metavar="DIR", help="folder to write (created)")
    tiny.add_argument("--seed", type=int, default=0, help="random seed of the weights")
    tiny.set_defaults(func=run_tiny)
    whisper = sub.add_parser(
        "tiny-whisper",
        help="write a small random Whisper for --asr whisper:DIR (offline, for tests)",
        description="Write a small randomly initialised Whisper, with its processor and a "
        "tokenizer trained here, in the layout --asr whisper:DIR loads. Its transcripts are "
        "noise: recognition needs real weights (e.g. openai/whisper-base.en).",
    )
    whisper.add_argument("--out", required=True, metavar="DIR", help="folder to write (created)")
    whisper.add_argument("--seed", type=int, default=0, help="random seed of the weights")
    whisper.set_defaults(func=run_tiny_whisper)
    listing = sub.add_parser(
        "list",
        help="the models the backend needs and how to fetch them",
        description="The models the backend loads, and the commands that fetch them into DIR.",
    )
    listing.add_argument("--models-dir", default=None, metavar="DIR")
    listing.set_defaults(func=run_list)
    return parser


def run_tiny(args: argparse.Namespace) -> int:
    import time

    from app.perception.models.tiny import write_tiny_models

    t0 = time.perf_counter()
    out = write_tiny_models(args.out, seed=args.seed)
    print(
        f"tiny random models written to {out} in {time.perf_counter() - t0:.1f} s; "
        f"serve them with: semanticxr serve --perception models --models-dir {out}"
    )
    return 0


def run_tiny_whisper(args: argparse.Namespace) -> int:
    import time

    from app.speech.whisper import write_tiny_whisper

    t0 = time.perf_counter()
    out = write_tiny_whisper(args.out, seed=args.seed)
    print(
        f"tiny random Whisper written to {out} in {time.perf_counter() - t0:.1f} s; "
        f"serve it with: semanticxr serve --asr whisper:{out}"
    )
    return 0


def run_list(args: argparse.Namespace) -> int:
    from app.perception.models.weights import PROFILES, fetch_commands

    for profile in PROFILES.values():
        print(f"profile {profile.name}:")
        for spec in profile.models:
            print(f"  {spec.role:9} {spec.hub_id}  (folder {spec.folder})")
        print("fetch into --models-dir:")
        for command in fetch_commands(profile, args.models_dir):
            print(f"  {command}")
    return 0
