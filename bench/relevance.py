"""How often a query's answer says "match" when it should, with the real MiniLM encoder.

    python -m bench.relevance [--maps 5] [--objects 20] [--out out/]

Maps of `--objects` random synthetic categories; every category's name and paraphrases are
asked of every map, answered as the server does (top 5 by label, rated by
app.answering.relevance). A query whose category is in the map should match (recall); one
whose category is absent should not match an unrelated object (false matches; a confusion
of the category, e.g. "chair" for "armchair", is not counted either way). Then the fixed
queries: the demo's must match, nonsense and absent objects must not.
"""

from __future__ import annotations

import argparse
import random

import numpy as np

from app.answering.relevance import CONFIDENT, MATCH_MAX_GAP_Z, MATCH_MIN_Z, rater_for, relevance_of
from app.semantics import get_text_encoder
from bench.common import machine, write_outputs
from world.categories import CATEGORIES, is_background

MUST_MATCH = (
    "something to sit on",
    "where can I wash the dishes?",
    "the fridge",
    "where can I make coffee?",
    "where do I keep the milk cold",
    "something to keep food cold",
    "a chair",
)
MUST_NOT_MATCH = ("xyzzy plugh", "asdf qwer", "blorp", "hello world", "keys")
# Not listed: "where are my keys" on a map without keys matches a keyboard (MiniLM puts
# the sentence nearer "keyboard" than "keys"), a known miss.


def _related(a: str, b: str) -> bool:
    return a == b or a in CATEGORIES[b].confusions or b in CATEGORIES[a].confusions


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--maps", type=int, default=5, help="random maps (default 5)")
    parser.add_argument("--objects", type=int, default=20, help="categories per map (default 20)")
    parser.add_argument("--out", default="out", help="folder for relevance.json (default out)")
    args = parser.parse_args(argv)
    encoder = get_text_encoder()
    rater = rater_for(encoder)
    categories = [c for c in CATEGORIES if not is_background(c)]
    queries = {q: c for c in categories for q in (c, *CATEGORIES[c].paraphrases)}
    query_embeddings = dict(zip(queries, encoder.encode(list(queries)), strict=True))

    def answer(text: str, embedding: np.ndarray, present: list[str]) -> tuple[str, bool]:
        label_scores = encoder.encode(present) @ embedding
        top = [present[i] for i in np.argsort(-label_scores)[:5]]
        return top[0], rater.rate(embedding, top).match

    rng = random.Random(0)
    found = absent_matched = asked_present = asked_absent = 0
    right: list[tuple[float, float]] = []  # (z, gap) of right top-1 answers
    unrelated: list[tuple[float, float]] = []  # ... of top-1 answers to absent things
    for _ in range(args.maps):
        present = rng.sample(categories, args.objects)
        for text, category in queries.items():
            best, match = answer(text, query_embeddings[text], present)
            standing = rater.standing(query_embeddings[text], [best])
            if category in present:
                asked_present += 1
                found += match
                if best == category and standing is not None:
                    right.append(standing[0])
            elif not _related(best, category):
                asked_absent += 1
                absent_matched += match
                if standing is not None:
                    unrelated.append(standing[0])
    no_keys = [c for c in categories if c != "keys"]
    fixed = {
        text: answer(text, encoder.encode_query(text), no_keys)[1]
        for text in MUST_MATCH + MUST_NOT_MATCH
    }
    document = {
        "machine": machine(),
        "encoder": encoder.model_id,
        "maps": args.maps,
        "objects_per_map": args.objects,
        "recall": found / asked_present,
        "right_answers_match": _match_rate(right),
        "curve": _curve(right, unrelated, asked_absent),
        "false_match_rate": absent_matched / asked_absent,
        "queries_present": asked_present,
        "queries_absent": asked_absent,
        "fixed_queries_match": fixed,
        "fixed_queries_right": all(fixed[t] for t in MUST_MATCH)
        and not any(fixed[t] for t in MUST_NOT_MATCH),
    }
    print(f"{'min z':>6} {'max gap':>8} {'right answers match':>20} {'false matches':>14}")
    for point in document["curve"]:
        print(
            f"{point['min_z']:6.1f} {point['max_gap_z']:8.1f} "
            f"{point['right_answers_match']:20.1%} {point['false_match_rate']:14.1%}"
            + ("  <- today" if point["today"] else "")
        )
    print(
        f"right answers match {document['right_answers_match']:.1%} over {len(right)}; "
        f"recall {document['recall']:.1%} over {asked_present} queries, false matches "
        f"{document['false_match_rate']:.1%} over {asked_absent}; fixed queries right: "
        f"{document['fixed_queries_right']}"
    )
    write_outputs(args.out, "relevance", document)
    return document


CURVE_MIN_Z = (2.6, 2.8, 3.0, 3.2, 3.4)
CURVE_MAX_GAP_Z = (2.0, 2.5, 3.0)


def _match_rate(
    standings: list[tuple[float, float]],
    min_z: float = MATCH_MIN_Z,
    max_gap_z: float = MATCH_MAX_GAP_Z,
) -> float:
    """Share of these top-1 answers rated a confident match at these limits."""
    rated = [relevance_of(z, gap, min_z, max_gap_z) >= CONFIDENT for z, gap in standings]
    return sum(rated) / max(len(rated), 1)


def _curve(right: list, unrelated: list, asked_absent: int) -> list[dict]:
    """Right top-1 answers rated a match against top-1 answers to absent things rated a
    match, over the match limits (shown where the encoder cannot reach both targets at
    once). The top-1 answer alone: `false_match_rate` above counts a match
    by any of the top 5."""
    return [
        {
            "min_z": min_z,
            "max_gap_z": max_gap_z,
            "right_answers_match": _match_rate(right, min_z, max_gap_z),
            "false_match_rate": _match_rate(unrelated, min_z, max_gap_z)
            * len(unrelated)
            / max(asked_absent, 1),
            "today": (min_z, max_gap_z) == (MATCH_MIN_Z, MATCH_MAX_GAP_Z),
        }
        for min_z in CURVE_MIN_Z
        for max_gap_z in CURVE_MAX_GAP_Z
    ]


if __name__ == "__main__":
    main()
