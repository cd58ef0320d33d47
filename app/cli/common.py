"""What several commands share: the scene argument type, writing a JSON result and a
session's frames in words."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from app.protocol import SessionStats, SessionSummary


def scene_name(text: str) -> str:
    """argparse type: one of the synthetic scenes."""
    from world import SCENE_NAMES  # here: the world loads open3d

    if text not in SCENE_NAMES:
        raise argparse.ArgumentTypeError(
            f"unknown scene {text!r}; valid names: {', '.join(SCENE_NAMES)}"
        )
    return text


def frames_words(stats: SessionStats | SessionSummary) -> str:
    """The frames a session walked, whole and as sightings: "300 frames (60 whole, 240
    sightings)"; "300 frames" from a server that does not count them apart."""
    if stats.frames_whole is None or stats.sightings is None:
        return f"{stats.frames} frames"
    return f"{stats.frames} frames ({stats.frames_whole} whole, {stats.sightings} sightings)"


def write_json(path: str, document: dict) -> None:
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text(json.dumps(document, indent=2, sort_keys=False) + "\n")
    print(f"wrote {target}", file=sys.stderr)
