"""CLIP (`transformers`): per-object crop embeddings and the matching text tower.

The image tower embeds a keyframe's crops in one batch (semanticxr) or one at a time (the
baseline); the text tower embeds the vocabulary and, as `ClipTextEncoder`, a session's
queries, so objects and queries live in one space. A device answering local queries loads
the text tower alone (`ClipTextTower`, `load_text_encoder`): no vision weights in memory.
"""

from __future__ import annotations

import threading

import numpy as np
import torch
from transformers import CLIPConfig, CLIPModel, CLIPProcessor, CLIPTextModelWithProjection

from app.semantics import TextEncoder


def _unit(rows: torch.Tensor) -> np.ndarray:
    rows = rows.float()
    rows = rows / rows.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    return np.ascontiguousarray(rows.cpu().numpy(), dtype=np.float32)


class ClipEmbedder:
    """CLIP's two towers. Thread-safe (one forward at a time)."""

    def __init__(
        self,
        model: CLIPModel,
        processor: CLIPProcessor,
        device: str,
        dtype: torch.dtype,
        model_id: str,
    ):
        self.processor = processor
        self.model = model.to(device, dtype).eval()
        self.device, self.dtype = device, dtype
        self.model_id = model_id
        self.dim = int(self.model.config.projection_dim)
        self.logit_scale = float(self.model.logit_scale.detach().exp())
        self._lock = threading.Lock()

    @classmethod
    def load(cls, source: str, local_only: bool, device: str, dtype: torch.dtype, model_id: str):
        """From a folder or a hub id (`from_pretrained`); announced as `model_id`."""
        return cls(
            CLIPModel.from_pretrained(source, local_files_only=local_only),
            CLIPProcessor.from_pretrained(source, local_files_only=local_only),
            device,
            dtype,
            model_id,
        )

    def _pixels(self, crops: list[np.ndarray]) -> torch.Tensor:
        pixels = self.processor.image_processor(images=crops, return_tensors="pt")["pixel_values"]
        return pixels.to(self.device, self.dtype)

    @torch.inference_mode()
    def embed_crops_batched(self, crops: list[np.ndarray]) -> np.ndarray:
        """uint8 [h, w, 3] crops -> float32 [n, dim] unit rows, in one forward pass."""
        if not crops:
            return np.zeros((0, self.dim), np.float32)
        pixels = self._pixels(crops)
        with self._lock:
            features = self.model.get_image_features(pixel_values=pixels).pooler_output
        return _unit(features)

    def embed_crops_one_by_one(self, crops: list[np.ndarray]) -> np.ndarray:
        """The baseline organisation: the same crops, one forward pass each."""
        if not crops:
            return np.zeros((0, self.dim), np.float32)
        return np.concatenate([self.embed_crops_batched([crop]) for crop in crops])

    @torch.inference_mode()
    def embed_texts(self, texts: list[str]) -> np.ndarray:
        """Texts -> float32 [n, dim] unit rows from the text tower."""
        tokens = _tokens(
            self.processor.tokenizer, texts, self.model.config.text_config, self.device
        )
        with self._lock:
            features = self.model.get_text_features(
                input_ids=tokens["input_ids"], attention_mask=tokens["attention_mask"]
            ).pooler_output
        return _unit(features)


def _tokens(tokenizer, texts: list[str], text_config, device: str):
    return tokenizer(
        texts,
        padding=True,
        truncation=True,
        max_length=text_config.max_position_embeddings,
        return_tensors="pt",
    ).to(device)


class ClipTextTower:
    """CLIP's text tower alone, read from a full CLIP checkpoint (the vision weights stay on
    disk): what a device loads to answer local queries. Same numbers as
    `ClipEmbedder.embed_texts` on the same checkpoint. Thread-safe."""

    def __init__(
        self,
        model: CLIPTextModelWithProjection,
        tokenizer,
        device: str,
        dtype: torch.dtype,
        model_id: str,
    ):
        self.tokenizer = tokenizer
        self.model = model.to(device, dtype).eval()
        self.device, self.dtype = device, dtype
        self.model_id = model_id
        self.dim = int(self.model.config.projection_dim)
        self._lock = threading.Lock()

    @classmethod
    def load(
        cls,
        source: str,
        local_only: bool,
        model_id: str,
        device: str = "cpu",
        dtype: torch.dtype = torch.float32,
    ) -> ClipTextTower:
        """From a CLIP folder or hub id; announced as `model_id`."""
        from transformers import AutoTokenizer
        from transformers.utils import logging as hf_logging

        hf_logging.disable_progress_bar()
        hf_logging.set_verbosity_error()  # not the report of the vision weights left unread
        config = CLIPConfig.from_pretrained(source, local_files_only=local_only)
        text_config = config.text_config
        # The projection's width lives in the outer config (the text config's default is 512).
        text_config.projection_dim = config.projection_dim
        model = CLIPTextModelWithProjection.from_pretrained(
            source, config=text_config, local_files_only=local_only
        )
        tokenizer = AutoTokenizer.from_pretrained(source, local_files_only=local_only)
        return cls(model, tokenizer, device, dtype, model_id)

    @torch.inference_mode()
    def embed_texts(self, texts: list[str]) -> np.ndarray:
        """Texts -> float32 [n, dim] unit rows."""
        tokens = _tokens(self.tokenizer, texts, self.model.config, self.device)
        with self._lock:
            features = self.model(
                input_ids=tokens["input_ids"], attention_mask=tokens["attention_mask"]
            ).text_embeds
        return _unit(features)


class ClipTextEncoder(TextEncoder):
    """A session's query and label encoder on the `models` backend: CLIP's text tower (of
    the server's `ClipEmbedder`, or a device's `ClipTextTower`)."""

    def __init__(self, embedder: ClipEmbedder | ClipTextTower, cache_size: int = 4096):
        super().__init__(cache_size)
        self._embedder = embedder
        self.model_id = embedder.model_id
        self.dim = embedder.dim

    def _encode_uncached(self, texts: list[str]) -> np.ndarray:
        return self._embedder.embed_texts(texts)


def load_text_encoder(source: str, local_only: bool, model_id: str) -> ClipTextEncoder:
    """A device's query encoder for a session on the `models` backend: the text tower of the
    CLIP model at `source` (a folder or hub id; see `weights.text_towers_in`), on the CPU."""
    return ClipTextEncoder(ClipTextTower.load(source, local_only, model_id))
