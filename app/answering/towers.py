"""The text tower a map embeds with, made the way every map-making end makes it.

A static tower embeds an object's label with the label's texts (`StaticEncoder`'s
label_texts, from WordNet: app.answering.label_knowledge); the server, the evals and the
benches get theirs here so that they agree.
"""

from __future__ import annotations

import sys
from pathlib import Path

from app.answering.label_knowledge import label_texts
from app.semantics import TextEncoder, get_text_encoder
from app.semantics.distil import load_static_tower
from app.semantics.static import StaticEncoder, StaticTower

TEXT_TOWERS = ("minilm", "static")
"""A session's `text_tower` choices: the packaged MiniLM, or the static tower distilled
from it."""


def map_static_encoder(tower: StaticTower) -> StaticEncoder:
    """The static tower as a map embeds with it: labels with their texts."""
    return StaticEncoder(tower, label_texts=label_texts)


def text_tower(name: str, static_path: str | Path | None = None) -> TextEncoder:
    """A process's text encoder by tower name: "minilm" (the packaged MiniLM) or "static"
    (the tower in file `static_path`, else the command line's tower cache's, distilled there
    on first use with progress on stderr), as a map embeds with it."""
    if name == "minilm":
        return get_text_encoder()
    if name == "static":
        return map_static_encoder(
            load_static_tower(static_path, lambda line: print(line, file=sys.stderr, flush=True))
        )
    raise ValueError(f"text tower must be one of {', '.join(TEXT_TOWERS)}, got {name!r}")
