"""`semanticxr gateway`: one more gateway in front of a cluster's map shards (no Ray needed:
it finds the shards in the shared store). Takes the `serve` flags; --store must be the
cluster's postgresql:// URL."""

from __future__ import annotations

import argparse
from typing import Any

from app.flags import add_dataclass_flags
from app.server.settings import ServerSettings


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "gateway",
        help="run one more gateway of a cluster (started by `serve --cluster`)",
        description=(
            "Relay wire protocol v1 to the map shards of a cluster, found in its PostgreSQL "
            "store (--store). Any number of gateways can run, on any machine that reaches "
            "the store and the shards."
        ),
    )
    add_dataclass_flags(parser, ServerSettings, env_prefix="SEMANTICXR_")
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    import logging
    import sys

    from uvicorn import Server

    from app.cli.ports import check_ports
    from app.cli.serve import settings_from_args, store_reachable
    from app.cluster.gateway import create_gateway_app
    from app.server.runner import uvicorn_config

    settings = settings_from_args(args)
    if not settings.store_url.startswith(("postgresql:", "postgres:")):
        print(
            "semanticxr gateway: --store: a gateway relays to the map shards of a cluster, "
            "found in the cluster's PostgreSQL store: give --store postgresql://...",
            file=sys.stderr,
        )
        return 2
    if settings.https:
        print(
            "semanticxr gateway: --https: a gateway serves plain HTTP; put a TLS proxy in "
            "front of it",
            file=sys.stderr,
        )
        return 2
    if not check_ports("gateway", (settings.host, settings.port, "--port")):
        return 2
    logging.basicConfig(
        level=settings.log_level.upper(), format="%(levelname)s %(name)s: %(message)s"
    )
    if not store_reachable("gateway", settings):
        return 2
    print(f"SemanticXR gateway on http://{settings.host}:{settings.port}")
    Server(uvicorn_config(create_gateway_app(settings), settings)).run()
    return 0
