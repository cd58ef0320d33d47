"""Moved: the question grammar lives in app.relations.grammar. These names stay importable
from here for the modules that still do (app/server/sessions.py, app/speech/vocabulary.py,
app/cli/relations_eval.py); new code imports app.relations.grammar."""

from app.relations.grammar import Reading, is_relational, parse, question_phrases

__all__ = ["Reading", "is_relational", "parse", "question_phrases"]
