"""A throwaway PostgreSQL cluster for the tests: started once per test session, removed after.

`initdb` and `pg_ctl` come from PATH or from Debian's /usr/lib/postgresql/<version>/bin (not on
PATH); tests that need them skip, saying so, where neither has them (`scripts/setup.sh`
installs Debian's `postgresql` as root). Both refuse to run as root, so as root the cluster
belongs to the `postgres` user and they run through `runuser`.

The cluster trades durability for speed (fsync, synchronous_commit and full-page writes off):
it only ever holds test data, and a test that kills a client still sees every commit the
server acknowledged. It listens on a free 127.0.0.1 port (password authentication: the URLs
carry a password, as an operator's would) and on a Unix socket in its directory (trusted).
"""

from __future__ import annotations

import itertools
import os
import pwd
import re
import shutil
import socket
import subprocess
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest

PG_USER = "postgres"
"""The cluster's superuser (and, as root, the system user that owns its files)."""
PG_PASSWORD = "pg-test-secret"
"""The superuser's password over TCP (the Unix socket trusts local connections)."""
DEBIAN_PG_ROOT = Path("/usr/lib/postgresql")
START_TIMEOUT_S = 60
SETTINGS = {
    "fsync": "off",  # test data only: nothing here must survive a power cut
    "synchronous_commit": "off",
    "full_page_writes": "off",
    "max_connections": "200",  # each store's pool holds a few; tests open many stores
    "shared_buffers": "32MB",
    "listen_addresses": "'127.0.0.1'",
    "log_min_messages": "warning",
}
LOCALE_AWARE = "TEMPLATE template0 LOCALE_PROVIDER icu ICU_LOCALE 'en-US'"
"""How test databases are created where PostgreSQL has ICU: sorting text by a language's
rules, as an operator's database usually does, so a store that relies on code-point order
fails here (without ICU they get the cluster's C locale)."""


def find_pg_bin() -> Path | None:
    """The folder holding initdb, pg_ctl and postgres: PATH first (symlinks resolved), then
    the newest /usr/lib/postgresql/<version>/bin. None where PostgreSQL is not installed."""
    candidates: list[Path] = []
    if found := shutil.which("initdb"):
        candidates.append(Path(found).resolve().parent)
    versions = [p for p in DEBIAN_PG_ROOT.glob("*/bin") if p.parent.name.isdigit()]
    candidates += sorted(versions, key=lambda p: int(p.parent.name), reverse=True)
    for folder in candidates:
        if all((folder / tool).is_file() for tool in ("initdb", "pg_ctl", "postgres")):
            return folder
    return None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class PgCluster:
    """A PostgreSQL cluster in a temporary directory; `start()` it, `remove()` it at the end."""

    def __init__(self, bin_dir: Path):
        self.bin_dir = bin_dir
        self.as_root = os.geteuid() == 0
        self.root = Path(tempfile.mkdtemp(prefix="semanticxr-pg-"))
        self.data_dir = self.root / "data"
        self.socket_dir = self.root  # short: a socket path must fit in 107 bytes
        self.log_file = self.root / "postgres.log"
        self.port = _free_port()
        self._names = itertools.count(1)
        self._database_options: str | None = LOCALE_AWARE
        if self.as_root:  # the cluster's files belong to the user that runs it
            owner = pwd.getpwnam(PG_USER)
            os.chown(self.root, owner.pw_uid, owner.pw_gid)

    # ------------------------------------------------------------------ processes
    def _run(self, tool: str, *args: str, timeout: float = START_TIMEOUT_S) -> None:
        command = [str(self.bin_dir / tool), *args]
        if self.as_root:
            command = ["runuser", "-u", PG_USER, "--", *command]
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout)
        if done.returncode != 0:
            log = self.log_file.read_text() if self.log_file.exists() else ""
            raise RuntimeError(
                f"{' '.join(command)} failed ({done.returncode}):\n{done.stdout}{done.stderr}{log}"
            )

    def init(self) -> None:
        """initdb: UTF-8, C locale, the superuser with a password over TCP."""
        password_file = self.root / "password"
        password_file.write_text(PG_PASSWORD + "\n")
        if self.as_root:
            owner = pwd.getpwnam(PG_USER)
            os.chown(password_file, owner.pw_uid, owner.pw_gid)
        self._run(
            "initdb",
            "-D",
            str(self.data_dir),
            "-U",
            PG_USER,
            f"--pwfile={password_file}",
            "--encoding=UTF8",
            "--locale=C",
            "--auth-local=trust",
            "--auth-host=scram-sha-256",
            "--no-sync",  # test data: skip the fsync of the new cluster
        )
        password_file.unlink()
        settings = {**SETTINGS, "port": str(self.port)}
        settings["unix_socket_directories"] = f"'{self.socket_dir}'"
        with open(self.data_dir / "postgresql.conf", "a") as conf:
            conf.writelines(f"{name} = {value}\n" for name, value in settings.items())

    def start(self) -> None:
        """Start the server and return once it accepts connections."""
        self._run(
            "pg_ctl", "-D", str(self.data_dir), "-l", str(self.log_file), "-w", "-t", "60", "start"
        )

    def stop(self) -> None:
        """Stop the server (fast shutdown: connected clients are cut off)."""
        self._run("pg_ctl", "-D", str(self.data_dir), "-m", "fast", "-w", "-t", "60", "stop")

    def remove(self) -> None:
        """Stop the server if it runs and delete the cluster's directory."""
        if (self.data_dir / "postmaster.pid").exists():
            try:
                self.stop()
            except (RuntimeError, subprocess.TimeoutExpired):
                self._run("pg_ctl", "-D", str(self.data_dir), "-m", "immediate", "stop")
        shutil.rmtree(self.root, ignore_errors=True)

    # ------------------------------------------------------------------ databases
    def url(self, database: str, *, password: str = PG_PASSWORD, port: int | None = None) -> str:
        """The TCP URL of `database` (with the superuser's password)."""
        return f"postgresql://{PG_USER}:{password}@127.0.0.1:{port or self.port}/{database}"

    def socket_url(self, database: str) -> str:
        """The Unix-socket URL of `database` (`postgresql:///db?host=<dir>`)."""
        return f"postgresql:///{database}?host={self.socket_dir}&port={self.port}&user={PG_USER}"

    def admin(self, statement: str) -> None:
        """Run one statement in the `postgres` database, outside a transaction."""
        import psycopg

        with psycopg.connect(self.url("postgres"), autocommit=True, connect_timeout=10) as conn:
            conn.execute(statement)

    def create_database(self, prefix: str = "test") -> str:
        """A new empty database (a name not used before in this cluster), locale-aware where
        PostgreSQL has ICU (`LOCALE_AWARE`); returns its name."""
        import psycopg

        name = f"{re.sub(r'[^a-z0-9_]', '_', prefix.lower())[:40]}_{next(self._names)}"
        if self._database_options is not None:
            try:
                self.admin(f'CREATE DATABASE "{name}" {self._database_options}')
                return name
            except psycopg.Error:  # no ICU in this build: the cluster's locale it is
                self._database_options = None
        self.admin(f'CREATE DATABASE "{name}"')
        return name

    def drop_database(self, name: str) -> None:
        """Drop a database, cutting off any client still connected to it."""
        self.admin(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


def start_cluster() -> PgCluster:
    """A running throwaway cluster; pytest.skip where PostgreSQL cannot be found."""
    bin_dir = find_pg_bin()
    if bin_dir is None:
        pytest.skip(
            "PostgreSQL not found (no initdb/pg_ctl on PATH or under "
            f"{DEBIAN_PG_ROOT}/<version>/bin); scripts/setup.sh installs Debian's postgresql"
        )
    if os.geteuid() == 0 and (shutil.which("runuser") is None or not _has_user(PG_USER)):
        pytest.skip(f"running as root without runuser or a {PG_USER!r} user to run PostgreSQL")
    cluster = PgCluster(bin_dir)
    try:
        cluster.init()
        cluster.start()
    except BaseException:
        cluster.remove()
        raise
    return cluster


def _has_user(name: str) -> bool:
    try:
        pwd.getpwnam(name)
    except KeyError:
        return False
    return True


# ---------------------------------------------------------------------- fixtures
@pytest.fixture(scope="session")
def pg_cluster() -> Iterator[PgCluster]:
    """The test session's PostgreSQL cluster (started on first use, removed at the end)."""
    cluster = start_cluster()
    try:
        yield cluster
    finally:
        cluster.remove()


@pytest.fixture(scope="session")
def pg_url(pg_cluster: PgCluster) -> str:
    """URL of a database created once for the test session."""
    return pg_cluster.url(pg_cluster.create_database("session"))


@pytest.fixture
def fresh_pg_url(pg_cluster: PgCluster, request: pytest.FixtureRequest) -> Iterator[str]:
    """URL of a new empty database for this test alone (dropped after it)."""
    name = pg_cluster.create_database(request.node.name)
    yield pg_cluster.url(name)
    pg_cluster.drop_database(name)
