"""A running server maps with numpy's BLAS on one thread (its own threads would spin)."""

from __future__ import annotations

from threadpoolctl import threadpool_info


def _blas_threads() -> list[int]:
    return [pool["num_threads"] for pool in threadpool_info() if pool["internal_api"] == "openblas"]


def test_the_servers_workers_use_numpy_blas_on_one_thread(live_server):
    manager = live_server().app.state.manager
    for pool in (manager.pool, manager.decode_pool):
        threads = pool.submit(_blas_threads).result(timeout=10)
        assert threads and set(threads) == {1}
