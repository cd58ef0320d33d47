"""Perception backends and the mapping engine each session maps with."""

from __future__ import annotations

from app.config import Knobs
from app.mapping.engine import MappingEngine
from app.perception import BackendOptions, make_backend
from app.perception.base import PerceptionBackend
from app.store import SessionRecord


class EnginesMixin:
    """The perception backends loaded at start and the engine a session maps with."""

    def _load_backend(self, name: str) -> PerceptionBackend:
        if name not in self.backends:
            options = BackendOptions(models_dir=self.settings.models_dir)
            self.backends[name] = make_backend(name, options)
        return self.backends[name]

    def _engine(self, rec: SessionRecord, knobs: Knobs) -> MappingEngine:
        """The session's engine: its backend as its organisation uses it, and the backend's
        text encoder when it has one (a `models` session embeds labels and queries with
        CLIP's text tower, and announces that model), else the server's."""
        backend = self._load_backend(rec.perception).for_mode(rec.mode)
        encoder = backend.text_encoder or self.encoder
        return MappingEngine(
            encoder, knobs, mode=rec.mode, backend=backend, max_objects=self.settings.max_objects
        )
