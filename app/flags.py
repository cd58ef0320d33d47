"""argparse helpers for the commands' flags (below the CLI: app.cli and bench use them).

Flags are generated from typed dataclasses (Knobs, ServerSettings), help from each field's
docstring, so a knob or a setting is documented once and gets its flag for free.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import inspect
import ssl
from typing import Any

from app.client import http_base_url, trusting
from app.config import Knobs, knob_docs, updated_knobs


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def server_url(text: str) -> str:
    """argparse type: a server URL, http(s):// or ws(s)://host:port."""
    try:
        http_base_url(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def tls_ca(text: str) -> ssl.SSLContext:
    """argparse type: a PEM file of certificates to trust -> the SSL context built from it
    (once, for every client of the command); a missing or unreadable file exits 2 naming
    --tls-ca."""
    try:
        return trusting(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_tls_ca_flag(parser: argparse.ArgumentParser) -> None:
    """--tls-ca PATH (dest tls_ca: an ssl.SSLContext, or None for the system's CAs)."""
    parser.add_argument(
        "--tls-ca",
        type=tls_ca,
        metavar="PATH",
        help="trust the server's certificate in this PEM file (a `serve --https` server's "
        "DATA_DIR/tls/cert.pem, or the CA of its --tls-cert); default: the system's CAs",
    )


def add_knob_flags(parser: argparse.ArgumentParser) -> None:
    """One --flag per knob, help text from the knob's docstring."""
    group = parser.add_argument_group('knobs (paper Table 3; docs/architecture.md "Knobs")')
    docs = knob_docs()
    for f in dataclasses.fields(Knobs):
        default = getattr(Knobs(), f.name)
        group.add_argument(
            f"--{f.name.replace('_', '-')}",
            dest=f"knob_{f.name}",
            default=None,
            metavar="LIST" if isinstance(default, list) else "N",
            help=f"{docs.get(f.name, '')} (default: {default})".replace("%", "%%"),
        )


def explicit_knobs(args: argparse.Namespace) -> dict[str, Any]:
    """Only the knob flags given on the command line, unvalidated."""
    return {
        f.name: getattr(args, f"knob_{f.name}")
        for f in dataclasses.fields(Knobs)
        if getattr(args, f"knob_{f.name}", None) is not None
    }


def knobs_from_args(args: argparse.Namespace) -> Knobs:
    """The default knobs changed by the knob flags given; KnobError names a bad one."""
    return updated_knobs(Knobs(), explicit_knobs(args))


def field_docs(cls: type) -> dict[str, str]:
    """Field name -> the docstring under it, read from the source of dataclass `cls`."""
    tree = ast.parse(inspect.getsource(cls))
    body = tree.body[0].body  # type: ignore[attr-defined]
    docs: dict[str, str] = {}
    for node, nxt in zip(body, body[1:], strict=False):
        if (
            isinstance(node, ast.AnnAssign)
            and isinstance(node.target, ast.Name)
            and isinstance(nxt, ast.Expr)
            and isinstance(nxt.value, ast.Constant)
            and isinstance(nxt.value.value, str)
        ):
            docs[node.target.id] = " ".join(nxt.value.value.split())
    return docs


def add_dataclass_flags(
    parser: argparse.ArgumentParser | argparse._ArgumentGroup,
    cls: type,
    *,
    env_prefix: str | None = None,
) -> None:
    """One --flag per field of dataclass `cls` (dest: the field name, default None so that
    an unset flag can be told apart), help from the field's docstring and its default.

    Field types: int, float, str and bool (--x / --no-x), each optionally `| None`; any other
    type is passed on as the text given. env_prefix: name the environment variable in the
    help (e.g. SEMANTICXR_ -> "env SEMANTICXR_PORT")."""
    docs = field_docs(cls)
    for f in dataclasses.fields(cls):
        kind = str(f.type).replace(" ", "").removesuffix("|None").removeprefix("None|")
        default = f.default if f.default is not dataclasses.MISSING else None
        notes = [f"default {default}" if default is not None else "default unset"]
        if env_prefix:
            notes.append(f"env {env_prefix}{f.name.upper()}")
        doc = docs.get(f.name, "").rstrip(".").replace("%", "%%")
        help_text = f"{doc} ({'; '.join(notes)})"
        flag = f"--{f.name.replace('_', '-')}"
        if kind == "bool":
            parser.add_argument(
                flag, dest=f.name, action=argparse.BooleanOptionalAction, help=help_text
            )
            continue
        converter = {"int": int, "float": float}.get(kind, str)
        parser.add_argument(
            flag,
            dest=f.name,
            type=converter,
            metavar=f.name.upper() if converter is str else "N",
            help=help_text,
        )
