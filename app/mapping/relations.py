"""Moved: relations live in app.relations (bodies, pairwise, index ...). These names stay
importable from here for the modules that still do (app/mapping/places.py,
app/server/sessions.py, app/cli/relations_eval.py); new code imports app.relations."""

from app.relations.bodies import Z_UP, snap_to_axis
from app.relations.index import ObjectGeometry, RelationIndex

__all__ = ["Z_UP", "ObjectGeometry", "RelationIndex", "snap_to_axis"]
