"""A running server maps with numpy's BLAS on one thread (its own threads would spin)."""

from __future__ import annotations

from threadpoolctl import ThreadpoolController, threadpool_info


def test_a_started_server_limits_numpy_blas_to_one_thread(live_server):
    ThreadpoolController().select(internal_api="openblas").limit(limits=2)  # as a fresh process
    live_server()
    blas = [pool for pool in threadpool_info() if pool["internal_api"] == "openblas"]
    assert blas and all(pool["num_threads"] == 1 for pool in blas)
