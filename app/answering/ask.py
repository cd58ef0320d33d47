"""`ask`: a question asked of a map, the one way every end asks it.

The server (a session's relational query), the device's local map (LQ), the device's query
router and the relations eval all ask here, so they answer alike: the grammar reads the
question; a reading about how things stand (a relation or a superlative) is answered by
`app.answering.relational.answer` over the map's objects and a relation source
(`RelationIndex` on the server, `OnDemandRelations` on the device); anything else, or a
question the map cannot ground, is None: the caller answers it as a plain query (its text
embedding ranked against the objects, rated by `app.answering.relevance.rate_hits`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from app.answering.relational import answer
from app.answering.relevance import LabelTexts
from app.answering.things import MapThing, MapThings, RelationalHit
from app.relations.grammar import Reading, is_relational, parse
from app.relations.source import RelationSource
from app.semantics import TextEncoder


def relational_reading(question: str | Reading) -> Reading | None:
    """The question's reading when it asks how things stand (a relation or a superlative),
    None for a plain question: what a caller checks before gathering the map for `ask`."""
    reading = parse(question) if isinstance(question, str) else question
    return reading if is_relational(reading) else None


def ask(
    question: str | Reading,
    things: Sequence[MapThing] | MapThings,
    relations: RelationSource,
    encoder: TextEncoder,
    viewer: np.ndarray | None = None,
    k: int = 5,
    label_texts: LabelTexts | None = None,
) -> list[RelationalHit] | None:
    """The top-k objects answering a question about how things stand, best first; None: a
    plain question, or one to answer as plain (an anchor the map holds nothing confident of,
    a question seen from the asker with no position).

    things: the map's objects, each with its geometry in `relations` under its id (same up
    axis); viewer: the asker's position float [3], metres, world frame (None: unknown);
    label_texts: the labels' texts the match rule reads (None: each label alone).
    """
    reading = relational_reading(question)
    if reading is None:
        return None
    return answer(reading, things, relations, encoder, viewer, k, label_texts)
