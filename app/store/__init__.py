"""Persistence behind one interface (`Store`), opened from one URL (the `store` setting).

A second implementation is a new module with a `Store` subclass and one line in `_OPENERS`.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from app.store.base import (
    CHANGE_KINDS,
    COUNTER_NAMES,
    SessionRecord,
    Store,
    StoredSession,
    StoreError,
    StoreUnavailableError,
    StoreVersionError,
)

__all__ = [
    "CHANGE_KINDS",
    "COUNTER_NAMES",
    "SessionRecord",
    "Store",
    "StoreError",
    "StoreURLError",
    "StoreUnavailableError",
    "StoreVersionError",
    "StoredSession",
    "check_store_url",
    "open_store",
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


_OPENERS: dict[str, tuple[Callable[[str], str], Callable[[str], Store]]] = {
    "sqlite": (_sqlite_path, _open_sqlite),
}
"""scheme -> (check and normalise the part after `scheme://`, open it)."""


def _split(url: str) -> tuple[str, str]:
    """(scheme, location) of a supported URL; StoreURLError naming the setting otherwise."""
    supported = ", ".join(f"{scheme}://" for scheme in _OPENERS)
    if not isinstance(url, str) or "://" not in url:
        raise StoreURLError(
            f"{SETTING} must be a URL such as sqlite:///data/semanticxr.sqlite3, got {url!r}"
        )
    scheme, rest = url.split("://", 1)
    if scheme not in _OPENERS:
        raise StoreURLError(
            f"{SETTING}: unknown scheme {scheme!r} in {url!r}; supported: {supported}"
        )
    return scheme, _OPENERS[scheme][0](rest)


def check_store_url(url: str) -> None:
    """Raise StoreURLError (naming the setting) if `open_store` could not understand `url`."""
    _split(url)


def open_store(url: str) -> Store:
    """The store at `url`: `sqlite:///<path>` (relative to the working directory) or
    `sqlite:////<absolute path>`. Raises StoreURLError for an unknown scheme or bad URL."""
    scheme, location = _split(url)
    return _OPENERS[scheme][1](location)


def sqlite_url(path: str | Path) -> str:
    """The URL of the SQLite file at `path` (absolute paths get the fourth slash)."""
    return f"sqlite:///{Path(path)}"
