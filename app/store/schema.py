"""The store's tables, written once for every database, and the migrations between versions.

Each table, column and index says the schema version it came in (`since`). A new store is
made at its database's first version (`Dialect.first_version`: SQLite 1, PostgreSQL 4) and
migrated from there like any other, so there is one path to each version; `statements`
gives the SQL of either. A migration adds what came in at its version: new tables with
their columns, new columns (ALTER TABLE, with `default` filling the rows from before it),
new indexes, and `fills` (rows from before it given a value computed then). A schema
change is a new version here: new things with `since` = SCHEMA_VERSION + 1.

Arrays are raw little-endian float32 bytes whose shape the row records (never pickle);
knobs and label counts are JSON text (`rows.py` encodes both the same for every database).
Where each database stores the version is its store's concern (SQLite's `user_version`,
PostgreSQL's `schema_version` table).
"""

from __future__ import annotations

from dataclasses import dataclass

from app.mapping.object import MAX_STAYS, STAY_BYTES
from app.store.dialect import Dialect

__all__ = ["SCHEMA_VERSION", "TABLES", "Column", "Index", "Table", "statements"]


@dataclass(frozen=True)
class Column:
    """One column. `type` is logical (`Dialect.types`): text, key (text compared by code
    point), json, int (64-bit), int32, real (float64), blob, serial (insertion order),
    arrival (arrival order, where the database does not keep it by itself)."""

    name: str
    type: str
    not_null: bool = False
    primary_key: bool = False
    references: str | None = None
    check: str | None = None
    since: int = 1
    default: str | None = None
    """What the rows from before the column get, when it is added to an existing table."""
    row_check: str | None = None
    """A check across columns that comes with this one (added to the table where ALTER
    TABLE can, joined to this column's check where it cannot)."""
    uncompressed: bool = False
    """Float noise: compressing it costs time and saves nothing."""


@dataclass(frozen=True)
class Index:
    name: str
    table: str
    columns: str
    since: int
    databases: tuple[str, ...] = ("sqlite", "postgresql")
    """The databases that have it (an index on a column only some have)."""


@dataclass(frozen=True)
class Table:
    name: str
    columns: tuple[Column, ...]
    """In the order a table made at the newest version has them; a column added later
    comes after the others in a table made before it."""
    constraints: tuple[str, ...] = ()
    """Table constraints (primary key, unique, checks), made with the table."""
    since: int = 1
    without_rowid: bool = False


@dataclass(frozen=True)
class Fill:
    """Rows from before version `since` get `value` (`{now}`: the migration's time)."""

    table: str
    column: str
    value: str
    since: int


SESSION = "sessions (session_id) ON DELETE CASCADE"
"""A session's rows go with it."""

TABLES: tuple[Table, ...] = (
    Table(
        "sessions",
        (
            Column("session_id", "key", primary_key=True),
            Column("name", "text", not_null=True),
            Column("mode", "text", not_null=True),
            # 2: the session's perception backend (sessions before it used `detections`).
            Column("perception", "text", not_null=True, since=2, default="'detections'"),
            Column("knobs", "json", not_null=True),  # {knob: value}
            Column("token_hash", "text", not_null=True),
            Column("created_at", "real", not_null=True),  # unix time, seconds
            Column("frames", "int", not_null=True),
            Column("keyframes", "int", not_null=True),
            Column("bytes_in", "int", not_null=True),
            Column("bytes_out", "int", not_null=True),
            Column("next_object_id", "int", not_null=True),
            Column("seq", "int", not_null=True),  # the delta log's seq
            Column("delta_floor", "int", not_null=True),  # the delta log's floor
            # 3: when the session was last used (unix time, seconds), for retention.
            Column("last_used_at", "real", not_null=True, since=3, default="0"),
            # 4: the frame t of the last keyframe, and its pose: float32 LE [16], row-major.
            Column("last_t", "real", since=4),
            Column(
                "last_pose", "blob", since=4, check="last_pose IS NULL OR length(last_pose) = 64"
            ),
            # 5: frames that came as sightings; the owner (the shard holding it, NULL: none),
            # the epoch (bumped at each claim: a write naming an older one is fenced) and
            # the owner's lease (unix time, seconds).
            Column("sightings", "int", not_null=True, since=5, default="0"),
            Column("owner", "key", since=5),
            Column("epoch", "int", not_null=True, since=5, default="0"),
            Column("lease_until", "real", since=5),
            # 6: the up axis, set at creation or inferred from the poses, and where it came
            # from; NULL while the default (+z) applies.
            Column(
                "up",
                "text",
                since=6,
                check="up IS NULL OR up IN ('+x', '-x', '+y', '-y', '+z', '-z')",
            ),
            Column(
                "up_source",
                "text",
                since=6,
                check="up_source IS NULL OR up_source IN ('set', 'inferred')",
                row_check="(up IS NULL) = (up_source IS NULL)",
            ),
            # 7: the text tower ("minilm", every session before it, or "static") and, for a
            # static one, the SHA-256 of the tower file it was created with.
            Column(
                "text_tower",
                "text",
                not_null=True,
                since=7,
                default="'minilm'",
                check="text_tower IN ('minilm', 'static')",
            ),
            Column(
                "tower_sha256",
                "text",
                since=7,
                check="tower_sha256 IS NULL OR length(tower_sha256) = 64",
                row_check="(text_tower = 'static') = (tower_sha256 IS NOT NULL)",
            ),
        ),
    ),
    Table(
        "objects",
        (
            Column("session_id", "key", not_null=True, references=SESSION),
            Column("object_id", "int", not_null=True),
            Column("change_seq", "int", not_null=True),  # seq of the commit that last changed it
            Column("version", "int", not_null=True),
            Column("n_obs", "int", not_null=True),
            Column("frames_seen", "int", not_null=True),
            Column("first_seen", "int", not_null=True),
            Column("last_seen", "int", not_null=True),
            Column("resolution_m", "real", not_null=True),
            Column("label_counts", "json", not_null=True),  # {label: count}, first seen first
            Column("n_points", "int32", not_null=True),
            # float32 little-endian [n_points, 3]
            Column("points", "blob", not_null=True, uncompressed=True),
            Column("embedding_dim", "int32"),  # NULL when the object has no embedding
            Column("embedding_sum", "blob"),  # float32 little-endian [embedding_dim]
            # 4: the living map. Objects removed from the map stay as history (state), with
            # when they were seen on the device clock (seconds), where they stayed
            # (stays_to_bytes records, oldest first, at most MAX_STAYS; NULL for none) and
            # per-label sums (float32 LE [labels, embedding_dim], a row per label of
            # label_counts in its order, all NaN: none for that label; NULL for none).
            Column(
                "state",
                "text",
                not_null=True,
                since=4,
                default="'present'",
                check="state IN ('present', 'removed')",
            ),
            Column("first_seen_t", "real", since=4),
            Column("last_seen_t", "real", since=4),
            Column(
                "stays",
                "blob",
                since=4,
                check=f"stays IS NULL OR (length(stays) % {STAY_BYTES} = 0"
                f" AND length(stays) <= {MAX_STAYS * STAY_BYTES})",
            ),
            Column(
                "label_embeddings",
                "blob",
                since=4,
                check="label_embeddings IS NULL"
                " OR (embedding_dim > 0 AND length(label_embeddings) % (4 * embedding_dim) = 0)",
                uncompressed=True,
            ),
        ),
        (
            "PRIMARY KEY (session_id, object_id)",
            "CHECK (length(points) = 12 * n_points)",
            "CHECK ((embedding_dim IS NULL) = (embedding_sum IS NULL))",
            "CHECK (embedding_sum IS NULL OR length(embedding_sum) = 4 * embedding_dim)",
        ),
    ),
    Table(
        "tombstones",
        (
            Column("session_id", "key", not_null=True, references=SESSION),
            Column("object_id", "int", not_null=True),
            Column("seq", "int", not_null=True),  # seq of the commit that removed it
        ),
        ("PRIMARY KEY (session_id, object_id)",),
        without_rowid=True,
    ),
    # 4: the changes the map concluded, in arrival order.
    Table(
        "changes",
        (
            Column("change_id", "arrival"),
            Column("session_id", "key", not_null=True, references=SESSION),
            Column("object_id", "int", not_null=True),
            Column("kind", "text", not_null=True, check="kind IN ('added', 'moved', 'removed')"),
            Column("t", "real", not_null=True),  # frame t that concluded it (device clock)
            Column("label", "text", not_null=True),
            Column("from_x", "real"),  # the old place, NULL where none
            Column("from_y", "real"),
            Column("from_z", "real"),
            Column("to_x", "real"),  # the new place, NULL where none
            Column("to_y", "real"),
            Column("to_z", "real"),
            Column("seq", "int", not_null=True),  # the update seq of the commit
        ),
        (
            "CHECK ((from_x IS NULL) = (from_y IS NULL) AND (from_x IS NULL) = (from_z IS NULL))",
            "CHECK ((to_x IS NULL) = (to_y IS NULL) AND (to_x IS NULL) = (to_z IS NULL))",
        ),
        since=4,
    ),
    # 5: the acks of each session's newest frames, so a frame sent again is answered
    # instead of mapped twice.
    Table(
        "done_acks",
        (
            Column("done_id", "serial"),  # insertion order
            Column("session_id", "key", not_null=True, references=SESSION),
            Column("stream_id", "text", not_null=True),
            Column("seq", "int", not_null=True),  # the frame's seq in its stream
            Column("ack", "blob", not_null=True),  # what the server answered, as it keeps it
        ),
        ("UNIQUE (session_id, stream_id, seq)",),
        since=5,
    ),
    # 5: the shard registry.
    Table(
        "shards",
        (
            Column("name", "key", primary_key=True),
            Column("url", "text", not_null=True),  # where gateways reach the shard
            Column("heartbeat_at", "real", not_null=True),  # unix time, seconds
        ),
        since=5,
    ),
)

INDEXES: tuple[Index, ...] = (
    Index("sessions_by_last_use", "sessions", "last_used_at", since=3),
    # The present map's reads (delta log, counts) and the removed objects' from the index.
    Index("objects_by_state", "objects", "session_id, state, object_id, change_seq", since=4),
    Index("changes_in_order", "changes", "session_id, change_id", 4, ("postgresql",)),
    Index("changes_by_seq", "changes", "session_id, seq", since=4),
    Index("changes_by_t", "changes", "session_id, t", since=4),
    Index("sessions_by_owner", "sessions", "owner", since=5),
    Index("done_acks_in_order", "done_acks", "session_id, done_id", since=5),
)

FILLS: tuple[Fill, ...] = (
    # Sessions from before retention count as used at the upgrade: a session is never
    # deleted for lack of a date.
    Fill("sessions", "last_used_at", "{now}", since=3),
)

SCHEMA_VERSION = max(
    thing.since
    for group in (TABLES, INDEXES, FILLS, *(table.columns for table in TABLES))
    for thing in group
)
"""The newest schema version: what a store is migrated to when opened."""


def statements(
    dialect: Dialect, from_version: int = 0, to_version: int = SCHEMA_VERSION
) -> list[str]:
    """The SQL taking a store of `dialect` from `from_version` (0: a new, empty one) to
    `to_version`, in order (the version number itself is the store's to record). ValueError
    on a version before the database's first or beyond SCHEMA_VERSION."""
    first = dialect.first_version
    if not (from_version == 0 or first <= from_version <= to_version <= SCHEMA_VERSION):
        raise ValueError(f"no migration from version {from_version} to {to_version}")
    if from_version == 0:
        done = first
        result = [
            s for table in TABLES if table.since <= first for s in _create(table, first, dialect)
        ]
        result += [
            _index(index) for index in INDEXES if index.since <= first and _has(index, dialect)
        ]
    else:
        done, result = from_version, []
    for version in range(done + 1, to_version + 1):
        result += _migration(version, dialect)
    return result


def _migration(version: int, dialect: Dialect) -> list[str]:
    """What came in at `version`, to a store at the version before it."""
    result = []
    for table in TABLES:
        if table.since == version:
            result += _create(table, version, dialect)
            continue
        for column in table.columns:
            if column.since == version and table.since < version:
                result += _add_column(table, column, dialect)
    result += [
        f"UPDATE {fill.table} SET {fill.column} = {fill.value.format(now=dialect.now)}"
        for fill in FILLS
        if fill.since == version
    ]
    result += [
        _index(index) for index in INDEXES if index.since == version and _has(index, dialect)
    ]
    return result


def _create(table: Table, version: int, dialect: Dialect) -> list[str]:
    columns = [
        _column(column, dialect, added=False)
        for column in table.columns
        if column.since <= version and dialect.types[column.type] is not None
    ]
    checks = [
        f"CHECK ({column.row_check})"
        for column in table.columns
        if column.row_check and column.since <= version
    ]
    body = ", ".join([*columns, *table.constraints, *checks])
    rowid = " WITHOUT ROWID" if table.without_rowid and dialect.without_rowid else ""
    return [f"CREATE TABLE {table.name} ({body}){rowid}"] + [
        dialect.uncompressed.format(table=table.name, column=column.name)
        for column in table.columns
        if column.uncompressed and dialect.uncompressed and column.since <= version
    ]


def _add_column(table: Table, column: Column, dialect: Dialect) -> list[str]:
    result = [f"ALTER TABLE {table.name} ADD COLUMN {_column(column, dialect, added=True)}"]
    if column.row_check and dialect.adds_row_checks:
        result.append(f"ALTER TABLE {table.name} ADD CHECK ({column.row_check})")
    return result


def _column(column: Column, dialect: Dialect, *, added: bool) -> str:
    """The column's definition; `added`: to an existing table (its default fills the rows
    there; a check across columns joins the column's where ALTER TABLE cannot add it)."""
    parts = [column.name, dialect.types[column.type]]
    if column.primary_key:
        parts.append("PRIMARY KEY")
    if column.not_null:
        parts.append("NOT NULL")
    if added and column.default is not None:
        parts.append(f"DEFAULT {column.default}")
    if column.references:
        parts.append(f"REFERENCES {column.references}")
    check = column.check
    if added and column.row_check and not dialect.adds_row_checks:
        check = f"{column.row_check} AND ({check})" if check else column.row_check
    if check:
        parts.append(f"CHECK ({check})")
    return " ".join(parts)


def _index(index: Index) -> str:
    return f"CREATE INDEX {index.name} ON {index.table} ({index.columns})"


def _has(index: Index, dialect: Dialect) -> bool:
    return dialect.name in index.databases
