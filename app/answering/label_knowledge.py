"""What a lexical database knows about a label: its texts (the label, its synonyms, what it
is and what kind of thing it is), read from WordNet's noun files.

    label_texts("rucksack") -> ("rucksack", "backpack", "knapsack", "packsack", "back pack",
        "a bag carried by a strap on your back or shoulder", "bag")

A match is rated against all of a label's texts (app.answering.relevance), so a query that
names the thing by another word ("my rucksack" for a backpack) or describes it ("somewhere
to sit and watch a movie" for a sofa) finds the label. The server reads them here and serves
them with the session's labels; a device embeds what it is served with its own text tower.

WordNet comes from Debian's `wordnet-base` (/usr/share/wordnet: index.noun, data.noun,
noun.exc); SEMANTICXR_WORDNET_DIR points elsewhere. Without it a label's texts are the label
alone (one warning logged). Only nouns are read; of a word's senses, the first
SENSES_PER_LABEL (WordNet orders them by frequency) that are physical things (artifacts,
plants, animals, food, natural objects, or the top nouns such as "person"), else its first
sense; a later one only when WordNet's tag counts (cntlist.rev) show it common enough
(SENSE_SHARE), so "box" is the container, not the theater's loge. A multiword label missing from WordNet ("wall cabinet") falls back to its head noun
("cabinet"), keeping the label itself first.
"""

from __future__ import annotations

import logging
import os
import re
import threading
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path

from app.answering.relevance import background_texts

log = logging.getLogger(__name__)

DEFAULT_WORDNET_DIR = "/usr/share/wordnet"
WORDNET_DIR_ENV = "SEMANTICXR_WORDNET_DIR"
SENSES_PER_LABEL = 2
"""Senses of a label read (a word with several physical senses: "plant" the factory and
the flora)."""
SENSE_SHARE = 0.5
"""A later physical sense is read only when WordNet's tagged-corpus count of it (cntlist.rev)
is at least this share of the label's most counted physical sense's: "box" the loge (8
tags) is a rare sense beside "box" the container (25). Without counts all are read."""
SYNONYMS_PER_LABEL = 4
"""Most synonyms (other lemmas of the label's senses) among its texts."""
MAX_TEXT_CHARS = 120
"""A gloss is cut at its first ';' and at this length (the examples in quotes dropped)."""
PHYSICAL_LEXICOGRAPHER_FILES = frozenset({3, 5, 6, 13, 17, 20})
"""noun.Tops, noun.animal, noun.artifact, noun.food, noun.object, noun.plant: the senses a
thing in a room can have (a "table" of data, noun.group, is not one)."""


@dataclass(frozen=True)
class Synset:
    """One WordNet noun sense."""

    offset: int
    lexicographer_file: int
    lemmas: tuple[str, ...]
    """Its words, spaces for underscores, in WordNet's order."""
    lex_ids: tuple[int, ...]
    """Each word's lexicographer id (its sense key's lex_id)."""
    hypernyms: tuple[int, ...]
    """Offsets of its direct hypernyms (kinds it is of)."""
    gloss: str
    """Its definition (first clause, no examples)."""


class WordNet:
    """A reader of WordNet's noun files in one directory (index.noun, data.noun, noun.exc)."""

    def __init__(self, directory: str | os.PathLike):
        self.directory = Path(directory)
        index_path = self.directory / "index.noun"
        data_path = self.directory / "data.noun"
        if not index_path.is_file() or not data_path.is_file():
            raise FileNotFoundError(f"no WordNet noun files (index.noun, data.noun) in {directory}")
        self._senses: dict[str, tuple[int, ...]] = {}
        with open(index_path, encoding="utf-8") as index:
            for line in index:
                if line.startswith(" "):
                    continue  # the licence header
                fields = line.split()
                synset_count, pointer_count = int(fields[2]), int(fields[3])
                offsets = fields[6 + pointer_count : 6 + pointer_count + synset_count]
                self._senses[fields[0]] = tuple(int(o) for o in offsets)
        self._exceptions: dict[str, str] = {}
        exceptions_path = self.directory / "noun.exc"
        if exceptions_path.is_file():
            with open(exceptions_path, encoding="utf-8") as exceptions:
                for line in exceptions:
                    fields = line.split()
                    if len(fields) >= 2:
                        self._exceptions.setdefault(fields[0], fields[1])
        self._data = open(data_path, "rb")  # noqa: SIM115 (read by offset for the reader's life)
        self._data_lock = threading.Lock()
        self._synsets: dict[int, Synset] = {}
        self._counts: dict[str, int] = {}
        counts_path = self.directory / "cntlist.rev"
        if counts_path.is_file():
            with open(counts_path, encoding="utf-8") as counts:
                for line in counts:
                    fields = line.split()
                    if len(fields) == 3 and "%1:" in fields[0]:
                        self._counts[fields[0].casefold()] = int(fields[2])

    def close(self) -> None:
        self._data.close()

    def lemma(self, word: str) -> str | None:
        """The index form of a noun ("Coffee Mugs" -> "coffee_mug"), or None: lower case,
        underscores for spaces, a plural reduced by noun.exc or the regular endings."""
        key = "_".join(word.casefold().split())
        if not key:
            return None
        if key in self._senses:
            return key
        if key in self._exceptions and self._exceptions[key] in self._senses:
            return self._exceptions[key]
        for ending, replacement in (("ses", "s"), ("xes", "x"), ("ches", "ch"), ("shes", "sh"),
                                    ("ies", "y"), ("s", "")):  # fmt: skip
            if key.endswith(ending) and key[: -len(ending)] + replacement in self._senses:
                return key[: -len(ending)] + replacement
        return None

    def senses(self, lemma: str) -> list[Synset]:
        """The noun senses of an index form, most frequent first."""
        return [self.synset(offset) for offset in self._senses.get(lemma, ())]

    def tag_count(self, lemma: str, synset: Synset) -> int | None:
        """How often this sense of the index form was tagged in WordNet's corpus (cntlist.rev,
        by sense key lemma%1:lex_filenum:lex_id::), 0 when never; None without cntlist.rev."""
        if not self._counts:
            return None
        key = lemma.casefold()
        for word, lex_id in zip(synset.lemmas, synset.lex_ids, strict=True):
            if "_".join(word.casefold().split()) == key:
                sense_key = f"{key}%1:{synset.lexicographer_file:02d}:{lex_id:02d}::"
                return self._counts.get(sense_key, 0)
        return 0

    def synset(self, offset: int) -> Synset:
        """The noun sense at this byte offset of data.noun."""
        synset = self._synsets.get(offset)
        if synset is None:
            with self._data_lock:
                self._data.seek(offset)
                line = self._data.readline().decode("utf-8")
            synset = self._synsets[offset] = _parse_synset(line)
        return synset


def _parse_synset(line: str) -> Synset:
    """One data.noun line: offset lex_filenum ss_type w_cnt (word lex_id)* p_cnt
    (symbol offset pos source/target)* | gloss."""
    head, _, gloss = line.partition(" | ")
    fields = head.split()
    word_count = int(fields[3], 16)
    lemmas = tuple(fields[4 + 2 * i].replace("_", " ") for i in range(word_count))
    lemmas = tuple(re.sub(r"\([a-z]+\)$", "", lemma) for lemma in lemmas)  # "(p)", "(a)" markers
    lex_ids = tuple(int(fields[5 + 2 * i], 16) for i in range(word_count))
    at = 4 + 2 * word_count
    pointer_count = int(fields[at])
    hypernyms = tuple(
        int(fields[at + 1 + 4 * i + 1])
        for i in range(pointer_count)
        if fields[at + 1 + 4 * i] in ("@", "@i")
    )
    return Synset(int(fields[0]), int(fields[1]), lemmas, lex_ids, hypernyms, _first_clause(gloss))


def _first_clause(gloss: str) -> str:
    gloss = re.sub(r'"[^"]*"', "", gloss).strip().split(";")[0].strip()
    if len(gloss) > MAX_TEXT_CHARS:
        gloss = gloss[:MAX_TEXT_CHARS].rsplit(" ", 1)[0]
    return gloss.strip(" ,")


def texts_of(wordnet: WordNet, label: str) -> tuple[str, ...]:
    """A label's texts: the label, synonyms, glosses, the hypernyms' first words (module
    docstring); the label alone when WordNet knows neither it nor its head noun."""
    label = " ".join(label.split())
    lemma = wordnet.lemma(label)
    if lemma is None and len(label.split()) > 1:
        lemma = wordnet.lemma(label.split()[-1])  # "wall cabinet" -> "cabinet"
    if lemma is None:
        return (label,)
    senses = wordnet.senses(lemma)
    physical = [s for s in senses if s.lexicographer_file in PHYSICAL_LEXICOGRAPHER_FILES]
    chosen = common_senses(wordnet, lemma, physical or senses[:1])[:SENSES_PER_LABEL]
    synonyms = [w for s in chosen for w in s.lemmas]
    glosses = [s.gloss for s in chosen if s.gloss]
    kinds = [wordnet.synset(h).lemmas[0] for s in chosen[:1] for h in s.hypernyms[:1]]
    texts = dict.fromkeys([label])
    for synonym in synonyms:
        if len(texts) > SYNONYMS_PER_LABEL:
            break
        texts.setdefault(synonym)
    for text in glosses + kinds:
        texts.setdefault(text)
    return tuple(t for t in texts if t)


def common_senses(wordnet: WordNet, lemma: str, senses: list[Synset]) -> list[Synset]:
    """Of these senses (in WordNet's order), the first and those tagged at least SENSE_SHARE
    as often as the most tagged of them; all of them when WordNet has no counts of them."""
    counts = [wordnet.tag_count(lemma, s) for s in senses]
    most = max((c for c in counts if c is not None), default=0)
    if most == 0:
        return senses
    return [
        s
        for i, (s, c) in enumerate(zip(senses, counts, strict=True))
        if i == 0 or c >= SENSE_SHARE * most
    ]


_wordnet: WordNet | None = None
_wordnet_missing = False
_cache: dict[str, tuple[str, ...]] = {}
_lock = threading.Lock()


def wordnet_dir() -> str:
    """Where WordNet is read from: $SEMANTICXR_WORDNET_DIR, else /usr/share/wordnet."""
    return os.environ.get(WORDNET_DIR_ENV) or DEFAULT_WORDNET_DIR


def label_texts(label: str) -> tuple[str, ...]:
    """A label's texts from the process's WordNet (read once, on first use; cached per
    label); (label,) when WordNet is absent."""
    global _wordnet, _wordnet_missing
    with _lock:
        texts = _cache.get(label)
        if texts is not None:
            return texts
        if _wordnet is None and not _wordnet_missing:
            try:
                _wordnet = WordNet(wordnet_dir())
            except FileNotFoundError as exc:
                _wordnet_missing = True
                log.warning("labels are matched by their names alone: %s", exc)
        texts = texts_of(_wordnet, label) if _wordnet is not None else (label,)
        _cache[label] = texts
        return texts


class ServedLabelTexts(Mapping[str, tuple[str, ...]]):
    """The label texts a server serves with its session's labels: WordNet's for a label
    outside the shipped background vocabulary (`app.answering.relevance.background_texts`),
    None for one inside it (every end holds those). The rater reads the same through it."""

    def __getitem__(self, label: str) -> tuple[str, ...]:
        if label in background_texts():
            raise KeyError(label)
        return label_texts(label)

    def __iter__(self) -> Iterator[str]:
        return iter(())  # looked up by label, never listed

    def __len__(self) -> int:
        return 0


SERVED_LABEL_TEXTS = ServedLabelTexts()
"""The server's label texts (`ServedLabelTexts`)."""


def served_texts(label: str) -> tuple[str, ...] | None:
    """What the server sends with an upsert of this label: its texts, or None for a label of
    the shipped background."""
    return SERVED_LABEL_TEXTS.get(label)
