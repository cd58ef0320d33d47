"""The `models` backend: pixels -> open-vocabulary detections with CLIP embeddings.

Per keyframe (CPU profile): OWL-ViT boxes prompted with the vocabulary -> depth-mode masks
-> crops with context -> CLIP image embeddings, one batch for the keyframe's objects
(semanticxr) or one crop at a time (baseline) -> labels by the best vocabulary match.
"""

from __future__ import annotations

import copy
import logging
import threading
import time
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np
import torch

from app.config import Mode
from app.perception.base import Detection, FrameDetections, FrameInput, PerceptionBackend
from app.perception.models import masks
from app.perception.models.detector import PROMPT, OwlViTDetector
from app.perception.models.embedder import ClipEmbedder, ClipTextEncoder
from app.perception.models.weights import (
    CPU_PROFILE,
    MissingModelsError,
    ModelSettings,
    Profile,
    load_settings,
    missing_models_message,
    resolve_models,
)

log = logging.getLogger("semanticxr.perception")


def load_vocabulary(path: str | None = None) -> list[str]:
    """Tags, one a line ('#' comments and blank lines skipped); the packaged indoor
    vocabulary (`vocabulary.txt`) without a path."""
    if path is None:
        text = resources.files(__package__).joinpath("vocabulary.txt").read_text("utf-8")
    else:
        text = Path(path).read_text("utf-8")
    tags = [line.split("#", 1)[0].strip() for line in text.splitlines()]
    tags = list(dict.fromkeys(t for t in tags if t))
    if not tags:
        raise ValueError(f"vocabulary {path or 'vocabulary.txt'} has no tags")
    return tags


@dataclass
class Proposals:
    """One keyframe's boxes, best first, and their masks as an instance image.

    instance_image: uint16 [H, W]; proposal i is id i + 1
    bboxes_px:      per proposal, the mask's (x0, y0, x1, y1), None when the mask is empty
    """

    scores: np.ndarray
    instance_image: np.ndarray
    bboxes_px: list[tuple[int, int, int, int] | None]


class ModelsBackend(PerceptionBackend):
    """Detections from the RGB-D keyframe itself (no device detections needed).

    One instance (the models) serves every session; `for_mode` gives a session a view
    that organises the per-object embedding its way, sharing the loaded models.
    """

    name = "models"
    needs_rgb = True

    def __init__(
        self,
        profile: Profile,
        detector: OwlViTDetector,
        embedder: ClipEmbedder,
        settings: ModelSettings,
        vocabulary: list[str],
    ):
        self.profile = profile
        self.detector = detector
        self.embedder = embedder
        self.settings = settings
        self.vocabulary = vocabulary
        self.batched = True
        """Embed a keyframe's crops in one batch (semanticxr) or one at a time (baseline)."""
        self.text_encoder = ClipTextEncoder(embedder)
        """The sessions' query encoder: the text tower of the image embedder."""
        detector.set_vocabulary(vocabulary)
        self.vocabulary_embeddings = embedder.embed_texts([PROMPT.format(t) for t in vocabulary])
        """float32 [len(vocabulary), dim] unit rows, the labels' side of the match."""

    def for_mode(self, mode: Mode) -> ModelsBackend:
        view = copy.copy(self)
        view.batched = mode == "semanticxr"
        return view

    # ------------------------------------------------------------------ stages
    def propose(self, frame: FrameInput) -> Proposals:
        """Boxes above the threshold, de-duplicated, best first, capped; depth-mode masks."""
        boxes, scores, _ = self.detector.detect(frame.rgb)
        keep = np.flatnonzero(scores >= self.settings.detection_threshold)
        keep = keep[masks.nms(boxes[keep], scores[keep], self.settings.nms_iou)]
        keep = keep[: self.settings.max_objects]
        pixel_boxes = [masks.box_to_pixels(boxes[i], frame.rgb_size) for i in keep]
        depth = masks.upsample_depth(frame.depth_m, frame.rgb_size)
        instance, bboxes = masks.instance_image_from_boxes(depth, pixel_boxes)
        return Proposals(scores[keep], instance, bboxes)

    def embed(self, crops: list[np.ndarray], batched: bool | None = None) -> np.ndarray:
        """float32 [n, dim] unit image embeddings of the crops, organised per `batched`
        (default: this view's organisation)."""
        batched = self.batched if batched is None else batched
        if batched:
            return self.embedder.embed_crops_batched(crops)
        return self.embedder.embed_crops_one_by_one(crops)

    def label(self, embeddings: np.ndarray) -> tuple[list[str], np.ndarray]:
        """The best vocabulary tag of each embedding and its zero-shot probability (CLIP's
        softmax over the vocabulary)."""
        logits = self.embedder.logit_scale * (embeddings @ self.vocabulary_embeddings.T)
        best = logits.argmax(axis=1)
        logits = logits - logits.max(axis=1, keepdims=True)
        probs = np.exp(logits) / np.exp(logits).sum(axis=1, keepdims=True)
        return [self.vocabulary[i] for i in best], probs[np.arange(len(best)), best]

    # ------------------------------------------------------------------ the interface
    def detect(self, frame: FrameInput, sent: FrameDetections | None) -> FrameDetections:
        """Detections from the keyframe's pixels; what the device sent is not used."""
        proposals = self.propose(frame)
        present = [i for i, b in enumerate(proposals.bboxes_px) if b is not None]
        crops = [masks.crop_with_context(frame.rgb, proposals.bboxes_px[i]) for i in present]
        embeddings = self.embed(crops)
        labels, scores = self.label(embeddings)
        detections = [
            Detection(i + 1, label, float(score), proposals.bboxes_px[i], embedding)
            for i, label, score, embedding in zip(present, labels, scores, embeddings, strict=True)
        ]
        return FrameDetections(proposals.instance_image, detections)


def pick_device() -> tuple[str, torch.dtype]:
    """cuda in fp16 when a GPU is present, else the CPU in fp32."""
    if torch.cuda.is_available():
        return "cuda", torch.float16
    return "cpu", torch.float32


_loaded: dict[tuple, ModelsBackend] = {}
_loaded_lock = threading.Lock()


def load_models_backend(
    models_dir: str | None,
    profile: Profile = CPU_PROFILE,
    models: tuple[OwlViTDetector, ClipEmbedder] | None = None,
) -> ModelsBackend:
    """The backend with its models loaded, once per process for the same models_dir and
    profile (the CLI loads them before serving; the server's sessions then share them).

    With `models` (a detector and an embedder made elsewhere, with their methods: a map
    shard's, which call the cluster's models deployment), nothing is loaded here: the
    backend is made on them and replaces this process's one for models_dir and profile.

    MissingModelsError (before any model loads) when a model is not where it must come
    from; the message names the folders and the commands that fetch them.
    """
    key = (str(Path(models_dir).resolve()) if models_dir else None, profile.name)
    with _loaded_lock:
        if models is not None:
            settings = load_settings(models_dir)
            vocabulary = load_vocabulary(settings.vocabulary)
            _loaded[key] = ModelsBackend(profile, *models, settings, vocabulary)
            return _loaded[key]
        if key in _loaded:
            return _loaded[key]
        resolved = resolve_models(profile, models_dir)
        settings = load_settings(models_dir)
        vocabulary = load_vocabulary(settings.vocabulary)
        device, dtype = pick_device()
        t0 = time.perf_counter()
        det, emb = resolved["detector"], resolved["embedder"]
        from transformers.utils import logging as hf_logging

        hf_logging.disable_progress_bar()
        hf_logging.set_verbosity_error()  # not the torchvision fallback notice at every load
        try:
            detector = OwlViTDetector.load(det.source, det.local_only, device, dtype)
            embedder = ClipEmbedder.load(emb.source, emb.local_only, device, dtype, emb.model_id)
        except OSError as exc:  # not on the hub, no network, or an incomplete folder
            raise MissingModelsError(
                f"perception 'models' could not load its models: {exc}\n"
                + missing_models_message(profile, models_dir, profile.models)
            ) from None
        backend = ModelsBackend(profile, detector, embedder, settings, vocabulary)
        log.info(
            "perception 'models' (%s profile) loaded on %s in %.1f s: %s, %s; %d tags",
            profile.name,
            device,
            time.perf_counter() - t0,
            det.model_id,
            emb.model_id,
            len(vocabulary),
        )
        _loaded[key] = backend
        return backend
