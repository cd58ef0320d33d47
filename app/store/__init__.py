"""Persistence behind one interface (`Store`), opened from one URL (the `store` setting).

Two implementations: `SqliteStore` (`sqlite:///<path>`, one file, the default) and
`PostgresStore` (`postgresql://user:password@host:port/database`, a server many processes
share). Another is a new module with a `Store` subclass and a line in `_OPENERS`.

Store URLs may carry a password: show them only through `redact_url`.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path

from app.store.base import (
    CHANGE_KINDS,
    COUNTER_NAMES,
    DONE_WINDOW,
    KeyframeCommit,
    SessionFenced,
    SessionHeld,
    SessionRecord,
    ShardRecord,
    Store,
    StoredSession,
    StoredSessionsLimit,
    StoreError,
    StoreUnavailableError,
    StoreVersionError,
)

__all__ = [
    "CHANGE_KINDS",
    "COUNTER_NAMES",
    "DONE_WINDOW",
    "KeyframeCommit",
    "SessionFenced",
    "SessionHeld",
    "SessionRecord",
    "ShardRecord",
    "Store",
    "StoreError",
    "StoreURLError",
    "StoreUnavailableError",
    "StoreVersionError",
    "StoredSession",
    "StoredSessionsLimit",
    "check_store_url",
    "open_store",
    "redact_url",
    "sqlite_url",
]

SETTING = "store (--store, SEMANTICXR_STORE)"
"""How the URL's setting is named in errors."""


class StoreURLError(StoreError, ValueError):
    """A store URL this server cannot open: unknown scheme or malformed."""


def _open_sqlite(location: str) -> Store:
    from app.store.sqlite import SqliteStore  # imported when used: sqlite3 + numpy rows

    return SqliteStore(location)


def _sqlite_path(location: str) -> str:
    """`sqlite:///data/x.db` -> "data/x.db"; `sqlite:////srv/x.db` -> "/srv/x.db"."""
    if not location.startswith("/") or location in ("/", "//"):
        raise StoreURLError(
            f"{SETTING}: a SQLite URL is sqlite:///<relative path> or sqlite:////<absolute "
            f"path>, got 'sqlite://{location}'"
        )
    path = location[1:]
    if path.endswith("/"):
        raise StoreURLError(f"{SETTING}: 'sqlite://{location}' names a folder, not a file")
    return path


def _open_postgres(url: str) -> Store:
    from app.store.postgres import PostgresStore  # imported when used: psycopg and its pool

    return PostgresStore(url)


def _postgres_url(location: str) -> str:
    """`user:pw@host:port/db?param=value` (after `postgresql://` or `postgres://`) -> the
    `postgresql://` URL libpq opens; StoreURLError naming the setting (password redacted)
    when libpq cannot parse it, a port is not a number, or it names no database."""
    from psycopg import ProgrammingError  # imported when used, like the store itself
    from psycopg.conninfo import conninfo_to_dict

    url = f"postgresql://{location}"
    example = "postgresql://user:password@host:port/database"
    try:
        params = conninfo_to_dict(url)
    except ProgrammingError as exc:
        raise StoreURLError(
            f"{SETTING}: {redact_url(url)!r} is not a PostgreSQL URL such as {example} "
            f"({str(exc).strip()})"
        ) from None
    ports = [port for port in str(params.get("port") or "").split(",") if port]
    if not all(port.isdigit() and 0 < int(port) < 65536 for port in ports):
        raise StoreURLError(
            f"{SETTING}: the port of {redact_url(url)!r} must be a number from 1 to 65535 "
            "(a password holding / : @ or ? must be percent-encoded)"
        )
    if not params.get("dbname"):
        raise StoreURLError(
            f"{SETTING}: {redact_url(url)!r} names no database; use {example} (or "
            "postgresql:///database?host=/socket/dir for a Unix socket)"
        )
    return url


_OPENERS: dict[str, tuple[Callable[[str], str], Callable[[str], Store]]] = {
    "sqlite": (_sqlite_path, _open_sqlite),
    "postgresql": (_postgres_url, _open_postgres),
    "postgres": (_postgres_url, _open_postgres),
}
"""scheme -> (check and normalise the part after `scheme://`, open it)."""


def _split(url: str) -> tuple[str, str]:
    """(scheme, location) of a supported URL; StoreURLError naming the setting otherwise."""
    supported = ", ".join(f"{scheme}://" for scheme in _OPENERS)
    if not isinstance(url, str) or "://" not in url:
        shown = redact_url(url) if isinstance(url, str) else url
        raise StoreURLError(
            f"{SETTING} must be a URL such as sqlite:///data/semanticxr.sqlite3 or "
            f"postgresql://user:password@host:port/database, got {shown!r}"
        )
    scheme, rest = url.split("://", 1)
    if scheme not in _OPENERS:
        raise StoreURLError(
            f"{SETTING}: unknown scheme {scheme!r} in {redact_url(url)!r}; supported: {supported}"
        )
    return scheme, _OPENERS[scheme][0](rest)


def check_store_url(url: str) -> None:
    """Raise StoreURLError (naming the setting) if `open_store` could not understand `url`."""
    _split(url)


def open_store(url: str) -> Store:
    """The store at `url`: `sqlite:///<path>` (relative to the working directory),
    `sqlite:////<absolute path>`, or a PostgreSQL database: `postgresql://` (or `postgres://`)
    `user:password@host:port/database`, `postgresql:///database?host=/socket/dir` for a Unix
    socket, with libpq's parameters after `?` (`connect_timeout=<s>`, `sslmode=...`). Raises
    StoreURLError for an unknown scheme or bad URL, StoreUnavailableError when a PostgreSQL
    server cannot be reached (in about `connect_timeout` seconds, 5 when unset)."""
    scheme, location = _split(url)
    return _OPENERS[scheme][1](location)


def sqlite_url(path: str | Path) -> str:
    """The URL of the SQLite file at `path` (absolute paths get the fourth slash)."""
    return f"sqlite:///{Path(path)}"


_PASSWORD_PARAMETER = re.compile(r"((?:^|[?&\s])(?:ssl)?password\s*=\s*)('[^']*'|[^&\s]*)")


def redact_url(url: str) -> str:
    """`url` fit to log or show: its password (`user:password@`, or a `password=` or
    `sslpassword=` parameter) replaced by `***`. Errs on hiding too much: everything from the
    first `:` to the last `@` counts as the password, so one holding an unescaped `/`, `?` or
    `@` is hidden whole (and an `@` further on hides the host too)."""
    scheme, sep, rest = url.partition("://")
    if sep:
        at = rest.rfind("@")
        user_info = rest[: max(at, 0)]
        if ":" in user_info:
            rest = user_info.split(":", 1)[0] + ":***" + rest[at:]
    return _PASSWORD_PARAMETER.sub(r"\1***", f"{scheme}{sep}{rest}")
