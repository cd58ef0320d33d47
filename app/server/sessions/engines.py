"""Perception backends and the mapping engine each session maps with."""

from __future__ import annotations

from app.config import Knobs
from app.mapping.engine import MappingEngine
from app.perception import DEFAULT_BACKEND, BackendOptions, make_backend
from app.perception.base import PerceptionBackend
from app.semantics import TextEncoder
from app.server.settings import ServerSettings
from app.store import SessionRecord


class Engines:
    """The perception backends loaded at start and the engine each session maps with."""

    def __init__(self, settings: ServerSettings, encoder: TextEncoder):
        self.settings = settings
        self.encoder = encoder
        self.backends: dict[str, PerceptionBackend] = {}
        """Perception backends loaded (at start), by name: what sessions may choose."""
        for name in [*settings.perception_backends, DEFAULT_BACKEND]:
            self._load_backend(name)

    def _load_backend(self, name: str) -> PerceptionBackend:
        if name not in self.backends:
            options = BackendOptions(models_dir=self.settings.models_dir)
            self.backends[name] = make_backend(name, options)
        return self.backends[name]

    def engine(self, rec: SessionRecord, knobs: Knobs) -> MappingEngine:
        """The session's engine: its backend as its organisation uses it, and the backend's
        text encoder when it has one (a `models` session embeds labels and queries with
        CLIP's text tower, and announces that model), else the server's."""
        backend = self._load_backend(rec.perception).for_mode(rec.mode)
        encoder = backend.text_encoder or self.encoder
        return MappingEngine(
            encoder, knobs, mode=rec.mode, backend=backend, max_objects=self.settings.max_objects
        )
