"""The local map's scan (client_sim.local_scan): the int8 kernel, the partition and the exact
re-scoring give the exact ranking of the stored embeddings, and a query allocates nothing
that grows with the map."""

from __future__ import annotations

import gc
import tracemalloc

import numpy as np
import pytest

from app.protocol import UpsertEntry, pack_delta
from client_sim.local_map import LocalMap
from client_sim.local_scan import KERNEL_COLUMNS, ScanScratch, one_thread, padded_dim

BATCH = 5000


def upserts(ids: range, embeddings: np.ndarray) -> list[UpsertEntry]:
    """One-point objects with these embeddings (the scan reads nothing else)."""
    return [
        UpsertEntry(
            id=oid,
            version=1,
            label=f"thing {oid % 7}",
            embedding=embeddings[i],
            points=np.full((1, 3), float(i % 10), np.float16),
            bbox=(0.0, 0.0, 0.0, 1.0, 1.0, 1.0),
            n_obs=1,
        )
        for i, oid in enumerate(ids)
    ]


def random_map(n: int, dim: int, seed: int, embeddings: np.ndarray | None = None) -> LocalMap:
    """A map of n objects, ids 0..n-1, random embeddings unless given, by deltas of BATCH."""
    if embeddings is None:
        embeddings = np.random.default_rng(seed).standard_normal((n, dim))
    m = LocalMap(dim=dim, max_points_per_object=4, budget_mb=10_000)
    for seq, start in enumerate(range(0, n, BATCH), start=1):
        ids = range(start, min(n, start + BATCH))
        m.apply_delta(pack_delta(seq, upserts(ids, embeddings[start : start + len(ids)])))
    return m


def reference(m: LocalMap, query: np.ndarray) -> tuple[list[int], np.ndarray]:
    """(ids best first, equal cosines by id; their cosines) of the stored int8 rows with the
    query, in float64: what an exact scan of the whole map gives."""
    n = len(m)
    rows = m._store.embeddings[:n].astype(np.float64)
    scales = m._store.columns["scale"][:n].astype(np.float64)
    ids = m._store.columns["id"][:n]
    unit = np.asarray(query, np.float64) / np.linalg.norm(query)
    cosines = rows @ unit * scales
    order = np.lexsort((ids, -cosines))
    return ids[order].tolist(), cosines[order]


NEAR_TIE = 1e-5
"""Cosines closer than this may come in either order: float32 rounding of the scores (< 1e-6
at these dims) could swap them, so they are compared as a group."""


def assert_exact_ranking(m: LocalMap, query: np.ndarray, k: int) -> None:
    """The k hits are the reference's k best in its order, scores within float32 rounding;
    where reference cosines are within NEAR_TIE of each other, any order among them."""
    ids, cosines = reference(m, query)
    hits = m.query_embedding(query, k=k)
    group = np.concatenate(([0], np.cumsum(np.diff(cosines) < -NEAR_TIE)))
    rank = {oid: i for i, oid in enumerate(ids)}
    assert len(hits) == min(k, len(m)) == len({hit.id for hit in hits})
    assert [group[rank[hit.id]] for hit in hits] == group[: len(hits)].tolist()
    assert [hit.score for hit in hits] == pytest.approx(
        [cosines[rank[hit.id]] for hit in hits], abs=1e-6
    )
    unambiguous = np.bincount(group)[group[: len(hits)]] == 1
    assert [h.id for h, alone in zip(hits, unambiguous, strict=True) if alone] == [
        oid for oid, alone in zip(ids, unambiguous, strict=False) if alone
    ]


@pytest.mark.parametrize("dim", [256, 384, 40, 5])
@pytest.mark.parametrize("n", [1, 3, 100, 7000])
def test_a_query_ranks_as_an_exact_float_scan_of_the_stored_rows(n, dim):
    m = random_map(n, dim, seed=n + dim)
    queries = np.random.default_rng(dim).standard_normal((4, dim))

    for k in (1, 5, 20):
        for query in queries:
            assert_exact_ranking(m, query, k)


@pytest.mark.parametrize("dim", [256, 384, 40])
def test_a_query_close_to_a_stored_row_finds_it_first_among_close_rivals(dim):
    """Rows a little apart from one another near the query: the kernel's bfloat16 scores
    cannot tell them apart, the exact re-scoring does."""
    rng = np.random.default_rng(dim)
    base = rng.standard_normal(dim)
    embeddings = rng.standard_normal((3000, dim))
    embeddings[:60] = base + 0.05 * rng.standard_normal((60, dim))
    m = random_map(3000, dim, seed=0, embeddings=embeddings)

    assert_exact_ranking(m, base, k=10)
    assert_exact_ranking(m, embeddings[17], k=10)
    assert m.query_embedding(embeddings[17], k=1)[0].id == 17


@pytest.mark.parametrize("dim", [256, 384, 40])
def test_objects_sharing_one_embedding_tie_and_come_in_id_order(dim):
    rng = np.random.default_rng(7)
    embeddings = rng.standard_normal((2000, dim))
    shared = [3, *range(500, 540), 1999]  # one label's text, scattered over the rows
    embeddings[shared] = embeddings[3]
    m = random_map(2000, dim, seed=0, embeddings=embeddings)
    query = embeddings[3] + 0.3 * rng.standard_normal(dim)

    hits = m.query_embedding(query, k=30)

    assert [hit.id for hit in hits] == shared[:30]
    assert len({hit.score for hit in hits}) == 1
    ids, _ = reference(m, query)
    assert ids[:42] == shared


def test_rows_moved_by_removals_are_still_ranked_exactly():
    m = random_map(3000, 256, seed=4)
    m.apply_delta(pack_delta(2, removed=list(range(0, 3000, 7))))  # swap-removes and compacts
    m.apply_delta(pack_delta(3, removed=[5, 11, 2999]))  # a few: swap-removes

    for query in np.random.default_rng(4).standard_normal((5, 256)):
        assert_exact_ranking(m, query, k=8)


def test_k_larger_than_the_map_returns_every_object_ranked():
    m = random_map(12, 256, seed=1)
    query = np.random.default_rng(1).standard_normal(256)

    hits = m.query_embedding(query, k=50)

    assert [hit.id for hit in hits] == reference(m, query)[0]
    assert len(hits) == 12


def test_an_empty_map_and_k_below_one_answer_nothing():
    query = np.ones(256)
    assert LocalMap(dim=256).query_embedding(query, k=5) == []
    m = random_map(10, 256, seed=2)
    assert m.query_embedding(query, k=0) == []
    m.apply_delta(pack_delta(2, removed=list(range(10))))
    assert m.query_embedding(query, k=5) == []


def test_a_zero_query_scores_every_object_zero_in_id_order():
    m = random_map(30, 256, seed=3)

    hits = m.query_embedding(np.zeros(256), k=4)

    assert [hit.id for hit in hits] == [0, 1, 2, 3]
    assert [hit.score for hit in hits] == [0.0] * 4


@pytest.mark.parametrize(("dim", "bytes_per_object"), [(40, 1), (256, 4)])
def test_a_query_allocates_nothing_the_size_of_the_map(dim, bytes_per_object):
    """tracemalloc sees numpy's allocations (torch's kernel output is SCAN_CHUNK_ROWS-sized
    whatever the map): a query's peak is a few KB plus its candidates' float32 copies (the
    rows within the kernel's error of the k-th best, re-scored exactly), below a bool per
    object at 40-d and a float32 per object at 256-d (the candidates' rows weigh more)."""
    n = 40_000
    m = random_map(n, dim, seed=5)
    queries = np.random.default_rng(5).standard_normal((6, dim))
    m.query_embedding(queries[0])
    scratch = m._store.scratch
    gc.collect()

    tracemalloc.start()
    try:
        for query in queries[1:]:
            tracemalloc.reset_peak()
            before = tracemalloc.get_traced_memory()[0]
            m.query_embedding(query, k=5)
            peak = tracemalloc.get_traced_memory()[1] - before
            candidates = int(scratch.above[:n].sum())
            allowed = 8192 + candidates * dim * 13  # int8 rows, as float32, times the query
            assert allowed < bytes_per_object * n, f"{candidates} candidates: a vain check"
            assert peak < allowed, (peak, candidates)
    finally:
        tracemalloc.stop()
    assert m._store.scratch is scratch  # reused, not reallocated


def test_the_scratch_follows_the_capacity_and_is_counted_in_memory():
    m = random_map(100, 256, seed=6)
    store = m._store
    assert store.scratch.capacity == store.capacity
    held = m.memory_bytes()

    m.apply_delta(pack_delta(2, upserts(range(100, 3000), np.ones((2900, 256)))))

    assert store.scratch.capacity == store.capacity >= 3000
    assert m.memory_bytes() - held >= 2900 * ScanScratch.BYTES_PER_ROW
    assert store.row_bytes() >= padded_dim(256) + ScanScratch.BYTES_PER_ROW


def test_the_stored_matrix_is_padded_to_the_kernel_width_with_zeros():
    m = random_map(20, 40, seed=8)
    matrix = m._store.columns["embedding"]

    assert matrix.shape[1] == padded_dim(40) == 48 and 48 % KERNEL_COLUMNS == 0
    assert not matrix[:, 40:].any()
    assert m._store.embeddings.shape[1] == 40


def test_one_thread_changes_only_the_calling_threads_torch_thread_count():
    import threading

    import torch

    from client_sim import local_scan

    if local_scan._OPENMP is None:
        pytest.skip("torch runs its kernels on no OpenMP runtime here")
    outside: list[int] = []
    before = torch.get_num_threads()
    with one_thread():
        inside = torch.get_num_threads()
        other = threading.Thread(target=lambda: outside.append(torch.get_num_threads()))
        other.start()
        other.join()

    assert inside == 1
    assert outside == [before]
    assert torch.get_num_threads() == before
