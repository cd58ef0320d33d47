"""The `semanticxr` command: one entry point, one subcommand per job, one module each.

The top layer (docs/architecture.md "Layers"): each module here holds one
command's argparse and its entry point (`add_parser(subparsers)`, `run(args)`), and may
import anything below it (app, client_sim, viewer); nothing below imports this package.
Modules load their heavy dependencies (torch, open3d, viser) when their command runs, not
when the parser is built.
"""

from __future__ import annotations

import argparse
import os
import sys

from app import __version__
from app.cli import demo, device, eval, gateway, models, serve, sessions, towers, viewer
from app.config import KnobError
from app.server.settings import SettingsError

COMMANDS = (eval, serve, gateway, device, demo, viewer, sessions, models, towers)
"""In the order `--help` lists them."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="semanticxr",
        description="Real-time, open-vocabulary 3D semantic mapping for XR devices.",
    )
    parser.add_argument("--version", action="version", version=f"semanticxr {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for command in COMMANDS:
        command.add_parser(sub)
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
