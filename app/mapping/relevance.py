"""Moved: a hit's relevance lives in app.answering.relevance. These names stay importable
from here for the modules that still do (app/server/sessions.py, app/server/app.py,
viewer/app.py, app/cli/relations_eval.py, tests/bench/test_relevance_bench.py); new code
imports app.answering.relevance."""

from app.answering.relevance import (
    CONFIDENT,
    MATCH_MAX_GAP_Z,
    MATCH_MIN_Z,
    Rating,
    rate_hits,
    rater_for,
)

__all__ = ["CONFIDENT", "MATCH_MAX_GAP_Z", "MATCH_MIN_Z", "Rating", "rate_hits", "rater_for"]
