"""What several commands share: the scene argument type and writing a JSON result."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def scene_name(text: str) -> str:
    """argparse type: one of the synthetic scenes."""
    from client_sim.world import SCENE_NAMES  # here: the world loads open3d

    if text not in SCENE_NAMES:
        raise argparse.ArgumentTypeError(
            f"unknown scene {text!r}; valid names: {', '.join(SCENE_NAMES)}"
        )
    return text


def write_json(path: str, document: dict) -> None:
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text(json.dumps(document, indent=2, sort_keys=False) + "\n")
    print(f"wrote {target}", file=sys.stderr)
