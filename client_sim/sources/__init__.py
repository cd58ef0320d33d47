"""Frame sources of the device emulator: one interface (`FrameSource`), one module per source.

Recorded datasets (`tum`, `7scenes`, `replica`) and iPhone/iPad captures (`record3d`: a
Record3D .r3d file; `stray`: a Stray Scanner folder) are built from a "kind:path" spec with
`make_source`; the synthetic world lives in `client_sim.sources.synthetic`, and its scripted
second visit in `client_sim.sources.revisit`. All are imported lazily, so reading a dataset
never loads the synthetic world (open3d scenes, renderer).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from client_sim.sources.base import FrameSource, SourceError, SourceFrame

if TYPE_CHECKING:
    from client_sim.sources.revisit import RevisitSource
    from client_sim.sources.synthetic import SyntheticFrame, SyntheticSource

SOURCE_KINDS: tuple[str, ...] = (
    "synthetic",
    "revisit",
    "tum",
    "7scenes",
    "replica",
    "record3d",
    "stray",
)
PHONE_SOURCE_KINDS: tuple[str, ...] = ("record3d", "stray")
"""The kinds that take `max_side_px` and `min_confidence` (client_sim.sources.phone)."""

__all__ = [
    "PHONE_SOURCE_KINDS",
    "SOURCE_KINDS",
    "FrameSource",
    "RevisitSource",
    "SourceError",
    "SourceFrame",
    "SyntheticFrame",
    "SyntheticSource",
    "make_source",
]


def make_source(spec: str, **kwargs: Any) -> FrameSource:
    """A source from "kind:path" (kind in SOURCE_KINDS; for synthetic and revisit, the path is a
    scene name such as "apartment"); kwargs go to its loader.

    Raises ValueError naming the valid source kinds when the spec is malformed.
    """
    kind, sep, path = str(spec).partition(":")
    if not sep or not path or kind not in SOURCE_KINDS:
        raise ValueError(
            f"bad source spec {spec!r}: expected 'kind:path' with kind one of {', '.join(SOURCE_KINDS)}"
        )
    if kind == "synthetic":
        from client_sim.sources.synthetic import SyntheticSource

        return SyntheticSource(path, **kwargs)
    if kind == "revisit":
        from client_sim.sources.revisit import RevisitSource

        return RevisitSource(path, **kwargs)
    if kind == "tum":
        from client_sim.sources.tum import TumSource

        return TumSource(path, **kwargs)
    if kind == "7scenes":
        from client_sim.sources.sevenscenes import SevenScenesSource

        return SevenScenesSource(path, **kwargs)
    if kind == "record3d":
        from client_sim.sources.record3d import Record3DSource

        return Record3DSource(path, **kwargs)
    if kind == "stray":
        from client_sim.sources.stray import StraySource

        return StraySource(path, **kwargs)
    from client_sim.sources.replica import ReplicaSource

    return ReplicaSource(path, **kwargs)


def __getattr__(name: str) -> Any:
    # The synthetic source pulls in the whole procedural world; import it on first use only.
    if name in ("SyntheticSource", "SyntheticFrame"):
        from client_sim.sources import synthetic

        return getattr(synthetic, name)
    if name == "RevisitSource":
        from client_sim.sources import revisit

        return revisit.RevisitSource
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
