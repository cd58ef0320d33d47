"""The evaluation: the synthetic world mapped in process and scored against its truth.

One module per scenario, each a config and a run: `walk` (one walk, semantic quality and
speed), `relations` (questions about how things stand), `revisit` (does the map follow a
changed world); the metrics beside them (`semantic_scores`, `change_scores`). The
definitions are in docs/evaluation.md. `semanticxr eval` (app/cli/eval.py) and the benches
(bench/) call it. This package sits in the top layer with them and imports nothing here, so
that importing one scenario does not load the others.
"""
