"""Perception: frame -> per-object detections, behind one interface (`base.PerceptionBackend`).

Backends by name: the server loads the ones its `perception` setting names at start, and a
session chooses among those and `detections`. A new backend is a new module here and one
line in `BACKENDS`. Importing this package stays light: a backend's module is imported only
when the backend is made (a model backend's libraries load with it).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from app.perception.base import PerceptionBackend

__all__ = ["BACKENDS", "DEFAULT_BACKEND", "UnknownBackendError", "make_backend"]


def _detections() -> PerceptionBackend:
    from app.perception.detections import DetectionsBackend

    return DetectionsBackend()


BACKENDS: dict[str, Callable[[], PerceptionBackend]] = {"detections": _detections}
"""Backend name -> factory (called once per server: one instance serves every session)."""

DEFAULT_BACKEND = "detections"
"""Always available: the device sends its detections with the frame."""


class UnknownBackendError(ValueError):
    """A perception backend name that is not registered."""


def make_backend(name: str = DEFAULT_BACKEND) -> PerceptionBackend:
    """The perception backend called `name`; UnknownBackendError if there is none."""
    factory = BACKENDS.get(name)
    if factory is None:
        raise UnknownBackendError(
            f"unknown perception backend {name!r}; available: {', '.join(BACKENDS)}"
        )
    return factory()
