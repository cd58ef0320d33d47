"""Answering a question asked of a map: how well hits answer it, and what stands how.

- `ask`: the one way every end asks (the server, the device's local map and query router,
  the relations eval): read the question, answer it relationally or leave it plain.
- `relevance`: a hit's calibrated relevance and the `match` verdict of a plain query, rated
  against a background vocabulary (the `models` perception backend's, app/perception/models/
  vocabulary.txt, read as package data).
- `relational`: scoring every object of a map against a reading (`answer`); `things` (what it
  reads of the map, the hits it gives), `phrases`, `question` (grounding, clauses) and
  `superlative` are its parts.

Layered above app.relations (the geometry and the grammar) and app.perception (whose
vocabulary file relevance reads), below app.mapping: nothing here reads the mapping engine;
the callers hand it the map's objects.
"""
