"""Perception backends, text towers and the mapping engine each session maps with."""

from __future__ import annotations

from pathlib import Path

from app.config import Knobs
from app.errors import InputError
from app.mapping.engine import MappingEngine
from app.perception import DEFAULT_BACKEND, BackendOptions, make_backend
from app.perception.base import PerceptionBackend
from app.protocol.rest import TEXT_TOWERS, EmbeddingInfo
from app.semantics import TextEncoder
from app.server.settings import ServerSettings
from app.server.towers import TOWERS_DIR, TowerService
from app.store import SessionRecord

STATIC = "static"
"""The text tower of a session that embeds with a static table (`TowerService`)."""


class Engines:
    """The perception backends loaded at start, the static text towers, and the engine each
    session maps with."""

    def __init__(self, settings: ServerSettings, encoder: TextEncoder):
        self.settings = settings
        self.encoder = encoder
        self.backends: dict[str, PerceptionBackend] = {}
        """Perception backends loaded (at start), by name: what sessions may choose."""
        for name in [*settings.perception_backends, DEFAULT_BACKEND]:
            self._load_backend(name)
        self.towers = TowerService(
            Path(settings.data_dir) / TOWERS_DIR, encoder.model_id, settings.static_tower
        )
        """The static text towers: distilled from `encoder` or `--static-tower`'s."""

    def _load_backend(self, name: str) -> PerceptionBackend:
        if name not in self.backends:
            options = BackendOptions(models_dir=self.settings.models_dir)
            self.backends[name] = make_backend(name, options)
        return self.backends[name]

    def tower_of_new_session(self, text_tower: str, perception: str) -> str | None:
        """The tower file's SHA-256 a new session with `text_tower` is created with (None
        for minilm); InputError naming `text_tower` for an unknown one, or a static one on a
        backend with its own text tower (`models`: none distilled from it so far). May
        wait minutes for the first distillation."""
        if text_tower not in TEXT_TOWERS:
            raise InputError(
                "text_tower", f"must be one of {', '.join(TEXT_TOWERS)}; got {text_tower!r}"
            )
        if text_tower != STATIC:
            return None
        if self._load_backend(perception).text_encoder is not None:
            raise InputError(
                "text_tower",
                f"static is not available with perception {perception!r}: only MiniLM "
                f"sessions (perception detections) have a static tower so far",
            )
        return self.towers.for_new_session().sha256

    def engine(self, rec: SessionRecord, knobs: Knobs) -> MappingEngine:
        """The session's engine: its backend as its organisation uses it, and its text
        encoder: the backend's when it has one (a `models` session embeds labels and queries
        with CLIP's text tower, and announces that model), the static tower the session was
        created with (MissingTowerError when the tower store no longer holds it), else the
        server's."""
        backend = self._load_backend(rec.perception).for_mode(rec.mode)
        if rec.text_tower == STATIC and rec.tower_sha256 is not None:
            encoder = self.towers.encoder(rec.tower_sha256)
        else:
            encoder = backend.text_encoder or self.encoder
        return MappingEngine(
            encoder, knobs, mode=rec.mode, backend=backend, max_objects=self.settings.max_objects
        )


def embedding_info(encoder: TextEncoder, rec: SessionRecord) -> EmbeddingInfo:
    """The session's `embedding`: its encoder's model and dimension, and for a static tower
    the SHA-256 of its file (what a device downloads it by)."""
    sha256 = rec.tower_sha256 if rec.text_tower == STATIC else None
    return EmbeddingInfo(model=encoder.model_id, dim=encoder.dim, sha256=sha256)
