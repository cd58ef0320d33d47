"""Moved: answering a question about how things stand lives in app.answering (`ask`,
`relational.answer`). These names stay importable from here for the modules that still do
(app/server/sessions.py, app/server/routes/rest.py, app/cli/relations_eval.py); new code
imports app.answering."""

from app.answering.relational import answer
from app.answering.things import MapThing, RelationalHit, is_match

__all__ = ["MapThing", "RelationalHit", "answer", "is_match"]
