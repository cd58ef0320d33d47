"""`semanticxr sessions list|show|delete|export|import`: a server's sessions, from outside.

    semanticxr sessions list --server http://127.0.0.1:8000
    semanticxr sessions show SID --server URL    # statistics and the recent changes
    semanticxr sessions export SID --out kitchen.ply --format ply --server URL

Every action takes `--server URL`, `--api-key` (default: env SEMANTICXR_API_KEY, as the
device does; the key also serves as any session's token) and `--tls-ca PATH` (the
certificate of a `serve --https` server). `--json` prints the server's
answer as JSON instead of a table.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import shutil
import sys
from pathlib import Path
from typing import Any

from app.client.connection import http_base_url
from app.client.rest import (
    ApiError,
    SessionApi,
    delete_session,
    export_map,
    http_client,
    import_map,
    list_sessions,
    request,
)
from app.flags import add_tls_ca_flag, server_url
from app.protocol import SessionStats, SessionSummary

COLUMNS = (
    ("session_id", "SESSION", 16),
    ("name", "NAME", 24),
    ("mode", "MODE", 10),
    ("objects", "OBJECTS", 7),
    ("keyframes", "KEYFRAMES", 9),
    ("frames", "FRAMES", 8),
)
"""The table's columns: field, heading, width; NAME takes what the terminal has left."""
RECENT_CHANGES = 10
"""Changes `show` lists, the newest."""


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "sessions",
        help="list, show, delete, export or import a server's sessions",
        description="A server's sessions: list them, show one, delete one, export one's map "
        "(JSON or PLY), import a JSON export as a new session.",
    )
    sub = parser.add_subparsers(dest="sessions_command", required=True, metavar="ACTION")

    def action(name: str, help: str) -> argparse.ArgumentParser:
        p = sub.add_parser(name, help=help, description=help[0].upper() + help[1:] + ".")
        p.add_argument(
            "--server", required=True, type=server_url, metavar="URL", help="e.g. http://host:8000"
        )
        p.add_argument(
            "--api-key",
            default=os.environ.get("SEMANTICXR_API_KEY"),
            help="server API key (default: env SEMANTICXR_API_KEY)",
        )
        add_tls_ca_flag(p)
        return p

    listing = action("list", "every session of the server, as a table")
    listing.add_argument("--json", action="store_true", help="print JSON instead of a table")
    listing.set_defaults(func=run_list)
    show = action("show", "one session's statistics and its recent changes")
    show.add_argument("sid", metavar="SID")
    show.add_argument("--json", action="store_true", help="print JSON instead of a table")
    show.set_defaults(func=run_show)
    delete = action("delete", "delete a session and its map")
    delete.add_argument("sid", metavar="SID")
    delete.set_defaults(func=run_delete)
    export = action("export", "write a session's map to a file (JSON export or binary PLY)")
    export.add_argument("sid", metavar="SID")
    export.add_argument("--out", required=True, metavar="FILE", help="file to write")
    export.add_argument("--format", choices=("json", "ply"), default="json", help="(default json)")
    export.add_argument(
        "--embeddings", action="store_true", help="include the objects' embeddings (JSON)"
    )
    export.set_defaults(func=run_export)
    imported = action("import", "create a session from a JSON export")
    imported.add_argument("file", metavar="FILE", help="a JSON export")
    imported.add_argument("--json", action="store_true", help="print the server's answer")
    imported.set_defaults(func=run_import)
    return parser


def _call(coroutine: Any) -> Any:
    """Run one REST call; an ApiError becomes a message on stderr and exit status 1."""
    try:
        return asyncio.run(coroutine)
    except ApiError as exc:
        print(f"semanticxr sessions: {exc}", file=sys.stderr)
        raise SystemExit(1) from None


def table(rows: list[SessionSummary], width: int) -> str:
    """The sessions as a fixed-width table no wider than `width` (the NAME column gives way,
    long names end in "…"; a wide terminal shows them whole)."""
    fixed = sum(w + 2 for field, _, w in COLUMNS if field != "name")
    longest = max((len(row.name) for row in rows), default=4)
    name_width = max(8, min(longest, width - fixed - 2))
    widths = {field: (name_width if field == "name" else w) for field, _, w in COLUMNS}

    def cell(value: Any, field: str) -> str:
        text, w = str(value), widths[field]
        text = text if len(text) <= w else text[: w - 1] + "…"
        return text.rjust(w) if isinstance(value, int) else text.ljust(w)

    lines = ["  ".join(heading.ljust(widths[f]) for f, heading, _ in COLUMNS).rstrip()]
    lines += ["  ".join(cell(getattr(row, f), f) for f, _, _ in COLUMNS).rstrip() for row in rows]
    return "\n".join(lines)


def run_list(args: argparse.Namespace) -> int:
    rows = _call(list_sessions(args.server, api_key=args.api_key, ssl_context=args.tls_ca))
    if args.json:
        print(json.dumps([row.to_json() for row in rows], indent=2))
    elif not rows:
        print("no sessions")
    else:
        print(table(rows, shutil.get_terminal_size().columns))
    return 0


def ago_words(seconds: float) -> str:
    """How long ago, as people say it: "just now", "40 s ago", "10 min ago", "3 h ago" (the
    dashboard says the same, static/app.js `agoWords`)."""
    s = max(0.0, seconds)
    if s < 5:
        return "just now"
    if s < 90:
        return f"{int(s + 0.5)} s ago"
    if s < 90 * 60:
        return f"{int(s / 60 + 0.5)} min ago"
    if s < 48 * 3600:
        return f"{int(s / 3600 + 0.5)} h ago"
    return f"{int(s / 86400 + 0.5)} days ago"


def place_words(kind: str, place: dict) -> str:
    """A change's `place` in words: "on the dining table", "near the sofa"; where a removed
    thing was: "from the desk", "from near the sofa"."""
    the = f"the {place.get('label')}"
    relation = place.get("relation")
    if kind == "removed":
        return f"from {the}" if relation == "on" else f"from near {the}"
    return f"{relation} {the}"


def change_words(change: dict, now_t: float | None) -> str:
    """One change of `GET .../changes` in words: "mug moved on the dining table, 10 min ago",
    "laptop removed from the desk" (no place, no time: "book removed")."""
    kind = change.get("kind", "changed")
    words = f"{change.get('label', '?')} {kind}"
    if isinstance(change.get("place"), dict):
        words += f" {place_words(kind, change['place'])}"
    t = change.get("t")
    if isinstance(now_t, int | float) and isinstance(t, int | float):
        words += f", {ago_words(now_t - t)}"
    return words


async def recent_changes(args: argparse.Namespace) -> dict | None:
    """`GET .../changes` for the newest RECENT_CHANGES; None from a server without the
    living map (404 for the call, the session itself having answered)."""
    url = f"{http_base_url(args.server)}/v1/sessions/{args.sid}/changes"
    async with http_client(args.api_key, ssl_context=args.tls_ca) as http:
        try:
            return await request(http, "GET", url, params={"limit": RECENT_CHANGES})
        except ApiError as exc:
            if exc.status == 404:
                return None
            raise


def run_show(args: argparse.Namespace) -> int:
    async def fetch() -> tuple[SessionStats, dict | None]:
        async with SessionApi(args.server, args.sid, args.api_key, ssl_context=args.tls_ca) as api:
            stats = await api.fetch()
        return stats, await recent_changes(args)

    stats, changes = _call(fetch())
    shown = stats.to_json()
    if args.json:
        print(json.dumps({**shown, "recent_changes": changes} if changes else shown, indent=2))
        return 0
    for key, value in shown.items():
        if key == "knobs":
            continue  # `--json` shows them; they would fill the screen
        if isinstance(value, dict):
            value = ", ".join(f"{k}={v}" for k, v in value.items())
        print(f"{key:20s} {value}")
    if changes is not None:
        listed = changes.get("changes", [])
        print(f"{'recent changes':20s} {'none' if not listed else 'newest first'}")
        for change in reversed(listed):
            print(f"  {change_words(change, changes.get('now_t'))}")
    return 0


def run_delete(args: argparse.Namespace) -> int:
    _call(delete_session(args.server, args.sid, token=args.api_key, ssl_context=args.tls_ca))
    print(f"deleted session {args.sid}")
    return 0


def run_export(args: argparse.Namespace) -> int:
    out = Path(args.out)
    written = _call(
        export_map(
            args.server,
            args.sid,
            out,
            format=args.format,
            embeddings=args.embeddings,
            token=args.api_key,
            ssl_context=args.tls_ca,
        )
    )
    print(f"wrote {out} ({written} bytes, {args.format})")
    return 0


def run_import(args: argparse.Namespace) -> int:
    export = Path(args.file).read_bytes()
    answer = _call(import_map(args.server, export, api_key=args.api_key, ssl_context=args.tls_ca))
    if args.json:
        print(json.dumps(answer, indent=2))
    else:
        print(f"imported as session {answer['session_id']} (token {answer['token']})")
    return 0
