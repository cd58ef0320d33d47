"""Perception: frame -> per-object detections, behind one interface (`base.PerceptionBackend`).

Backends by name: the server loads the ones its `perception` setting names at start, and a
session chooses among those and `detections`. A new backend is a new module here and one
line in `BACKENDS`. Importing this package stays light: a backend's module is imported only
when the backend is made (a model backend's libraries load with it).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from app.perception.base import PerceptionBackend

__all__ = [
    "BACKENDS",
    "DEFAULT_BACKEND",
    "BackendOptions",
    "UnknownBackendError",
    "make_backend",
]


@dataclass(frozen=True)
class BackendOptions:
    """What a backend may need from the server's settings to load."""

    models_dir: str | None = None
    """Folder of model sub-folders (`models` backend); None loads Hugging Face ids."""


def _detections(options: BackendOptions) -> PerceptionBackend:
    from app.perception.detections import DetectionsBackend

    return DetectionsBackend()


def _models(options: BackendOptions) -> PerceptionBackend:
    from app.perception.models.weights import CPU_PROFILE, resolve_models

    resolve_models(CPU_PROFILE, options.models_dir)  # a missing model fails before torch loads
    os.environ.setdefault("TRANSFORMERS_VERBOSITY", "error")  # not its torchvision notices
    from app.perception.models.backend import load_models_backend

    return load_models_backend(options.models_dir)


BACKENDS: dict[str, Callable[[BackendOptions], PerceptionBackend]] = {
    "detections": _detections,
    "models": _models,
}
"""Backend name -> factory (called once per server: one instance serves every session)."""

DEFAULT_BACKEND = "detections"
"""Always available: the device sends its detections with the frame."""


class UnknownBackendError(ValueError):
    """A perception backend name that is not registered."""


def make_backend(
    name: str = DEFAULT_BACKEND, options: BackendOptions | None = None
) -> PerceptionBackend:
    """The perception backend called `name`; UnknownBackendError if there is none (the
    `models` backend raises MissingModelsError when its weights are not there)."""
    factory = BACKENDS.get(name)
    if factory is None:
        raise UnknownBackendError(
            f"unknown perception backend {name!r}; available: {', '.join(BACKENDS)}"
        )
    return factory(options or BackendOptions())
