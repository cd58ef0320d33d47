"""`semanticxr towers distil --out FILE`: a static text tower, distilled from a text tower
(minutes, once; nothing downloaded), for `semanticxr serve --static-tower FILE`.

    semanticxr towers distil --out minilm-static.tower
    semanticxr serve --static-tower minilm-static.tower

Progress goes to stderr; the tower's model id, hash and size to stdout at the end.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "towers",
        help="build static text towers (for serve --static-tower)",
        description="Static text towers: a table of token vectors distilled from a text "
        "tower, which every device and the page can run to embed a question in well under "
        "a millisecond.",
    )
    sub = parser.add_subparsers(dest="towers_command", required=True, metavar="ACTION")
    distil = sub.add_parser(
        "distil",
        help="distil a static tower from a text tower into a file",
        description="Distil a static text tower from TEACHER (minutes, once, nothing "
        "downloaded) and write its file to --out.",
    )
    distil.add_argument("--out", required=True, metavar="FILE", help="the tower file to write")
    distil.add_argument(
        "--teacher",
        default=None,
        metavar="MODEL",
        help="the text tower to distil from (default all-MiniLM-L6-v2, the packaged MiniLM)",
    )
    distil.set_defaults(func=run_distil)
    return parser


def run_distil(args: argparse.Namespace) -> int:
    from app.semantics import DEFAULT_MODEL_ID
    from app.semantics.distil import distil_static_tower
    from app.semantics.static import StaticTower

    out = Path(args.out)
    if not out.parent.is_dir():
        print(f"semanticxr towers distil: --out {out}: no folder {out.parent}", file=sys.stderr)
        return 2
    teacher = args.teacher or DEFAULT_MODEL_ID
    start = time.monotonic()

    def progress(message: str) -> None:
        print(f"[towers] {time.monotonic() - start:6.1f} s  {message}", file=sys.stderr, flush=True)

    progress(f"distilling a static text tower from {teacher}")
    try:
        data = distil_static_tower(teacher, progress=progress)
    except (ValueError, OSError) as exc:
        print(f"semanticxr towers distil: {exc}", file=sys.stderr)
        return 1
    tower = StaticTower.from_bytes(data)
    partial = out.with_name(out.name + ".part")
    partial.write_bytes(data)
    partial.replace(out)
    progress(f"wrote {out}")
    print(f"{tower.model_id} sha256 {tower.sha256} dim {tower.dim} "
          f"vocab {len(tower.vocab)} bytes {len(data)} -> {out}")  # fmt: skip
    return 0
