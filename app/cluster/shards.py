"""Map shards as named, detached Ray actors (`mapshard-0` ... `mapshard-N-1`).

Each actor runs a whole SemanticXR server in its process with `shard_name` set: it claims
the sessions it loads in the shared PostgreSQL store, commits under that claim, beats every
second with the address gateways reach it at, and serves many sessions at once. Ray restarts
an actor whose process dies (`max_restarts=-1`); the new incarnation beats under the same
name at a new address, and its sessions are claimed again by whichever live shard the
gateways route them to. Ray imports only here and in `serve_models.py` (the shards' shared
`models` backend): a gateway and a standalone server never need it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
from collections.abc import Mapping

from app.server.settings import ServerSettings

log = logging.getLogger("semanticxr.cluster")

NAMESPACE = "semanticxr"
"""The Ray namespace the shards are named in (so any driver finds them by name)."""
SHARD_PREFIX = "mapshard-"
WILDCARD_HOSTS = ("0.0.0.0", "::", "")


class ClusterError(RuntimeError):
    """The cluster cannot be reached or the shards cannot start; the message names the flag."""


def shard_names(n: int) -> list[str]:
    return [f"{SHARD_PREFIX}{i}" for i in range(n)]


def _ray():
    try:
        import ray
    except ImportError as exc:  # pragma: no cover - ray is a dependency
        raise ClusterError(f"--cluster needs Ray (pip install ray): {exc}") from None
    return ray


def connect(cluster: str, num_cpus: int | None = None) -> None:
    """Join the Ray cluster `cluster` names: 'auto' (the local one `ray start --head`
    runs, else a new local one), or an address such as ray://HOST:10001. ClusterError naming
    --cluster when it cannot be reached."""
    ray = _ray()
    if ray.is_initialized():
        return
    try:
        if cluster == "auto":
            try:
                ray.init(address="auto", namespace=NAMESPACE, log_to_driver=False)
            except (ConnectionError, RuntimeError):
                ray.init(
                    namespace=NAMESPACE,
                    num_cpus=num_cpus,
                    include_dashboard=False,
                    object_store_memory=256 << 20,
                    log_to_driver=False,
                )
        else:
            ray.init(address=cluster, namespace=NAMESPACE, log_to_driver=False)
    except Exception as exc:
        raise ClusterError(
            f"--cluster {cluster}: cannot join that Ray cluster ({type(exc).__name__}: {exc}); "
            f"give 'auto' for a local one, or the ray:// address of a running head"
        ) from None


def _actor_class():
    ray = _ray()

    @ray.remote(max_restarts=-1, max_task_retries=0, num_cpus=0)
    class MapShard:
        """One map shard: a SemanticXR server with `shard_name` set, in this actor's process."""

        def __init__(self, name: str, fields: Mapping[str, object]):
            os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch loads
            logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
            from app.server.runner import ServerThread, free_port

            host = str(fields["host"])
            port = free_port(host)
            # A wildcard bind is reached at this node's address (gateways may run elsewhere).
            reached_at = ray.util.get_node_ip_address() if host in WILDCARD_HOSTS else host
            settings = ServerSettings(
                **{**fields, "shard_name": name, "port": port},
                shard_url=f"http://{reached_at}:{port}",
            )
            if settings.models_service is not None:  # the cluster's models, not its own
                from app.cluster.serve_models import use_models_service

                use_models_service(settings.models_dir, settings.models_service)
            self.server = ServerThread(settings).start(timeout_s=300)
            self.name = name

        def address(self) -> str:
            return self.server.url

        def pid(self) -> int:
            return os.getpid()

    return MapShard


def shard_fields(settings: ServerSettings) -> dict[str, object]:
    """What a shard is started with: the gateway's settings but its own bind (loopback on
    its node unless --shard-host says otherwise) and none of the cluster flags."""
    fields = dataclasses.asdict(settings)
    for gateway_only in ("cluster", "shards", "shard_name", "shard_url", "port"):
        fields.pop(gateway_only)
    return fields


def start_shards(settings: ServerSettings, timeout_s: float = 300.0) -> list:
    """Start (or find, when they run already) the `settings.shards` map shards as detached
    actors and wait until each serves; their handles. ClusterError when one cannot start."""
    ray = _ray()
    cls = _actor_class()
    fields = shard_fields(settings)
    handles = [
        cls.options(name=name, namespace=NAMESPACE, lifetime="detached", get_if_exists=True).remote(
            name, fields
        )
        for name in shard_names(settings.shards)
    ]
    try:
        addresses = ray.get([h.address.remote() for h in handles], timeout=timeout_s)
    except Exception as exc:
        raise ClusterError(
            f"--shards {settings.shards}: the map shards did not start within {timeout_s:.0f} s "
            f"({type(exc).__name__}: {exc})"
        ) from None
    for name, address in zip(shard_names(settings.shards), addresses, strict=True):
        log.info("map shard %s serves at %s", name, address)
    return handles


def stop_shards(n: int) -> None:
    """Kill the shards mapshard-0..n-1 for good (no restart)."""
    ray = _ray()
    for name in shard_names(n):
        with contextlib.suppress(ValueError):  # not running
            ray.kill(ray.get_actor(name, namespace=NAMESPACE), no_restart=True)
