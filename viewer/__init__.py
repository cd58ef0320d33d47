"""The viser 3D viewer: follows a session's map updates and shows objects and query hits.

`viewer.scene` turns deltas into scene-node operations (pure, no viser; its colours are in
`viewer.palette`, boxes and framing in `viewer.shapes`, relation words in `viewer.words`);
`viewer.app` is the viser server, its GUI and the updates subscription. The app's names are
imported lazily so that `viewer.scene` stays usable (and fast to import) without viser.
"""

from __future__ import annotations

from typing import Any

from viewer.scene import DeltaError, DeltaSummary, SceneModel, SceneSink, ViewObject

__all__ = [
    "DeltaError",
    "DeltaSummary",
    "SceneModel",
    "SceneSink",
    "ViewObject",
    "ViewerApp",
]


def __getattr__(name: str) -> Any:
    if name == "ViewerApp":
        from viewer import app

        return getattr(app, name)
    raise AttributeError(f"module 'viewer' has no attribute {name!r}")
