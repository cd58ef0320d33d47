"""The phrases of a reading: which are embedded, and which labels a phrase names by its head
noun ("the table" names the dining table)."""

from __future__ import annotations

from app.relations.grammar import Reading

_IRREGULAR_PLURALS = {
    "shelves": "shelf", "knives": "knife", "people": "person", "boxes": "box", "glasses":
    "glasses", "dishes": "dish", "benches": "bench", "couches": "couch", "watches": "watch",
}  # fmt: skip


def head_noun(phrase: str) -> str:
    """The last word of a phrase, lower case, a plural's s dropped ("dining tables" ->
    "table"; "glass" and "bus" keep theirs)."""
    words = phrase.lower().split()
    return _singular(words[-1]) if words else ""


def _singular(word: str) -> str:
    if word in _IRREGULAR_PLURALS:
        return _IRREGULAR_PLURALS[word]
    if word.endswith("ies") and len(word) > 4:
        return word[:-3] + "y"
    if word.endswith("s") and not word.endswith(("ss", "us", "is")) and len(word) > 3:
        return word[:-1]
    return word


_ARTICLES = frozenset({"the", "a", "an", "my", "our", "your", "this", "that"})
COMPOUND_HEAD_MIN_LETTERS = 5
"""A head noun of at least this many letters also names a one-word compound ending in it:
"shelf" a bookshelf, "case" no bookcase."""


def same_head(phrase: str, label: str) -> bool:
    """Whether a phrase names a label by its head noun: the label ends in the same noun ("the
    table" and "dining table"), or in a compound of it ("the shelf" and "bookshelf"), and
    every other word of the phrase is in the label ("side table" does not name the dining
    table; "dining table" does)."""
    words = [_singular(w) for w in phrase.lower().split() if w not in _ARTICLES]
    label_words = [_singular(w) for w in label.lower().split()]
    if not words or not label_words:
        return False
    head, label_head = words[-1], label_words[-1]
    if head != label_head and not (
        len(head) >= COMPOUND_HEAD_MIN_LETTERS and label_head.endswith(head)
    ):
        return False
    return all(w in label_words for w in words[:-1])


def phrases_of(reading: Reading) -> list[str]:
    """The phrases `answer` embeds for a reading, in one `encoder.encode` call: the anchors,
    then the target (a device encodes them ahead, off its loop, into the encoder's cache)."""
    return list(dict.fromkeys([*anchor_phrases_of(reading), target_phrase_of(reading)]))


def anchor_phrases_of(reading: Reading) -> list[str]:
    phrases = [a for c in reading.relations for a in c.anchors]
    if reading.superlative is not None:
        phrases += reading.superlative.anchors
    return phrases


def target_phrase_of(reading: Reading) -> str:
    """The target phrase, or for an unspecified target the question's words (its cosine)."""
    return _question(reading) if reading.any_target else reading.target


def _question(reading: Reading) -> str:
    """Words for an unspecified target's cosine: the anchors ("on the table" -> "table")."""
    clauses = [" ".join(c.anchors) for c in reading.relations]
    return " ".join(clauses) or "object"
