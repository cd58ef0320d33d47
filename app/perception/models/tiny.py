"""Small randomly initialised models of the `models` backend's architectures, offline.

`write_tiny_models(DIR)` writes, in exactly the layout `--models-dir DIR` expects, an OWL-ViT
and a CLIP with 2-layer, 32-wide towers on 64x64 images, with their processors and a
byte-level BPE tokenizer trained here on the vocabulary's words. They run the real loading
and inference code in seconds; their outputs mean nothing (random weights).
"""

from __future__ import annotations

import json
from pathlib import Path

from app.perception.models.weights import CPU_PROFILE, MODEL_ID_FILE, SETTINGS_FILE, Profile

IMAGE_PX = 64
WIDTH = 32
LAYERS = 2
TEXT_POSITIONS = 16
BPE_VOCAB_SIZE = 400
TINY_PREFIX = "tiny-random/"
"""Tiny models announce `tiny-random/<folder>`, so they never pass for the real weights."""


def train_tokenizer(words: list[str], pad_token: str):
    """A CLIPTokenizer over a byte-level BPE trained on `words`; its specials get the
    highest ids (as in CLIP, where the text tower pools at the end-of-text token)."""
    from tokenizers import Tokenizer, models, normalizers, pre_tokenizers, trainers
    from transformers import CLIPTokenizer

    bpe = Tokenizer(models.BPE(continuing_subword_prefix="", end_of_word_suffix="</w>"))
    bpe.normalizer = normalizers.Lowercase()
    bpe.pre_tokenizer = pre_tokenizers.ByteLevel(add_prefix_space=False)
    trainer = trainers.BpeTrainer(
        vocab_size=BPE_VOCAB_SIZE,
        initial_alphabet=pre_tokenizers.ByteLevel.alphabet(),
        end_of_word_suffix="</w>",
        show_progress=False,
    )
    bpe.train_from_iterator(words, trainer)
    model = json.loads(bpe.to_str())["model"]
    vocab: dict[str, int] = dict(model["vocab"])
    for special in ("<|startoftext|>", "<|endoftext|>"):
        vocab[special] = len(vocab)
    merges = [tuple(m) if isinstance(m, list) else tuple(m.split()) for m in model["merges"]]
    return CLIPTokenizer(vocab=vocab, merges=merges, pad_token=pad_token)


def _text_config(tokenizer) -> dict:
    return {
        "vocab_size": len(tokenizer),
        "hidden_size": WIDTH,
        "intermediate_size": 2 * WIDTH,
        "num_hidden_layers": LAYERS,
        "num_attention_heads": 2,
        "max_position_embeddings": TEXT_POSITIONS,
        "bos_token_id": tokenizer.bos_token_id,
        "eos_token_id": tokenizer.eos_token_id,
        "pad_token_id": tokenizer.pad_token_id,
    }


def _vision_config(patch_px: int) -> dict:
    return {
        "hidden_size": WIDTH,
        "intermediate_size": 2 * WIDTH,
        "num_hidden_layers": LAYERS,
        "num_attention_heads": 2,
        "image_size": IMAGE_PX,
        "patch_size": patch_px,
    }


def write_tiny_models(out: str | Path, profile: Profile = CPU_PROFILE, seed: int = 0) -> Path:
    """Write the profile's models, tiny and random, into out/<folder>, plus out/semanticxr.json
    (threshold 0, so random boxes still become detections). Returns out."""
    import torch
    from transformers import (
        CLIPConfig,
        CLIPImageProcessor,
        CLIPModel,
        CLIPProcessor,
        OwlViTConfig,
        OwlViTForObjectDetection,
        OwlViTImageProcessor,
        OwlViTProcessor,
    )
    from transformers.utils import logging as hf_logging

    from app.perception.models.backend import load_vocabulary
    from app.perception.models.detector import PROMPT

    hf_logging.disable_progress_bar()
    hf_logging.set_verbosity_error()  # not the torchvision fallback notice

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(seed)
    tags = load_vocabulary()
    words = [w for tag in tags for w in PROMPT.format(tag).split()] * 2

    # OWL-ViT pads with "!" (id 0 here too): a query whose first token is 0 counts as padding.
    owl_tokenizer = train_tokenizer(words, pad_token="!")
    owl_config = OwlViTConfig(
        text_config=_text_config(owl_tokenizer),
        vision_config=_vision_config(patch_px=16),
        projection_dim=WIDTH,
    )
    owl_dir = out / profile.detector.folder
    detector = OwlViTForObjectDetection(owl_config).eval()
    with torch.no_grad():  # random box offsets saturate the sigmoid into empty boxes: damp
        detector.box_head.dense2.weight.mul_(0.01)  # them, so boxes sit near their patches
        detector.box_head.dense2.bias.zero_()
    detector.save_pretrained(owl_dir)
    size = {"height": IMAGE_PX, "width": IMAGE_PX}
    OwlViTProcessor(
        image_processor=OwlViTImageProcessor(size=size, crop_size=size),
        tokenizer=owl_tokenizer,
    ).save_pretrained(owl_dir)

    clip_tokenizer = train_tokenizer(words, pad_token="<|endoftext|>")
    clip_config = CLIPConfig(
        text_config=_text_config(clip_tokenizer),
        vision_config=_vision_config(patch_px=16),
        projection_dim=WIDTH,
    )
    clip_dir = out / profile.embedder.folder
    CLIPModel(clip_config).eval().save_pretrained(clip_dir)
    CLIPProcessor(
        image_processor=CLIPImageProcessor(
            size={"shortest_edge": IMAGE_PX}, crop_size={"height": IMAGE_PX, "width": IMAGE_PX}
        ),
        tokenizer=clip_tokenizer,
    ).save_pretrained(clip_dir)

    for spec in profile.models:
        (out / spec.folder / MODEL_ID_FILE).write_text(TINY_PREFIX + spec.folder + "\n")
    (out / SETTINGS_FILE).write_text(json.dumps({"detection_threshold": 0.0}, indent=2) + "\n")
    return out
