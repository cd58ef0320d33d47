"""Perception speed per keyframe: the `models` backend's stages, with the per-object crop
embeddings in one batch (semanticxr) against one at a time (the baseline).

    python -m bench.perception [--objects 1,4,8,16,32] [--repeats 2] [--out out/]

Full-size architectures, randomly initialised from their configs (no download; the time
does not depend on the weights' values): OWL-ViT B/32 at 768x768 prompted with the default
vocabulary, CLIP ViT-B/32's image tower at 224x224, on a 640x480 RGB-D keyframe with N
objects. On `cuda` (fp16) when a GPU is present, else the CPU. Quality needs real weights:
this measures time only.
"""

from __future__ import annotations

import os
import statistics
import time

import numpy as np

from bench.common import bench_parser, machine, write_outputs

WIDTH_PX, HEIGHT_PX, DEPTH_RATIO = 640, 480, 2


def _timed(fn, repeats: int) -> tuple[float, object]:
    """Median wall time of `fn()` in ms over `repeats` runs, and its last result."""
    times, result = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times), result


def _object_boxes(n: int, rng: np.random.Generator) -> list[tuple[int, int, int, int]]:
    """n boxes of 60-200 px at random places in the frame."""
    boxes = []
    for _ in range(n):
        w, h = rng.integers(60, 200, 2)
        x0, y0 = rng.integers(0, WIDTH_PX - w), rng.integers(0, HEIGHT_PX - h)
        boxes.append((int(x0), int(y0), int(x0 + w), int(y0 + h)))
    return boxes


def build_backend(device: str, dtype):
    """The CPU profile's backend with full-size, randomly initialised models."""
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

    from app.perception.models.backend import ModelsBackend, load_vocabulary
    from app.perception.models.detector import PROMPT, OwlViTDetector
    from app.perception.models.embedder import ClipEmbedder
    from app.perception.models.tiny import train_tokenizer
    from app.perception.models.weights import CPU_PROFILE, ModelSettings

    torch.manual_seed(0)
    vocabulary = load_vocabulary()
    words = [w for tag in vocabulary for w in PROMPT.format(tag).split()]
    # A small trained tokenizer: token ids index the full 49,408-row tables (speed is the same).
    owl_tokens, clip_tokens = train_tokenizer(words, "!"), train_tokenizer(words, "<|endoftext|>")
    owl_config, clip_config = OwlViTConfig(), CLIPConfig()  # B/32 at 768² and 224²
    for config, tokens in ((owl_config, owl_tokens), (clip_config, clip_tokens)):
        config.text_config.bos_token_id = tokens.bos_token_id
        config.text_config.eos_token_id = tokens.eos_token_id
    detector = OwlViTDetector(
        OwlViTForObjectDetection(owl_config),
        OwlViTProcessor(image_processor=OwlViTImageProcessor(), tokenizer=owl_tokens),
        device,
        dtype,
    )
    embedder = ClipEmbedder(
        CLIPModel(clip_config),
        CLIPProcessor(image_processor=CLIPImageProcessor(), tokenizer=clip_tokens),
        device,
        dtype,
        "random/clip-vit-base-patch32",
    )
    return ModelsBackend(CPU_PROFILE, detector, embedder, ModelSettings(), vocabulary)


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    os.environ.setdefault("TRANSFORMERS_VERBOSITY", "error")
    parser = bench_parser(__doc__)
    parser.add_argument("--objects", default="1,4,8,16,32", help="objects per keyframe")
    parser.add_argument("--repeats", type=int, default=2, help="runs per measurement (median)")
    parser.add_argument(
        "--detector-repeats", type=int, default=3, help="detector runs per measurement (median)"
    )
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    parser.add_argument("--out", default="out", help="folder for perception.json")
    args = parser.parse_args(argv)
    counts = [int(n) for n in args.objects.split(",") if n.strip()]

    import torch

    from app.perception.models import masks
    from app.perception.models.backend import pick_device

    if args.threads:
        torch.set_num_threads(args.threads)
    device, dtype = pick_device()
    print(f"perception bench on {device} ({dtype}), {torch.get_num_threads()} threads")
    t0 = time.perf_counter()
    backend = build_backend(device, dtype)
    build_s = time.perf_counter() - t0
    print(
        f"  built random full-size models and embedded {len(backend.vocabulary)} prompts "
        f"in {build_s:.1f} s"
    )

    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (HEIGHT_PX, WIDTH_PX, 3), np.uint8)
    depth = rng.uniform(0.5, 4.0, (HEIGHT_PX // DEPTH_RATIO, WIDTH_PX // DEPTH_RATIO))
    depth = depth.astype(np.float32)
    backend.embed([rgb[:64, :64]] * 2, batched=True)  # warm-up
    detect_ms, _ = _timed(lambda: backend.detector.detect(rgb), args.detector_repeats)
    print(f"  detect (OWL-ViT B/32, 768², {len(backend.vocabulary)} prompts): {detect_ms:.0f} ms")

    rows = []
    header = "objects  masks  crops  embed batched  embed 1-by-1  label  keyframe sxr  keyframe base  embed speed-up  keyframe speed-up"
    print(header)
    for n in counts:
        boxes = _object_boxes(n, rng)

        def mask_stage(boxes=boxes):
            full = masks.upsample_depth(depth, (WIDTH_PX, HEIGHT_PX))
            return masks.instance_image_from_boxes(full, boxes)

        masks_ms, (_, bboxes) = _timed(mask_stage, args.repeats)
        present = [b for b in bboxes if b is not None]
        crops_ms, crops = _timed(
            lambda present=present: [masks.crop_with_context(rgb, b) for b in present],
            args.repeats,
        )
        batched_ms, emb = _timed(lambda crops=crops: backend.embed(crops, True), args.repeats)
        single_ms, _ = _timed(lambda crops=crops: backend.embed(crops, False), args.repeats)
        label_ms, _ = _timed(lambda emb=emb: backend.label(emb), args.repeats)
        common = detect_ms + masks_ms + crops_ms + label_ms
        row = {
            "objects": n,
            "embedded": len(crops),
            "detect_ms": detect_ms,
            "masks_ms": masks_ms,
            "crops_ms": crops_ms,
            "embed_batched_ms": batched_ms,
            "embed_one_by_one_ms": single_ms,
            "label_ms": label_ms,
            "keyframe_semanticxr_ms": common + batched_ms,
            "keyframe_baseline_ms": common + single_ms,
            "embed_speedup": single_ms / batched_ms,
            "keyframe_speedup": (common + single_ms) / (common + batched_ms),
        }
        rows.append(row)
        print(
            f"{n:7d}  {masks_ms:5.1f}  {crops_ms:5.1f}  {batched_ms:13.0f}  {single_ms:12.0f}  "
            f"{label_ms:5.2f}  {row['keyframe_semanticxr_ms']:12.0f}  "
            f"{row['keyframe_baseline_ms']:13.0f}  {row['embed_speedup']:13.2f}x  "
            f"{row['keyframe_speedup']:16.2f}x"
        )
    print(
        "Times only: the models are randomly initialised (speed does not depend on the "
        "weights' values). Detection and label QUALITY need the real weights "
        "(semanticxr models list)."
    )
    write_outputs(
        args.out,
        "perception",
        {
            "machine": machine(),
            "device": device,
            "dtype": str(dtype),
            "threads": torch.get_num_threads(),
            "frame": {"rgb": [WIDTH_PX, HEIGHT_PX], "depth_ratio": DEPTH_RATIO},
            "models": {
                "detector": "OWL-ViT B/32 at 768x768, random weights",
                "embedder": "CLIP ViT-B/32 image tower at 224x224, random weights",
                "prompts": len(backend.vocabulary),
            },
            "repeats": args.repeats,
            "build_s": build_s,
            "rows": rows,
            "note": "time only; quality needs real weights",
        },
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
