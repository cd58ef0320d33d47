"""`semanticxr serve`: the server. One flag per ServerSettings field, generated (help from
the field's docstring), so a new setting gets its flag for free; a flag overrides the
SEMANTICXR_<FIELD> environment variable, which overrides the default."""

from __future__ import annotations

import argparse
import dataclasses
from typing import TYPE_CHECKING, Any

from app.flags import add_dataclass_flags
from app.server.settings import ServerSettings

if TYPE_CHECKING:
    from app.server.tls import Certificate


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "serve",
        help="run the SemanticXR server (REST + WebSockets, wire protocol v1)",
        description="Serve the wire protocol v1. Flags override SEMANTICXR_* environment variables.",
    )
    add_dataclass_flags(parser, ServerSettings, env_prefix="SEMANTICXR_")
    parser.set_defaults(func=run)
    return parser


def settings_from_args(args: argparse.Namespace) -> ServerSettings:
    """Defaults, then SEMANTICXR_* variables, then the flags given (SettingsError names a bad
    value)."""
    flags = {f.name: getattr(args, f.name, None) for f in dataclasses.fields(ServerSettings)}
    return ServerSettings.from_env(**flags)


def load_backends(settings: ServerSettings) -> None:
    """Load the perception backends `settings` names before the server binds its port (they
    are loaded once per process; the server's sessions then share them), so a missing model
    stops `serve` with its fix, and the server never starts half-working."""
    from app.perception import BackendOptions, make_backend

    for name in settings.perception_backends:
        make_backend(name, BackendOptions(models_dir=settings.models_dir))


SERVER_OMP_WAIT_POLICY = "PASSIVE"
"""How torch's OpenMP threads wait between parallel regions in a server (unless the
environment says otherwise). Spinning ("ACTIVE", libgomp's default) burns the core that
mapping needs after every label or query encoding: at 8 paced devices the server spent 11.0
ms of CPU a frame spinning, 8.6 passive, and acked keyframes at p50 98 against 62 ms
(`python -m bench.load --devices 8`). A query encodes in 11 ms instead of 7.6."""


def run(args: argparse.Namespace) -> int:
    import logging
    import os
    import sys

    # before torch (the text encoder) loads libgomp, which reads it once
    os.environ.setdefault("OMP_WAIT_POLICY", SERVER_OMP_WAIT_POLICY)

    from uvicorn import Server

    from app.cli.ports import check_ports
    from app.perception.models.weights import MissingModelsError
    from app.server.app import create_app
    from app.server.runner import tls_ready, uvicorn_config
    from app.server.tls import TlsError
    from app.server.towers import TowerFileError, read_tower_file
    from app.speech import AsrSettingError, check_asr

    settings = settings_from_args(args)
    if not check_ports("serve", (settings.host, settings.port, "--port")):
        return 2
    logging.basicConfig(
        level=settings.log_level.upper(), format="%(levelname)s %(name)s: %(message)s"
    )
    if settings.cluster is not None:
        return run_cluster(settings)
    try:
        check_asr(settings.asr)  # before any model loads: a missing Whisper stops us at once
        load_backends(settings)
        if settings.static_tower is not None:  # a bad file stops us before the port binds
            from app.semantics import DEFAULT_MODEL_ID

            read_tower_file(settings.static_tower, DEFAULT_MODEL_ID)
        settings, certificate = tls_ready(settings)
    except (MissingModelsError, TlsError, AsrSettingError, TowerFileError) as exc:
        print(f"semanticxr serve: {exc}", file=sys.stderr)
        return 2
    if certificate is None:
        print(
            f"SemanticXR on http://{settings.host}:{settings.port}  (data in {settings.data_dir})"
        )
    else:
        print(https_banner(settings, certificate, color=sys.stdout.isatty()), flush=True)
    server = Server(uvicorn_config(create_app(settings), settings))
    server.run()
    return _exit_code(server)


def https_banner(settings: ServerSettings, certificate: Certificate, color: bool = False) -> str:
    """What `serve --https` says at start: where it serves, the real-device page's URL
    (`https://<LAN address>:<port>/xr`) and a QR code of it (nothing secret: no key, no
    token), what a phone will say of a self-signed certificate, and the clients' --tls-ca.
    color: draw the code in ANSI white on black (a terminal with a light theme)."""
    from app.server.edges import LOOPBACK_HOSTS, WILDCARD_BINDS
    from app.server.tls import page_host, url_host

    host = page_host(settings.host, certificate.names)
    origin = f"https://{url_host(host)}:{settings.port}"
    wildcard = settings.host in WILDCARD_BINDS
    where = "every interface, IPv4 and IPv6" if settings.host == "" else settings.host
    lines = [f"SemanticXR on {origin}  (listening on {where}; data in {settings.data_dir})"]
    if settings.host in LOOPBACK_HOSTS:
        lines.append("  this machine only: leave out --host for a phone on the network to reach it")
    lines += [
        f"Open this on a phone on the same network: {origin}/xr",
        qr_text(f"{origin}/xr", color),
    ]
    others = [
        f"https://{url_host(name)}:{settings.port}/xr"
        for name in certificate.names
        if wildcard and name not in (host, *LOOPBACK_HOSTS) and not name.startswith("*")
    ]
    if others:
        lines.append(f"  also: {', '.join(others)}")
    if certificate.self_signed:
        state = "made now" if certificate.made else "reused"
        lines.append(
            "The phone will warn that the connection is not private (this server's own "
            f"certificate, {state}): proceed once (Chrome: Advanced, Proceed; Safari: Show "
            "Details, visit this website)."
        )
    lines.append(f"Python clients: --tls-ca {certificate.cert_path}")
    return "\n".join(lines)


def qr_text(text: str, color: bool = False) -> str:
    """`text` as a QR code in half-block characters (two rows of modules a line, with its
    quiet zone), the light modules drawn, as a dark terminal shows them; color: in ANSI
    white on black, so that a light theme shows it the same."""
    import io

    import segno

    out = io.StringIO()
    segno.make(text, error="m", micro=False).terminal(out=out, compact=True)
    lines = out.getvalue().splitlines()
    if color:
        lines = [f"\x1b[97;40m{line}\x1b[0m" for line in lines]
    return "\n".join(lines)


def run_cluster(settings: ServerSettings) -> int:
    """`serve --cluster`: join (or start) the Ray cluster, start the models deployment when
    --perception includes models (the shards call it: `app/cluster/serve_models.py`), start
    the map shards as detached actors, then serve the gateway on --port until Ctrl-C. Shards
    of a local cluster this command started stop with it; on a cluster that was already
    running they stay up for the other gateways (stop them with `ray stop`, or this command
    with --shards on a fresh cluster)."""
    import sys

    from uvicorn import Server

    from app.cluster.gateway import create_gateway_app
    from app.cluster.serve_models import ModelsDeploymentError, start_models
    from app.cluster.shards import ClusterError, connect, start_shards
    from app.server.runner import uvicorn_config

    if not store_reachable("serve", settings):  # before any shard starts
        return 2
    try:
        connect(settings.cluster)
        if "models" in settings.perception_backends:
            settings = dataclasses.replace(settings, models_service=start_models(settings))
        start_shards(settings)
    except (ClusterError, ModelsDeploymentError) as exc:
        print(f"semanticxr serve: {exc}", file=sys.stderr)
        return 2
    print(
        f"SemanticXR gateway on http://{settings.host}:{settings.port} in front of "
        f"{settings.shards} map shards (Ray: {settings.cluster})"
    )
    server = Server(uvicorn_config(create_gateway_app(settings), settings))
    server.run()
    return _exit_code(server)


def store_reachable(command: str, settings: ServerSettings) -> bool:
    """Whether the store opens; else one line naming --store on stderr (the password
    hidden: the store's errors show its URL redacted)."""
    import sys

    from app.store import StoreUnavailableError, open_store

    try:
        open_store(settings.store_url).close()
    except StoreUnavailableError as exc:
        print(f"semanticxr {command}: --store: {exc}", file=sys.stderr)
        return False
    return True


def _exit_code(server) -> int:
    """130 when a Ctrl-C (SIGINT) stopped the server, else 0. uvicorn re-raises the signal
    after its graceful shutdown, but asyncio's runner may then finish the main task before
    the interrupt lands and return normally: the exit code must not depend on that race."""
    import signal
    import sys

    if signal.SIGINT in getattr(server, "_captured_signals", ()):
        print("interrupted", file=sys.stderr)
        return 130
    return 0
