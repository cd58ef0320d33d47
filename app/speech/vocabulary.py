"""What a session's embedded recogniser expects to hear: the map's labels, their words, the
question forms the relational reader knows (`app.relations.grammar.question_phrases`) and the
indoor vocabulary, as a small text corpus for a trigram language model, over a background of
the most common English words.

Measured on espeak-ng speech of the apartment's paraphrases (`semanticxr eval --scenario
speech`): PocketSphinx's general 27 MB model got 32 % top-1 at ~1.1 s a question; labels and
question forms alone 23 % (everything heard as a label); this corpus over the 5,000 most
likely words 40 % at ~0.35 s, and "where is the <label>" questions 89-96 % word for word.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Iterable, Sequence
from importlib import resources

from app.relations.grammar import question_phrases

COMMON_QUESTIONS = (
    "where is the {}",
    "where are the {}",
    "where is my {}",
    "where are my {}",
    "find the {}",
    "find my {}",
    "show me the {}",
    "where did i leave my {}",
    "where did i put the {}",
    "is there a {}",
    "the {}",
    "a {}",
    "{}",
)
"""The forms every label is said in (the grammar's other scaffolds are said once each)."""
RELATIONS_PER_LABEL = 12
"""Relation phrases each label is said with (of the grammar's 78)."""
ANCHORLESS = ("me", "the floor", "the wall", "the window")
"""Anchors that need no label: the asker, and what rooms always have."""
_WORD = re.compile(r"[a-z]+(?:'[a-z]+)?")


def words_of(text: str) -> list[str]:
    """Lower-case words of a label or question ("TV-stand" -> ["tv", "stand"])."""
    return _WORD.findall(text.lower())


def indoor_tags() -> list[str]:
    """The `models` backend's packaged indoor vocabulary (one tag a line): things a room
    holds, whether or not this map has seen them yet."""
    text = resources.files("app.perception.models").joinpath("vocabulary.txt").read_text("utf-8")
    tags = (line.split("#", 1)[0].strip().lower() for line in text.splitlines())
    return list(dict.fromkeys(t for t in tags if t))


def normalised_labels(labels: Iterable[str]) -> list[str]:
    """Distinct labels as words ("Coffee-Table" -> "coffee table"), sorted."""
    return sorted({" ".join(words_of(label)) for label in labels} - {""})


def vocabulary_key(labels: Iterable[str]) -> str:
    """One key per set of labels: a recogniser rebuilds its model when the key changes."""
    return hashlib.sha256("\n".join(normalised_labels(labels)).encode()).hexdigest()[:16]


def session_corpus(labels: Sequence[str]) -> list[str]:
    """Sentences a trigram model learns the session's questions from: each label in the
    common question forms, in relations to other labels (every relation phrase of the
    grammar, the anchors rotating through the labels), with superlatives; every scaffold,
    filler and tail once. Deterministic for a set of labels."""
    labels = normalised_labels(labels)
    phrases = question_phrases()
    lines = [form.format(label) for label in labels for form in COMMON_QUESTIONS]
    lines += [f"{scaffold} the" for scaffold in phrases["scaffolds"]]
    lines += [*phrases["fillers"], *phrases["tails"]]
    anchors = [f"the {label}" for label in labels] + list(ANCHORLESS)
    relations, superlatives = phrases["relations"], phrases["superlatives"]
    for i, label in enumerate(labels):
        for j in range(RELATIONS_PER_LABEL):  # the phrases rotate: each is said by some
            relation = relations[(i * RELATIONS_PER_LABEL + j) % len(relations)]
            lines.append(f"the {label} {relation} {anchors[(i + j + 1) % len(anchors)]}")
        superlative = superlatives[i % len(superlatives)]
        lines.append(f"the {superlative} {label}")
        lines.append(f"the {label} {superlative} to {anchors[(i * 7 + 3) % len(anchors)]}")
    return lines


def background_corpus() -> list[str]:
    """What any session may be asked about without the map holding it yet: each indoor tag
    after "the" (weighed below the session's own labels)."""
    return [f"the {tag}" for tag in indoor_tags()]
