"""What differs between the SQL databases a store runs on, and nothing else.

The queries (`sql.py`) and the schema (`schema.py`) are written once, with `?` placeholders
and logical column types; a `Dialect` says how one database spells them: its placeholder,
its column types, how a write locks a session's row, how one statement covers a list of ids,
what keeps the changes' arrival order, and the schema features only one of them has. The
connection, its transactions and its errors stay in the store of each database
(`sqlite.py`, `postgres.py`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

__all__ = ["POSTGRES", "SQLITE", "Dialect"]


@dataclass(frozen=True)
class Dialect:
    """How one database spells what the store's SQL needs."""

    name: str
    placeholder: str
    """Replaces each `?` of a statement that takes parameters."""
    types: Mapping[str, str | None]
    """Logical column type (`schema.Column.type`) -> this database's; None: no column (the
    database keeps the value itself, as SQLite's rowid keeps the changes' arrival order)."""
    first_version: int
    """The schema version this database's stores were first made at: a new store is made at
    it and migrated from there, so there is one path to each version."""
    now: str
    """The current unix time (seconds) as an SQL expression."""
    lock_row: str
    """Ends a SELECT of a session's row that a write goes on to change: the row stays locked
    until the transaction ends ("" where a write transaction already excludes every other)."""
    lock_creations: str | None
    """A statement (one `?`: the lock's name) that queues creations, so none lands between
    another's count and its insert; None where a write transaction already does."""
    arrival_order: str
    """The column that orders `changes` by arrival."""
    batches_ids: bool
    """True: a statement over many ids runs once, with them as one array parameter
    (`in_ids`, `each_id`); False: it runs once per id."""
    in_ids: str
    """`column {in_ids}`: the column matches the id parameter (one id, or an array)."""
    each_id: str
    """`SELECT ?, {each_id}, ?`: one row per id of the parameter (one id, or an array)."""
    without_rowid: bool
    """Tables keyed by their primary key alone may say so (`schema.Table.without_rowid`)."""
    adds_row_checks: bool
    """ALTER TABLE can add a CHECK across columns; where it cannot, the check joins the CHECK
    of the column it came with (`schema.Column.row_check`)."""
    uncompressed: str | None
    """How to keep a column's values uncompressed (`{table}`, `{column}`); None where values
    are never compressed."""

    def sql(self, statement: str) -> str:
        """`statement` with this database's placeholders instead of `?`."""
        if self.placeholder == "?":
            return statement
        assert "%" not in statement, "a literal % would need escaping for psycopg"
        return statement.replace("?", self.placeholder)

    def ids(self, ids: list[int]) -> list[list[int]] | list[int]:
        """The values for the id parameter of a statement over `ids`: one array, or one id
        for each run."""
        return [ids] if self.batches_ids else ids


SQLITE = Dialect(
    name="sqlite",
    placeholder="?",
    types={
        "text": "TEXT",
        "key": "TEXT",  # SQLite compares text by code point
        "json": "TEXT",
        "int": "INTEGER",
        "int32": "INTEGER",
        "real": "REAL",
        "blob": "BLOB",
        "serial": "INTEGER PRIMARY KEY",  # the rowid: insertion order
        "arrival": None,  # the rowid
    },
    first_version=1,
    now="(julianday('now') - 2440587.5) * 86400.0",
    lock_row="",  # BEGIN IMMEDIATE: one writer at a time, across processes too
    lock_creations=None,
    arrival_order="rowid",
    batches_ids=False,
    in_ids="= ?",
    each_id="?",
    without_rowid=True,
    adds_row_checks=False,
    uncompressed=None,
)
"""SQLite 3 (the `sqlite3` module): one file, one writer at a time."""

POSTGRES = Dialect(
    name="postgresql",
    placeholder="%s",
    types={
        "text": "text",
        "key": 'text COLLATE "C"',  # sorted by code point, as in SQLite
        "json": "json",  # its text kept as written: key order is meaning for label ties
        "int": "bigint",
        "int32": "integer",
        "real": "double precision",
        "blob": "bytea",
        "serial": "bigint GENERATED ALWAYS AS IDENTITY PRIMARY KEY",
        "arrival": "bigint GENERATED ALWAYS AS IDENTITY PRIMARY KEY",
    },
    first_version=4,
    now="extract(epoch FROM now())",
    lock_row=" FOR NO KEY UPDATE",
    lock_creations="SELECT pg_advisory_xact_lock(hashtext(?))",
    arrival_order="change_id",
    batches_ids=True,
    in_ids="= ANY(?)",
    each_id="unnest(?::bigint[])",
    without_rowid=False,
    adds_row_checks=True,
    uncompressed="ALTER TABLE {table} ALTER COLUMN {column} SET STORAGE EXTERNAL",
)
"""PostgreSQL (psycopg 3): a server many processes share; writes at READ COMMITTED."""
