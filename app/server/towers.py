"""The server's static text towers: the file `--static-tower` names, or the one it distils
from its text tower on first need and keeps in DATA_DIR/towers (app.semantics.distil's
TowerStore), each served by its SHA-256 (`GET /v1/text-towers/{sha256}`) and embedding the
labels of the sessions created with it (`text_tower: "static"`)."""

from __future__ import annotations

import gzip
import logging
import threading
from collections.abc import Callable
from concurrent.futures import Future
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from app.semantics import TextEncoder
    from app.semantics.distil import TowerStore
    from app.semantics.static import StaticTower

log = logging.getLogger("semanticxr")

TOWERS_DIR = "towers"
"""The folder of DATA_DIR that keeps the server's static towers, one file per hash."""


class MissingTowerError(RuntimeError):
    """A static session's tower is not in the server's tower store: the session cannot be
    loaded with the tower it was created with (and with no other)."""


class TowerFileError(ValueError):
    """`--static-tower FILE` is unreadable, not a tower, or distilled from another tower
    than the server's."""


def read_tower_file(path: str | Path, teacher: str | None = None) -> StaticTower:
    """The tower in `path`; TowerFileError naming the file and what is wrong (unreadable,
    not a static tower, or not distilled from `teacher` when given)."""
    from app.semantics.static import StaticTower, TowerError

    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise TowerFileError(f"--static-tower {path}: {exc.strerror or exc}") from None
    try:
        tower = StaticTower.from_bytes(data)
    except TowerError as exc:
        raise TowerFileError(f"--static-tower {path}: not a static text tower: {exc}") from None
    if teacher is not None and tower.teacher != teacher:
        raise TowerFileError(
            f"--static-tower {path}: distilled from {tower.teacher}, but this server embeds "
            f"with {teacher}; distil one from it (semanticxr towers distil --teacher {teacher})"
        )
    return tower


class TowerService:
    """The static towers of one server: `for_new_session()` (the tower new static sessions
    get, distilled once on first need), `tower(sha)` / `encoder(sha)` (a stored tower by
    hash, for a session created with it), `file_bytes(sha)` (what the route serves)."""

    def __init__(
        self,
        directory: str | Path,
        teacher: str,
        static_tower: str | None = None,
        build: Callable[[str, Callable[[str], None]], bytes] | None = None,
    ):
        """build(teacher, progress) -> tower file: how a tower is distilled (default
        `distil_static_tower`)."""
        self.directory = Path(directory)
        self._build = build
        self.teacher = teacher
        """The model id of the server's text tower, the one static towers are distilled from."""
        self._store: TowerStore | None = None
        self._lock = threading.Lock()
        self._towers: dict[str, StaticTower] = {}
        self._encoders: dict[str, TextEncoder] = {}
        self._files: dict[str, bytes] = {}
        self._gzipped: dict[str, bytes] = {}
        self._current: StaticTower | None = None
        self._distilling: Future[StaticTower] | None = None
        if static_tower is not None:
            tower = read_tower_file(static_tower, teacher)
            stored = self.store.put(tower.to_bytes())  # kept: a restart without the flag has it
            self._current = self._towers[stored.sha256] = stored
            log.info("static text tower %s from %s", stored.model_id, static_tower)

    @property
    def store(self) -> TowerStore:
        """The tower store in `directory`, made on first use (a server whose sessions are all
        MiniLM never makes it)."""
        if self._store is None:
            from app.semantics.distil import TowerStore

            self._store = TowerStore(self.directory)
        return self._store

    def for_new_session(self) -> StaticTower:
        """The tower a new static session is created with: `--static-tower`'s, else the one
        distilled from the server's text tower (once, on first need, in a worker thread,
        logging its progress, and kept in the tower store for later starts). Creators that
        ask meanwhile wait for that one distillation."""
        with self._lock:
            if self._current is not None:
                return self._current
            if self._distilling is None:
                self._distilling = Future()
                threading.Thread(
                    target=self._distil, args=(self._distilling,), name="distil-tower", daemon=True
                ).start()
            distilling = self._distilling
        return distilling.result()

    def _distil(self, future: Future[StaticTower]) -> None:
        def build(teacher: str) -> bytes:
            log.info(
                "distilling a static text tower from %s (once; minutes; kept in %s)",
                teacher,
                self.directory,
            )
            if self._build is not None:
                return self._build(teacher, progress)
            from app.semantics.distil import distil_static_tower

            return distil_static_tower(teacher, progress=progress)

        def progress(message: str) -> None:
            log.info("distilling: %s", message)

        try:
            tower = self.store.for_teacher(self.teacher, build=build)
        except BaseException as exc:
            log.exception("distilling the static text tower failed")
            with self._lock:
                self._distilling = None  # the next creator tries again
            future.set_exception(exc)
            return
        with self._lock:
            self._current = self._towers[tower.sha256] = tower
            self._distilling = None
        log.info("static text tower %s ready", tower.model_id)
        future.set_result(tower)

    def tower(self, sha256: str) -> StaticTower | None:
        """The stored tower of that hash; None when the store does not hold it."""
        with self._lock:
            if sha256 in self._towers:
                return self._towers[sha256]
        data = self.store.get(sha256)
        if data is None:
            return None
        from app.semantics.static import StaticTower

        tower = StaticTower.from_bytes(data)
        with self._lock:
            return self._towers.setdefault(sha256, tower)

    def file_bytes(self, sha256: str) -> bytes | None:
        """The tower file of that hash, as served; None when the store does not hold it."""
        with self._lock:
            if sha256 in self._files:
                return self._files[sha256]
        data = self.store.get(sha256)
        if data is not None:
            with self._lock:
                self._files[sha256] = data
        return data

    def gzipped_bytes(self, sha256: str) -> bytes | None:
        """`file_bytes` gzipped (level 6, no timestamp: the same bytes on every server; a
        distilled tower's 7.8 MB go as 5.4 in 0.3 s, once per tower); None as file_bytes."""
        with self._lock:
            if sha256 in self._gzipped:
                return self._gzipped[sha256]
        data = self.file_bytes(sha256)
        if data is None:
            return None
        packed = gzip.compress(data, compresslevel=6, mtime=0)
        with self._lock:
            return self._gzipped.setdefault(sha256, packed)

    def encoder(self, sha256: str) -> TextEncoder:
        """The encoder of the stored tower of that hash (one per tower, shared by its
        sessions, with its label cache); MissingTowerError when the store does not hold it."""
        with self._lock:
            if sha256 in self._encoders:
                return self._encoders[sha256]
        tower = self.tower(sha256)
        if tower is None:
            raise MissingTowerError(
                f"this session embeds with the static text tower {sha256}, which this "
                f"server's tower store ({self.directory}) no longer holds; start the server "
                f"with --static-tower FILE holding that tower (no other tower can read the "
                f"session's map)"
            )
        from app.answering.towers import map_static_encoder

        with self._lock:  # labels with their texts, as every map-making end embeds them
            return self._encoders.setdefault(sha256, map_static_encoder(tower))
