"""A relational answer in words, as the viewer labels its target: "mug — on the desk"
(`static/app.js` `relationWords` says the same)."""

from __future__ import annotations

from collections.abc import Sequence

_RELATION_PHRASES = {
    "next_to": "next to",
    "left_of": "left of",
    "right_of": "right of",
    "in_front_of": "in front of",
    "closest": "closest to",
    "farthest": "farthest from",
}
"""A kind's words before its anchors where they are not the kind itself ("on the desk")."""
_TO_THE_ASKER = {
    "near": "near you",
    "next_to": "next to you",
    "left_of": "on your left",
    "right_of": "on your right",
    "in_front_of": "in front of you",
    "behind": "behind you",
    "closest": "closest to you",
    "farthest": "farthest from you",
}
"""A kind measured from the asker (no anchor): "the lamp closest to me"."""
SUPERLATIVES_WITHIN_CATEGORY = ("biggest", "smallest", "highest", "lowest")


def relation_words(kind: str, anchor_labels: Sequence[str]) -> str:
    """A hit's relation in words: "on the desk", "between the chair and the sofa", "closest
    to you" (no anchor: the asker), "the biggest" (a superlative within the category). A kind
    this viewer does not know is said with its name ("beside the sofa" for "beside")."""
    if kind in SUPERLATIVES_WITHIN_CATEGORY:
        return f"the {kind}"
    if not anchor_labels:
        return _TO_THE_ASKER.get(kind, f"{kind.replace('_', ' ')} you")
    names = [f"the {label}" for label in anchor_labels]
    listed = names[0] if len(names) == 1 else f"{', '.join(names[:-1])} and {names[-1]}"
    return f"{_RELATION_PHRASES.get(kind, kind.replace('_', ' '))} {listed}"
