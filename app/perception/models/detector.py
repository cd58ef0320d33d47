"""Open-vocabulary boxes: OWL-ViT (`transformers`) prompted with a vocabulary.

The prompts' text embeddings are computed once per vocabulary; a keyframe then costs one
image-tower pass plus the class and box heads.
"""

from __future__ import annotations

import threading

import numpy as np
import torch
from transformers import OwlViTForObjectDetection, OwlViTProcessor

PROMPT = "a photo of a {}"


class OwlViTDetector:
    """OWL-ViT with a fixed set of text queries. Thread-safe (one forward at a time)."""

    def __init__(
        self,
        model: OwlViTForObjectDetection,
        processor: OwlViTProcessor,
        device: str,
        dtype: torch.dtype,
    ):
        self.processor = processor
        self.model = model.to(device, dtype).eval()
        self.device, self.dtype = device, dtype
        self._lock = threading.Lock()
        self._queries: torch.Tensor | None = None

    @classmethod
    def load(cls, source: str, local_only: bool, device: str, dtype: torch.dtype):
        """From a folder or a hub id (`from_pretrained`)."""
        return cls(
            OwlViTForObjectDetection.from_pretrained(source, local_files_only=local_only),
            OwlViTProcessor.from_pretrained(source, local_files_only=local_only),
            device,
            dtype,
        )

    @torch.inference_mode()
    def set_vocabulary(self, tags: list[str]) -> None:
        """Prompt the detector with these tags (text tower run once, here)."""
        tokens = self.processor.tokenizer(
            [PROMPT.format(t) for t in tags],
            padding="max_length",
            truncation=True,
            max_length=self.model.config.text_config.max_position_embeddings,
            return_tensors="pt",
        ).to(self.device)
        owlvit = self.model.owlvit
        pooled = owlvit.text_model(
            input_ids=tokens["input_ids"], attention_mask=tokens["attention_mask"]
        ).pooler_output
        with self._lock:
            self._queries = owlvit.text_projection(pooled)

    @torch.inference_mode()
    def detect(self, rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """uint8 [H, W, 3] -> boxes float32 [P, 4] (x0, y0, x1, y1 in RGB pixels), scores
        float32 [P] (sigmoid of the best query's logit) and that query's index int64 [P], for
        every one of the model's P patch boxes (filtering is the caller's)."""
        if self._queries is None:
            raise RuntimeError("set_vocabulary first")
        height, width = rgb.shape[:2]
        pixels = self.processor.image_processor(images=rgb, return_tensors="pt")["pixel_values"]
        pixels = pixels.to(self.device, self.dtype)
        with self._lock:
            feature_map, _ = self.model.image_embedder(pixel_values=pixels)
            batch, rows, cols, dim = feature_map.shape
            image_feats = feature_map.reshape(batch, rows * cols, dim)
            queries = self._queries[None]
            query_mask = torch.ones(queries.shape[:2], dtype=torch.bool, device=self.device)
            logits, _ = self.model.class_predictor(image_feats, queries, query_mask)
            boxes = self.model.box_predictor(image_feats, feature_map)
        best, query = logits[0].float().max(dim=-1)
        cx, cy, w, h = boxes[0].float().unbind(-1)  # normalised to the (unpadded) image
        xyxy = torch.stack(
            [
                (cx - w / 2) * width,
                (cy - h / 2) * height,
                (cx + w / 2) * width,
                (cy + h / 2) * height,
            ],
            dim=-1,
        )
        return (
            xyxy.cpu().numpy().astype(np.float32),
            torch.sigmoid(best).cpu().numpy().astype(np.float32),
            query.cpu().numpy(),
        )
