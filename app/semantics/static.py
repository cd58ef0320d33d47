"""The static text tower: a question is the sum of its tokens' rows, no network to run.

A static tower is a table: one int8 row per token of a WordPiece vocabulary, distilled from a
session's text tower (app.semantics.distil). It encodes a question in well under a
millisecond, on the server, the Python device and the page alike, and every end gets the same
bits, because the steps are exact:

1. BERT's basic tokenisation (HF `BertNormalizer` with lowercasing + `BertPreTokenizer`),
   in this order: NUL, U+FFFD and control characters (category C*, but tab, newline and
   carriage return) dropped, whitespace (Unicode White_Space) made spaces, CJK ideographs
   padded with spaces, accents stripped (NFD, marks Mn dropped), lower case, split on
   spaces and around every punctuation character (ASCII !-/ :-@ [-` {-~ and category P*);
2. WordPiece per word: greedy longest match first, later pieces prefixed "##"; a word with a
   piece not in the vocabulary, or longer than `max_word_chars`, is unknown;
3. unknown words dropped, at most MAX_TOKENS ids kept;
4. the ids' int8 rows summed as integers (exact);
5. each sum divided by the sum's norm in float64, then rounded to float32 (one rounding each:
   IEEE division and square root are exact to the last bit on every end).

The rows share one scale, so integer sums keep the tokens' weights relative to each other.

The tower travels as one file (msgpack, `to_bytes`), named by its sha256: a session's
`embedding.model` is `static-` + the first 16 hex digits, so a device holding other bytes
refuses rather than scoring in another space.
"""

from __future__ import annotations

import hashlib
import unicodedata
from array import array
from bisect import bisect_left
from collections.abc import Callable, Sequence

import msgpack
import numpy as np

from app.semantics import TextEncoder

TOWER_FORMAT = "semanticxr-static-tower"
TOWER_VERSION = 1
STATIC_PREFIX = "static-"
"""`embedding.model` of a static tower: this + the first MODEL_ID_HEX hex digits of its sha256."""
MODEL_ID_HEX = 16
MAX_TOKENS = 512
"""Ids kept of a text (the first): the teacher's own limit."""
MAX_TOWER_BYTES = 64 * 1024 * 1024
"""Largest tower file read (a 256-d table of 30k tokens is ~7.6 MB)."""
MAX_VOCAB = 1_000_000
MAX_DIM = 4096


class TowerError(ValueError):
    """A tower file that cannot be read; the message names what is wrong."""


def static_model_id(sha256: str) -> str:
    """The `embedding.model` of the tower whose file has this sha256 (hex)."""
    return STATIC_PREFIX + sha256[:MODEL_ID_HEX]


def is_static_model_id(model_id: str) -> bool:
    return model_id.startswith(STATIC_PREFIX)


def sha256_hex(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


# --- step 1: BERT basic tokenisation -------------------------------------------------------


def _is_control(ch: str) -> bool:
    if ch in "\t\n\r":
        return False
    return unicodedata.category(ch).startswith("C")


def _is_whitespace(ch: str) -> bool:
    """Unicode White_Space (asked after `_is_control`, which takes the controls among it)."""
    return ch.isspace()


def _is_punctuation(ch: str) -> bool:
    cp = ord(ch)
    if 33 <= cp <= 47 or 58 <= cp <= 64 or 91 <= cp <= 96 or 123 <= cp <= 126:
        return True
    return unicodedata.category(ch).startswith("P")


def _is_cjk(cp: int) -> bool:
    return (
        0x4E00 <= cp <= 0x9FFF
        or 0x3400 <= cp <= 0x4DBF
        or 0x20000 <= cp <= 0x2A6DF
        or 0x2A700 <= cp <= 0x2B73F
        or 0x2B740 <= cp <= 0x2B81F
        or 0x2B820 <= cp <= 0x2CEAF
        or 0xF900 <= cp <= 0xFAFF
        or 0x2F800 <= cp <= 0x2FA1F
    )


def basic_words(text: str) -> list[str]:
    """Step 1: the words (and punctuation marks, each its own word) of `text`."""
    cleaned = []
    for ch in text:
        cp = ord(ch)
        if cp == 0 or cp == 0xFFFD or _is_control(ch):
            continue
        if _is_whitespace(ch):
            cleaned.append(" ")
        elif _is_cjk(cp):
            cleaned.append(f" {ch} ")
        else:
            cleaned.append(ch)
    stripped = "".join(
        ch
        for ch in unicodedata.normalize("NFD", "".join(cleaned))
        if unicodedata.category(ch) != "Mn"
    )
    # One character at a time, as HF does (a whole string's lower() makes a word's final
    # capital sigma a final sigma, another token).
    stripped = "".join(ch.lower() for ch in stripped)
    words: list[str] = []
    for chunk in stripped.split(" "):
        start = 0
        for i, ch in enumerate(chunk):
            if _is_punctuation(ch):
                if i > start:
                    words.append(chunk[start:i])
                words.append(ch)
                start = i + 1
        if start < len(chunk):
            words.append(chunk[start:])
    return words


# --- the tower -------------------------------------------------------------------------------


class _TokenIndex:
    """token -> id over a vocabulary held as one UTF-8 blob: a sorted array of the tokens'
    hashes and their ids (~12 bytes a token against ~100 for a dict of str), each hit checked
    against the token's own bytes, so a hash collision never maps a word to another token."""

    def __init__(self, vocab: Sequence[str]):
        encoded = [token.encode("utf-8") for token in vocab]
        self.blob = b"".join(encoded)
        self.offsets = np.zeros(len(encoded) + 1, np.int64)
        np.cumsum([len(e) for e in encoded], out=self.offsets[1:])
        hashes = np.array([hash(token) for token in vocab], np.int64)
        order = np.argsort(hashes, kind="stable")
        self.hashes = array("q", hashes[order].tolist())
        self.ids = array("l", order.tolist())

    def __len__(self) -> int:
        return len(self.offsets) - 1

    def token(self, i: int) -> str:
        return self.blob[self.offsets[i] : self.offsets[i + 1]].decode("utf-8")

    def get(self, token: str) -> int | None:
        wanted = hash(token)
        at = bisect_left(self.hashes, wanted)
        encoded = None
        while at < len(self.hashes) and self.hashes[at] == wanted:
            i = self.ids[at]
            encoded = encoded or token.encode("utf-8")
            if self.blob[self.offsets[i] : self.offsets[i + 1]] == encoded:
                return i
            at += 1
        return None


class StaticTower:
    """A static text tower: a WordPiece vocabulary and one int8 row per token.

    It keeps only what encoding needs (the int8 table, the vocabulary as one blob and a
    hashed index: ~8 MB for 29.5k x 256), not the file: `to_bytes()` packs it again, to the
    same bytes."""

    def __init__(
        self,
        teacher: str,
        vocab: Sequence[str],
        rows: np.ndarray,
        unk: str = "[UNK]",
        prefix: str = "##",
        max_word_chars: int = 100,
    ):
        self.teacher = teacher
        """The `embedding.model` of the tower it was distilled from."""
        self.rows = rows
        """int8 [len(vocab), dim], one scale for all."""
        self.unk, self.prefix, self.max_word_chars = unk, prefix, max_word_chars
        if rows.dtype != np.int8 or rows.ndim != 2:
            raise TowerError(f"rows: must be int8 [vocab, dim], got {rows.dtype} {rows.shape}")
        if len(vocab) != len(rows):
            raise TowerError(f"rows: {len(rows)} rows for a vocab of {len(vocab)}")
        if len(set(vocab)) != len(vocab):
            raise TowerError("vocab: a token is listed twice")
        self._index = _TokenIndex(vocab)
        self._unk_id = self._index.get(unk)
        self._sha256 = sha256_hex(self._pack(vocab))

    @property
    def vocab(self) -> tuple[str, ...]:
        return tuple(self._index.token(i) for i in range(len(self._index)))

    @property
    def dim(self) -> int:
        return int(self.rows.shape[1])

    @property
    def sha256(self) -> str:
        return self._sha256

    @property
    def model_id(self) -> str:
        return static_model_id(self.sha256)

    @property
    def unk_id(self) -> int | None:
        return self._unk_id

    # --- the file ---

    def _pack(self, vocab: Sequence[str]) -> bytes:
        return msgpack.packb(
            {
                "format": TOWER_FORMAT,
                "version": TOWER_VERSION,
                "teacher": self.teacher,
                "dim": self.dim,
                "vocab": list(vocab),
                "unk": self.unk,
                "prefix": self.prefix,
                "max_word_chars": self.max_word_chars,
                "rows": np.ascontiguousarray(self.rows).tobytes(),
            },
            use_bin_type=True,
        )

    def to_bytes(self) -> bytes:
        """The tower file: canonical bytes (the same tower always packs the same)."""
        return self._pack(self.vocab)

    @classmethod
    def from_bytes(cls, data: bytes) -> StaticTower:
        """Read a tower file; TowerError naming what is wrong."""
        if len(data) > MAX_TOWER_BYTES:
            raise TowerError(f"tower file: {len(data)} bytes, more than {MAX_TOWER_BYTES}")
        try:
            record = msgpack.unpackb(data, raw=False, max_bin_len=MAX_TOWER_BYTES)
        except Exception as exc:
            raise TowerError(f"tower file: not msgpack ({exc})") from exc
        if not isinstance(record, dict) or record.get("format") != TOWER_FORMAT:
            raise TowerError(f"format: not a {TOWER_FORMAT} file")
        if record.get("version") != TOWER_VERSION:
            raise TowerError(f"version: {record.get('version')!r}, this code reads {TOWER_VERSION}")
        vocab, dim, rows = record.get("vocab"), record.get("dim"), record.get("rows")
        if not isinstance(vocab, list) or not all(isinstance(t, str) for t in vocab):
            raise TowerError("vocab: must be a list of strings")
        if not 0 < len(vocab) <= MAX_VOCAB:
            raise TowerError(f"vocab: {len(vocab)} tokens, must be 1..{MAX_VOCAB}")
        if isinstance(dim, bool) or not isinstance(dim, int) or not 0 < dim <= MAX_DIM:
            raise TowerError(f"dim: must be an integer 1..{MAX_DIM}, got {dim!r}")
        if not isinstance(rows, bytes) or len(rows) != len(vocab) * dim:
            raise TowerError(f"rows: must be {len(vocab)} x {dim} int8 bytes")
        teacher = record.get("teacher")
        if not isinstance(teacher, str):
            raise TowerError("teacher: must be a string")
        unk, prefix, max_chars = (
            record.get("unk"),
            record.get("prefix"),
            record.get("max_word_chars"),
        )
        if not isinstance(unk, str) or not isinstance(prefix, str):
            raise TowerError("unk, prefix: must be strings")
        if isinstance(max_chars, bool) or not isinstance(max_chars, int) or max_chars < 1:
            raise TowerError(f"max_word_chars: must be a positive integer, got {max_chars!r}")
        table = np.frombuffer(rows, np.int8).reshape(len(vocab), dim)
        tower = cls(teacher, vocab, table, unk, prefix, max_chars)
        if tower.sha256 != sha256_hex(data):
            raise TowerError("tower file: not in canonical form (written by other code?)")
        return tower

    @classmethod
    def build(
        cls, vocab: list[str] | tuple[str, ...], rows: np.ndarray, *, teacher: str, **options
    ) -> StaticTower:
        """A tower of float `rows` [len(vocab), dim], quantised to int8 with one scale (the
        largest magnitude maps to 127): what a distillation ends with, and what tests use to
        make a tower of any vocabulary without distilling."""
        table = np.asarray(rows, np.float64)
        peak = float(np.abs(table).max()) if table.size else 0.0
        scaled = table / peak * 127 if peak > 0 else table
        quantised = np.clip(np.rint(scaled), -127, 127).astype(np.int8)
        return cls(teacher, tuple(vocab), quantised, **options)

    # --- encoding ---

    def _word_ids(self, word: str) -> list[int] | None:
        if len(word) > self.max_word_chars:
            return None
        ids, start = [], 0
        while start < len(word):
            end = len(word)
            while end > start:
                piece = word[start:end] if start == 0 else self.prefix + word[start:end]
                found = self._index.get(piece)
                if found is not None:
                    ids.append(found)
                    break
                end -= 1
            else:
                return None
            start = end
        return ids

    def token_ids(self, text: str) -> list[int]:
        """Steps 1-3: the ids of `text`, unknown words dropped, at most MAX_TOKENS."""
        unk = self.unk_id
        ids: list[int] = []
        for word in basic_words(text):
            pieces = self._word_ids(word)
            if pieces is not None:
                ids.extend(i for i in pieces if i != unk)
            if len(ids) >= MAX_TOKENS:
                break
        return ids[:MAX_TOKENS]

    def embed_ids(self, ids: list[int]) -> np.ndarray:
        """Steps 4-5: float32 [dim], unit, or zero when the ids sum to nothing."""
        if not ids:
            return np.zeros(self.dim, np.float32)
        total = self.rows[np.asarray(ids, np.int64)].sum(axis=0, dtype=np.int64)
        squares = int((total * total).sum())
        if squares == 0:
            return np.zeros(self.dim, np.float32)
        return (total.astype(np.float64) / np.sqrt(np.float64(squares))).astype(np.float32)

    def embed(self, text: str) -> np.ndarray:
        return self.embed_ids(self.token_ids(text))


class StaticEncoder(TextEncoder):
    """A TextEncoder over a StaticTower: the same encodings as every other end holding it.

    label_texts: a label's texts (its synonyms, definition and kind: app.answering
    .label_knowledge), given on the end that embeds labels for a map (the server, the evals):
    a label's embedding is then the unit sum of its name's and the mean of its other texts'
    (`encode_labels`). A sum of word rows knows a name only by its words; the texts say what
    the thing is, so descriptions find it (training paraphrases 90.3 -> 93.3 % top-1, held-out
    81.2 -> 85.0 %: docs/evaluation.md "Text towers"). Questions are embedded plain.
    """

    def __init__(
        self,
        tower: StaticTower,
        cache_size: int = 4096,
        label_texts: Callable[[str], Sequence[str]] | None = None,
    ):
        super().__init__(cache_size)
        self.tower = tower
        self.model_id = tower.model_id
        self.dim = tower.dim
        self._label_texts = label_texts
        self._labels: dict[str, np.ndarray] = {}

    def encode_labels(self, labels: list[str] | tuple[str, ...]) -> np.ndarray:
        if self._label_texts is None:
            return self.encode(labels)
        rows = []
        for label in labels:
            row = self._labels.get(label)
            if row is None:
                row = self._label_row(label)
                with self._lock:
                    if len(self._labels) >= self._cache_size:
                        self._labels.clear()
                    self._labels[label] = row
            rows.append(row)
        return np.stack(rows) if rows else np.zeros((0, self.dim), np.float32)

    def _label_row(self, label: str) -> np.ndarray:
        name = self.tower.embed(label).astype(np.float64)
        others = [t for t in self._label_texts(label) if t != label]
        if others:
            name = name + np.mean([self.tower.embed(t) for t in others], axis=0)
        norm = np.linalg.norm(name)
        return (name / norm if norm > 0 else name).astype(np.float32)

    def _encode_uncached(self, texts: list[str]) -> np.ndarray:
        if not texts:
            return np.zeros((0, self.dim), np.float32)
        return np.stack([self.tower.embed(t) for t in texts])
