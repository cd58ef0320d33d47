"""`semanticxr viewer`: the 3D viewer (viser) of one session's map."""

from __future__ import annotations

import argparse
import os
import time
from typing import Any

from app.flags import add_tls_ca_flag, server_url


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the `viewer` subcommand to `semanticxr`'s subparsers."""
    parser = subparsers.add_parser(
        "viewer",
        help="3D viewer of a session's map (viser): objects, boxes, labels, queries",
        description="Follow a session's map updates and show them in the browser; ask "
        "natural-language queries and see the hits highlighted.",
    )
    parser.add_argument(
        "--server", required=True, type=server_url, metavar="URL", help="e.g. http://host:8000"
    )
    add_tls_ca_flag(parser)
    parser.add_argument("--session", required=True, metavar="SID", help="session id to show")
    parser.add_argument(
        "--token",
        default=os.environ.get("SEMANTICXR_TOKEN"),
        help="the session's token (default: env SEMANTICXR_TOKEN; none for an open server)",
    )
    parser.add_argument("--port", type=int, default=8080, help="viewer port (default 8080)")
    parser.add_argument(
        "--host", default="127.0.0.1", help="interface to listen on (default 127.0.0.1)"
    )
    parser.add_argument(
        "--up",
        default="+z",
        choices=("+x", "+y", "+z", "-x", "-y", "-z"),
        help="up axis of the device's world frame (default +z, the synthetic world's)",
    )
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Run the viewer until Ctrl-C; prints its URL."""
    from app.cli.ports import check_ports

    if not check_ports("viewer", (args.host, args.port, "--port")):
        return 2  # viser would quietly take the next port: the printed URL would be wrong
    from viewer.app import ViewerApp  # here: viser loads in about a second

    app = ViewerApp(
        args.server,
        args.session,
        token=args.token,
        port=args.port,
        host=args.host,
        up_direction=args.up,
        ssl_context=args.tls_ca,
    )
    app.start()
    print(f"SemanticXR viewer of session {args.session} on {app.url}  (Ctrl-C to stop)")
    try:
        while True:
            time.sleep(3600)  # idle: the work happens in the viewer's threads
    except KeyboardInterrupt:
        pass
    finally:
        app.stop()
    return 0
