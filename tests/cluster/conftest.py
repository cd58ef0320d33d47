"""A real cluster for the tests: a local Ray, two map shards as detached actors, two gateways
on loopback ports, all over one PostgreSQL database of the test session's cluster.

Started once per test session (Ray and the shards take seconds to start). Tests kill and
stop shards; Ray restarts a killed one and a stopped one is continued, so the next test
finds two shards again (`Cluster.wait_for_shards`).
"""

from __future__ import annotations

import contextlib
import os
import signal
import time
from collections.abc import Iterator
from dataclasses import dataclass

import httpx
import pytest

from app.server.settings import ServerSettings

LEASE_S = 3.0
"""The shards' lease: a dead or hung shard's sessions move after about this long."""
START_TIMEOUT_S = 240.0


def pytest_collection_modifyitems(items):
    """Run in parallel (pytest-xdist), every cluster test goes to the same worker: one local
    Ray head per test session, not one per worker."""
    for item in items:
        if "tests/cluster/" in item.nodeid:
            item.add_marker(pytest.mark.xdist_group("ray"))


def poll(condition, timeout_s: float, what: str, every_s: float = 0.1):
    """condition()'s first truthy value, polled; AssertionError naming `what` past timeout_s."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"not within {timeout_s:g} s: {what}")
        time.sleep(every_s)


@dataclass
class Cluster:
    store_url: str
    gateways: list
    """ServerThreads serving the gateway app (`url`, `ws_url`)."""
    shard_count: int

    def store(self):
        from app.store import open_store

        return open_store(self.store_url)

    def live_shards(self) -> dict[str, str]:
        with self.store() as store:
            return {s.name: s.url for s in store.live_shards(LEASE_S)}

    def wait_for_shards(self, timeout_s: float = START_TIMEOUT_S) -> dict[str, str]:
        """Every shard beating and answering /healthz (after a test killed or stopped one)."""

        def all_up() -> dict[str, str] | None:
            live = self.live_shards()
            if len(live) < self.shard_count:
                return None
            for url in live.values():
                try:
                    if httpx.get(f"{url}/healthz", timeout=2).status_code != 200:
                        return None
                except httpx.HTTPError:
                    return None
            return live

        return poll(all_up, timeout_s, f"{self.shard_count} map shards up")

    def owner(self, sid: str) -> tuple[str | None, int]:
        with self.store() as store:
            rec = store.load_session(sid)
        return rec.owner, rec.epoch

    def pid(self, shard: str) -> int:
        import ray

        from app.cluster.shards import NAMESPACE

        return ray.get(ray.get_actor(shard, namespace=NAMESPACE).pid.remote(), timeout=30)

    def signal(self, shard: str, signum: int) -> int:
        pid = self.pid(shard)
        os.kill(pid, signum)
        return pid


@pytest.fixture(scope="session")
def local_ray() -> Iterator[object]:
    ray = pytest.importorskip("ray", reason="Ray is not installed (scripts/setup.sh installs it)")
    from app.cluster.shards import NAMESPACE

    ray.init(
        num_cpus=2,
        include_dashboard=False,
        object_store_memory=256 << 20,
        namespace=NAMESPACE,
        log_to_driver=False,
    )
    try:
        yield ray
    finally:
        ray.shutdown()


@pytest.fixture(scope="session")
def cluster(local_ray, pg_cluster) -> Iterator[Cluster]:
    from app.cluster.gateway import create_gateway_app
    from app.cluster.shards import start_shards, stop_shards
    from app.server.runner import ServerThread

    url = pg_cluster.url(pg_cluster.create_database("cluster"))
    common = {"host": "127.0.0.1", "store": url, "shard_lease_s": LEASE_S, "log_level": "warning"}
    start_shards(ServerSettings(port=0, shards=2, **common), timeout_s=START_TIMEOUT_S)
    gateways = [
        ServerThread(ServerSettings(port=0, **common), app_factory=create_gateway_app).start()
        for _ in range(2)
    ]
    running = Cluster(url, gateways, shard_count=2)
    try:
        running.wait_for_shards()
        yield running
    finally:
        for gateway in gateways:
            gateway.stop()
        for shard in running.live_shards():  # a stopped one would never die
            with contextlib.suppress(Exception):
                running.signal(shard, signal.SIGCONT)
        stop_shards(2)
