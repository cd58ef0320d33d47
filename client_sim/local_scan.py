"""The local map's 8-bit embeddings: how a row is quantised and how a query scans the rows.

A row is the received unit vector divided by its largest magnitude and rounded to
[-127, 127]; its scale is 1 / the int8 row's norm, so `int8 row * scale` is exactly a unit
vector and a score is a cosine. Versus the float32 vector, a score moves by at most
scale * sum|q| / 2 (~0.002 typical at 384-d).

A query (`nearest_rows`) reads the int8 matrix once with torch's weight-only int8 kernel
(`_weight_int8pack_mm`: a bfloat16 query against the int8 rows and their bfloat16 scales, in
place) on the calling thread alone (`one_thread`), `SCAN_CHUNK_ROWS` rows a call so that torch's own output stays small, writes the
approximate scores into a `ScanScratch` that the rows keep at their capacity, finds the k-th
best by an in-place partition (no sort), and re-scores exactly in float32 only the rows
within the kernel's error bound of it: the ranking is the exact one, ties broken by id.
Nothing a query allocates grows with the map (the candidates excepted: the rows within the
bound, a handful unless many objects share one embedding).

The kernel reads 16 columns at a time, so the matrix is stored `padded_dim(dim)` wide with
zero columns (at most 15 bytes a row); exact scores read the first `dim` columns only.
"""

from __future__ import annotations

import ctypes
import glob
import os
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import torch

from app.answering.things import row_dots

KERNEL_COLUMNS = 16
"""`torch._weight_int8pack_mm` reads 16 columns at a time: the matrix is padded to it."""

SCAN_CHUNK_ROWS = 16_384
"""Rows per kernel call: torch allocates each call's bfloat16 output (32 KB), whatever the
map's size; on one thread four calls at 50,000 objects cost what one does."""

KERNEL_ERROR = 3 * 2.0**-9 + 2.0**-14
"""Bound on |kernel score - `exact_scores`| for unit rows and a unit query: the query, the
scales and the result are each rounded to bfloat16 (8 significant bits: 2^-9 each), plus
float32 accumulation in the kernel and in `exact_scores` (< 2^-15 each up to 1,024-d)."""


def _openmp() -> ctypes.CDLL | None:
    """The OpenMP runtime torch's CPU kernels run on (omp_set_num_threads, per thread), or
    None where torch uses none (another parallel backend) or it cannot be found."""
    if "OpenMP" not in torch.__config__.parallel_info().split("parallel backend:")[-1]:
        return None
    torch_lib = os.path.join(os.path.dirname(torch.__file__), "lib")
    for name in (None, *sorted(glob.glob(os.path.join(torch_lib, "lib*omp*")))):
        try:
            runtime = ctypes.CDLL(name)
            runtime.omp_set_num_threads.argtypes = [ctypes.c_int]
            runtime.omp_get_max_threads.restype = ctypes.c_int
            return runtime
        except (OSError, AttributeError):
            continue
    return None


_OPENMP = _openmp()


@contextmanager
def one_thread() -> Iterator[None]:
    """torch's kernels called in this block run on the calling thread alone (OpenMP's thread
    count is a per-thread setting: other threads keep theirs). A scan is memory-bound: a
    second thread halves it on an idle device, but on a busy one the kernel then waits for a
    descheduled thread at every call (p50 40 ms instead of 2 ms at 50,000 objects, measured
    under load), so a query never waits for another thread."""
    if _OPENMP is None:
        yield
        return
    torch.get_num_threads()  # torch sets this thread's count on first use: let it first
    before = _OPENMP.omp_get_max_threads()
    _OPENMP.omp_set_num_threads(1)
    try:
        yield
    finally:
        _OPENMP.omp_set_num_threads(before)


def padded_dim(dim: int) -> int:
    """Columns of the stored int8 matrix for `dim`-d embeddings (a multiple of 16)."""
    return -(-dim // KERNEL_COLUMNS) * KERNEL_COLUMNS


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
    """uint16 bits of finite float32 `values` rounded to bfloat16 (nearest even, as torch
    rounds)."""
    bits = np.array(values, np.float32).view(np.uint32)  # a copy, rounded in place
    bits += 0x7FFF + ((bits >> 16) & 1)  # finite: at most 0xFF807FFF, no overflow
    bits >>= 16
    return bits.astype(np.uint16)


class ScanScratch:
    """What a query writes, one slot per row of the rows' capacity, allocated when the
    capacity changes and reused by every query (`BYTES_PER_ROW` bytes a row).

    scores: float32 [capacity] the kernel's approximate scores, row by row
    kth:    float32 [capacity] a copy of them, partitioned in place to find the k-th best
    above:  bool [capacity] which rows score within the error bound of the k-th best
    """

    BYTES_PER_ROW = 4 + 4 + 1

    def __init__(self, capacity: int):
        self.scores = np.zeros(capacity, np.float32)
        self.kth = np.empty(capacity, np.float32)
        self.above = np.empty(capacity, np.bool_)
        # A bfloat16 is a float32's top half: the kernel's results are written into the
        # scores' top halves (their bottom halves stay 0), a same-type copy with no cast.
        self.score_tops = self.scores.view(np.uint16)[1 if np.little_endian else 0 :: 2]

    @property
    def capacity(self) -> int:
        return len(self.scores)

    @property
    def nbytes(self) -> int:
        return self.scores.nbytes + self.kth.nbytes + self.above.nbytes


def exact_scores(
    embeddings: np.ndarray, scales: np.ndarray, rows: np.ndarray, query: np.ndarray
) -> np.ndarray:
    """float32 [m]: cosines of `rows` (int [m]) of int8 `embeddings` [., d] with their
    float32 `scales` with the unit float32 `query` [d], each row on its own
    (app.answering.things.row_dots: a matrix product's rounding depends on where a row sits,
    so copies of one embedding would not tie exactly and their order would not be by id)."""
    return (
        row_dots(embeddings[rows].astype(np.float32), np.asarray(query, np.float32)) * scales[rows]
    )


def approximate_scores(
    embeddings_t: torch.Tensor,
    scales_bf16_t: torch.Tensor,
    n: int,
    query: np.ndarray,
    scratch: ScanScratch,
) -> np.ndarray:
    """float32 [n] scores (a view of `scratch.scores`) of the first n rows against the unit
    `query` [d], each within `KERNEL_ERROR` of `exact_scores`. `embeddings_t` [capacity,
    padded_dim(d)] and `scales_bf16_t` are torch views of the int8 rows and of their scales'
    bfloat16 bits; the kernel reads them in place."""
    padded = np.zeros(embeddings_t.shape[1], np.float32)
    padded[: len(query)] = query
    # torch only for the kernel: its small element-wise ops wake the thread pool, which
    # costs milliseconds on a busy device; the rest is numpy.
    query_bf16 = torch.from_numpy(bfloat16_bits(padded)).view(torch.bfloat16)[None]
    tops = scratch.score_tops
    with one_thread():
        for start in range(0, n, SCAN_CHUNK_ROWS):
            stop = min(n, start + SCAN_CHUNK_ROWS)
            scores = torch._weight_int8pack_mm(
                query_bf16, embeddings_t[start:stop], scales_bf16_t[start:stop]
            )
            tops[start:stop] = scores.view(torch.int16).numpy().view(np.uint16)[0]
    return scratch.scores[:n]


def nearest_rows(
    embeddings: np.ndarray,
    scales: np.ndarray,
    ids: np.ndarray,
    embeddings_t: torch.Tensor,
    scales_bf16_t: torch.Tensor,
    n: int,
    query: np.ndarray,
    k: int,
    scratch: ScanScratch,
) -> tuple[np.ndarray, np.ndarray]:
    """(rows int64 [min(k, n)], their exact float32 cosines) of the first n rows most similar
    to the unit float32 `query` [d], best first, equal cosines by ascending id.

    embeddings: int8 [capacity, d] (the stored matrix's first d columns); scales: float32
    [capacity]; ids: int64 [capacity]; the torch views and `scratch` as `approximate_scores`.
    """
    if n == 0 or k < 1:
        return np.empty(0, np.int64), np.empty(0, np.float32)
    scores = approximate_scores(embeddings_t, scales_bf16_t, n, query, scratch)
    # Every row of the exact top k scores within 2 * KERNEL_ERROR of the approximate k-th
    # best, so re-scoring those rows exactly gives the exact ranking.
    at = n - min(n, k)
    kth = scratch.kth[:n]
    np.copyto(kth, scores)
    kth.partition(at)
    above = np.greater_equal(scores, kth[at] - 2 * KERNEL_ERROR, out=scratch.above[:n])
    candidates = np.flatnonzero(above)
    exact = exact_scores(embeddings, scales, candidates, query)
    best = np.lexsort((ids[candidates], -exact))[:k]
    return candidates[best], exact[best]
