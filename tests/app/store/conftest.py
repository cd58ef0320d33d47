"""Every store test that takes `store` or `store_url` runs against each store: SQLite, and
PostgreSQL (a database of its own per test, in the session's throwaway cluster: tests/pg.py;
skipped, saying why, where PostgreSQL cannot be found)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from app.store import Store, open_store, sqlite_url

STORE_KINDS = ("sqlite", "postgresql")


@pytest.fixture(params=STORE_KINDS)
def store_url(request: pytest.FixtureRequest, tmp_path) -> str:
    """The URL of a new, empty store of each kind."""
    if request.param == "sqlite":
        return sqlite_url(tmp_path / "data" / "semanticxr.db")
    return request.getfixturevalue("fresh_pg_url")


@pytest.fixture
def store(store_url: str) -> Iterator[Store]:
    """The store at `store_url`, open for the test and closed after it."""
    with open_store(store_url) as store:
        yield store
