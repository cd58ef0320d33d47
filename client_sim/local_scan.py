"""The local map's 8-bit embeddings: how a row is quantised and how rows are scored.

A row is the received unit vector divided by its largest magnitude and rounded to
[-127, 127]; its scale is 1 / the int8 row's norm, so `int8 row * scale` is exactly a unit
vector and a score is a cosine. Versus the float32 vector, a score moves by at most
scale * sum|q| / 2 (~0.002 typical at 384-d). Similarity is torch's weight-only int8 kernel
(`_weight_int8pack_mm`: a bfloat16 query against the int8 rows and their scales, read in
place); the caller re-scores the candidates within its error bound exactly in float32. For
dimensions the kernel does not take (not a multiple of 16) the rows are scored in float32
chunks instead.
"""

from __future__ import annotations

import numpy as np
import torch

from app.answering.things import row_dots

_KERNEL_MIN_DIM_MULTIPLE = 16
"""`torch._weight_int8pack_mm` reads 16 columns at a time: other widths give garbage."""

_KERNEL_ERROR = 3 * 2.0**-9
"""Bound on |kernel score - exact float32 score| for unit rows and a unit query: the query,
the scales and the result are each rounded to bfloat16 (8 significant bits)."""

_FALLBACK_ERROR = 1e-5
"""Bound on float32 rounding differences between a chunked and a per-candidate score."""

_FALLBACK_CHUNK_ROWS = 4096
"""Rows converted to float32 at a time when the int8 kernel cannot be used (~6 MB at 384-d)."""


def quantise_embeddings(embeddings: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(int8 [m, d], float32 [m] scales) of float [m, d] rows: `int8 * scale` is the row's
    direction as an exact unit vector (zero rows: zero and scale 0).

    Each row is divided by its largest magnitude and rounded to [-127, 127], so every row
    uses the whole 8-bit range whatever its spread.
    """
    as32 = np.asarray(embeddings, np.float32)
    peak = np.abs(as32).max(axis=1, keepdims=True) if as32.size else np.zeros((len(as32), 1))
    with np.errstate(divide="ignore", invalid="ignore"):
        levels = np.where(peak > 0, as32 / peak, 0.0) * 127
    quantised = np.clip(np.rint(levels), -127, 127).astype(np.int8)
    norms = np.linalg.norm(quantised.astype(np.float32), axis=1)
    scales = np.where(norms > 0, 1 / np.maximum(norms, 1e-12), 0).astype(np.float32)
    return quantised, scales


def bfloat16_bits(values: np.ndarray) -> np.ndarray:
    """uint16 bits of float32 `values` rounded to bfloat16 (nearest even, as torch does)."""
    rounded = torch.from_numpy(np.ascontiguousarray(values, np.float32)).to(torch.bfloat16)
    return rounded.view(torch.int16).numpy().view(np.uint16)


def float32_of_bfloat16(values: torch.Tensor) -> np.ndarray:
    """float32 numpy of a bfloat16 tensor, exactly (a bfloat16 is a float32's top half)."""
    bits = values.view(torch.int16).numpy().view(np.uint16)
    return (bits.astype(np.uint32) << 16).view(np.float32)


def exact_scores(
    embeddings: np.ndarray, scales: np.ndarray, rows: np.ndarray, query: np.ndarray
) -> np.ndarray:
    """float32 cosines of `rows` (int [m]) of int8 `embeddings` with their float32 `scales`
    with the unit float32 `query`."""
    return (embeddings[rows].astype(np.float32) @ query) * scales[rows]


def approximate_scores(
    embeddings: np.ndarray,
    scales: np.ndarray,
    embeddings_t: torch.Tensor,
    scales_bf16_t: torch.Tensor,
    n: int,
    query: np.ndarray,
) -> tuple[np.ndarray, float]:
    """(float32 [n] scores of the first n rows against the unit `query`, bound on their
    error against `exact_scores`). `embeddings_t` and `scales_bf16_t` are torch views of the
    int8 rows and of their scales' bfloat16 bits (the kernel reads them in place)."""
    dim = embeddings.shape[1]
    if dim % _KERNEL_MIN_DIM_MULTIPLE == 0 and hasattr(torch, "_weight_int8pack_mm"):
        # torch only for the kernel: its small element-wise ops wake the thread pool,
        # which costs milliseconds on a busy device; the rest is numpy.
        scales_bf16 = scales_bf16_t[:n]
        query_bf16 = torch.from_numpy(query).to(torch.bfloat16)[None]
        scores = torch._weight_int8pack_mm(query_bf16, embeddings_t[:n], scales_bf16)
        return float32_of_bfloat16(scores[0]), _KERNEL_ERROR
    out = np.empty(n, np.float32)
    for start in range(0, n, _FALLBACK_CHUNK_ROWS):
        rows = np.arange(start, min(n, start + _FALLBACK_CHUNK_ROWS))
        out[rows] = exact_scores(embeddings, scales, rows, query)
    return out, _FALLBACK_ERROR


def row_cosines(
    embeddings: np.ndarray, scales: np.ndarray, rows: np.ndarray, query: np.ndarray
) -> np.ndarray:
    """float32 [m]: cosines of `rows` with the unit `query`, each row on its own
    (app.answering.things.row_dots: copies with one embedding tie exactly)."""
    return (
        row_dots(embeddings[rows].astype(np.float32), np.asarray(query, np.float32)) * scales[rows]
    )
