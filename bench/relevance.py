"""How often a query's answer says "match" when it should, with the real MiniLM encoder; and
the calibration of the match rule (app.answering.relevance) per text tower.

    python -m bench.relevance [--tower minilm|static] [--maps 5] [--objects 20] [--out out/]
    python -m bench.relevance --calibrate      # fits the tower's rule, writes the package's
                                               # match_rules.json and background_texts.json
    python -m bench.relevance --cv             # leave-one-category-out validation of the fit

`--tower static` measures the static tower distilled from MiniLM (app.semantics.static; the
one in `--static-tower FILE`, else the one in the tower cache, distilled there on first use)
and writes relevance_static.json.

Maps of `--objects` random synthetic categories; queries are asked of every map, answered as
the server does (top 5 by label, rated with the labels' WordNet texts). Two sets of wordings:

- training: every category's name and `paraphrases` (world.categories), the only wordings
  the calibration sees;
- outside: bench/data/wordings/outside.json (descriptions and other names a person would
  type, by category) and outside_negatives.json (things no map here holds, and nonsense),
  written apart and never calibrated on.

Per set: right answers with match (top-1 is the asked category and the answer says match),
recall (the category is in the map and the answer says match), false matches (the category
is absent, the top-1 is not a listed confusion of it, or the query is a negative, and the
answer says match). Then the fixed queries: the demo's must match, nonsense and an absent
object must not.
"""

from __future__ import annotations

import argparse
import json
import random
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from app.answering.label_knowledge import label_texts
from app.answering.relevance import (
    BACKGROUND_EMBEDDINGS_DIR,
    BACKGROUND_TEXTS_RESOURCE,
    CONFIDENT,
    RULES_RESOURCE,
    STATIC_RULE_KEY,
    MatchRule,
    QueryRater,
    Standing,
    background_embeddings_name,
    background_text_list,
    background_texts,
    background_vocabulary,
)
from app.answering.towers import text_tower
from app.semantics import TextEncoder
from app.semantics.static import is_static_model_id
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

WORDINGS = Path(__file__).parent / "data" / "wordings"
FALSE_MATCH_TARGET = 0.08
"""The calibration keeps training false matches at most this (the issue's limit is 10 %)."""
ALIKE_COSINES = (0.65, 0.7, 0.75, 1.01)
"""alike_cosine values the calibration tries (above 1: no label is alike another)."""


@dataclass(frozen=True)
class Asked:
    """One query asked of one map."""

    kind: str
    """"right" (top-1 is the category), "wrong_top" (the category is present, top-1 another),
    "absent" (the category is absent and top-1 no confusion of it), "negative"."""
    top: list[str]
    """The top-5 labels, best first."""
    standings: list[Standing]
    text: str = ""
    """The query."""
    category: str = ""
    """The category it asks for ("" for a negative)."""
    rivals: list[tuple[str, str] | None] = field(default_factory=list)
    """Per top-5 label, the background label its gap is measured against and the text of it
    the query scores best (`QueryRater.rival`)."""


def outside_wordings() -> tuple[dict[str, str], list[str]]:
    """The held-out set: ({query: category}, [negative query])."""
    by_category = json.loads((WORDINGS / "outside.json").read_text("utf-8"))
    negatives = json.loads((WORDINGS / "outside_negatives.json").read_text("utf-8"))
    return {q: c for c, queries in by_category.items() for q in queries}, list(negatives)


def training_wordings() -> dict[str, str]:
    """{query: category}: every category's name and paraphrases."""
    return {q: c for c in _categories() for q in (c, *CATEGORIES[c].paraphrases)}


def _categories() -> list[str]:
    return [c for c in CATEGORIES if not is_background(c)]


def _related(a: str, b: str) -> bool:
    return a == b or a in CATEGORIES[b].confusions or b in CATEGORIES[a].confusions


def ask(
    encoder: TextEncoder,
    rater: QueryRater,
    queries: dict[str, str],
    negatives: list[str],
    maps: int,
    objects: int,
) -> list[Asked]:
    """Every query asked of `maps` random maps of `objects` categories (seeded), with the
    standings of its top 5 under the rater's rule."""
    categories = _categories()
    texts = {c: label_texts(c) for c in categories}
    asked_texts = list(queries) + list(negatives)
    embeddings = dict(zip(asked_texts, encoder.encode(asked_texts), strict=True))
    rng = random.Random(0)
    out = []
    for _ in range(maps):
        present = rng.sample(categories, objects)
        present_embeddings = encoder.encode_labels(present)
        for text in asked_texts:
            category = queries.get(text)
            order = np.argsort(-(present_embeddings @ embeddings[text]))[:5]
            top = [present[i] for i in order]
            if category is None:
                kind = "negative"
            elif category in present:
                kind = "right" if top[0] == category else "wrong_top"
            elif not _related(top[0], category):
                kind = "absent"
            else:
                continue
            standings = rater.standing(embeddings[text], top, texts) or []
            rivals = [rater.rival(embeddings[text], label) for label in top]
            out.append(Asked(kind, top, standings, text, category or "", rivals))
    return out


def figures(asked: list[Asked], rule: MatchRule) -> dict:
    """Right answers with match, recall and false matches of these answers under `rule`."""

    def match(a: Asked) -> bool:
        return any(s.relevance(rule) >= CONFIDENT for s in a.standings)

    def share(kinds: tuple[str, ...]) -> tuple[float, int]:
        chosen = [match(a) for a in asked if a.kind in kinds]
        return sum(chosen) / max(len(chosen), 1), len(chosen)

    present = [a for a in asked if a.kind in ("right", "wrong_top")]
    right, n_right = share(("right",))
    recall, n_present = share(("right", "wrong_top"))
    false, n_false = share(("absent", "negative"))
    negatives, n_negatives = share(("negative",))
    return {
        "top1": n_right / max(len(present), 1),
        "right_answers_match": right,
        "right_answers": n_right,
        "recall": recall,
        "queries_present": n_present,
        "false_match_rate": false,
        "queries_absent_or_negative": n_false,
        "negatives_false_match_rate": negatives,
        "negatives": n_negatives,
    }


def failures(asked: list[Asked], rule: MatchRule) -> list[dict]:
    """The answers `rule` gets wrong, each once with how many maps gave it: a right top-1
    without match ("right_unmatched"), or a match for a thing the map lacks or a negative
    ("false_match"), with the standings (z, gap, z_name) and relevance of `label`: the hit
    that says match, else the top-1."""
    seen: dict[tuple[str, str, str], dict] = {}
    for a in asked:
        relevance = [s.relevance(rule) for s in a.standings]
        matched = any(r >= CONFIDENT for r in relevance)
        if a.kind == "right" and not matched:
            kind = "right_unmatched"
        elif a.kind in ("absent", "negative") and matched:
            kind = "false_match"
        else:
            continue
        key = (kind, a.text, a.top[0])
        if key in seen:
            seen[key]["maps"] += 1
            continue
        # the hit that says match (false_match), else the top-1
        shown = next((i for i, r in enumerate(relevance) if r >= CONFIDENT), 0)
        standing = a.standings[shown] if a.standings else Standing(0.0, 0.0, 0.0)
        seen[key] = {
            "kind": kind,
            "query": a.text,
            "top": a.top,
            "label": a.top[shown],
            "z": round(standing.z, 3),
            "gap": round(standing.gap, 3),
            "z_name": round(standing.z_name, 3),
            "relevance": float(relevance[shown]) if relevance else 0.0,  # unrounded: vs 0.5
            # the background label the gap is measured against, and by which of its texts
            "rival": list(a.rivals[shown]) if a.rivals and a.rivals[shown] else None,
            "maps": 1,
        }
    return sorted(seen.values(), key=lambda f: (f["kind"], -f["maps"], f["query"]))


def calibrate(by_alike: dict[float, list[Asked]]) -> tuple[MatchRule, dict]:
    """The rule for this tower fitted on the training wordings asked (`asked_per_alike`,
    `fit_rule`), with its figures on them."""
    rule = fit_rule(by_alike)
    if rule is None:
        raise RuntimeError("no rule keeps the training false matches within the target")
    return rule, figures(by_alike[rule.alike_cosine], rule)


def asked_per_alike(
    encoder: TextEncoder, maps: int, objects: int, alikes: tuple[float, ...] = ALIKE_COSINES
) -> dict[float, list[Asked]]:
    """The training wordings asked (`ask`) under each alike_cosine, the background's texts
    read from WordNet."""
    vocabulary_texts = {label: label_texts(label) for label in background_vocabulary()}
    by_alike = {}
    for alike in alikes:
        rater = QueryRater(
            encoder, vocabulary_texts=vocabulary_texts, rule=MatchRule(alike_cosine=alike)
        )
        by_alike[alike] = ask(encoder, rater, training_wordings(), [], maps, objects)
    return by_alike


def fit_rule(by_alike: dict[float, list[Asked]]) -> MatchRule | None:
    """Per alike_cosine, a logistic regression of "right top-1 label" against "a top-5 label
    of an absent category" on (z, gap, z_name), its bias then moved to the most right answers
    with match whose false matches stay within FALSE_MATCH_TARGET; the alike_cosine with the
    most right answers (None: no rule keeps the false matches within the target)."""
    best: tuple[float, MatchRule] | None = None
    for alike, asked in by_alike.items():
        positives = [a.standings[0] for a in asked if a.kind == "right"]
        negatives = [s for a in asked if a.kind == "absent" for s in a.standings]
        if not positives or not negatives:
            continue
        x = np.array(positives + negatives, np.float64)
        y = np.r_[np.ones(len(positives)), np.zeros(len(negatives))]
        w = _logistic(x, y)
        rule = MatchRule(w_z=w[0], w_gap=w[1], w_name=w[2], bias=w[3], alike_cosine=alike)
        # per answer, its best hit's score without the bias: a match from -bias on
        best_score = np.array(
            [max((rule.score(*s) - rule.bias for s in a.standings), default=-np.inf) for a in asked]
        )
        right = np.array([a.kind == "right" for a in asked])
        false = np.array([a.kind in ("absent", "negative") for a in asked])
        for shift in np.arange(-4.0, 4.0, 0.05):
            bias = round(float(rule.bias + shift), 4)
            # relevance_of rounds to 5 decimals: a score from -2e-5 reads CONFIDENT
            match = best_score + bias >= -2e-5
            false_rate = match[false].sum() / max(false.sum(), 1)
            right_rate = match[right].sum() / max(right.sum(), 1)
            if false_rate <= FALSE_MATCH_TARGET and (best is None or right_rate > best[0]):
                best = (right_rate, replace(rule, bias=bias))
    return best[1] if best is not None else None


def cross_validate(by_alike: dict[float, list[Asked]]) -> dict:
    """Leave-one-category-out cross-validation of `fit_rule` on the training wordings: per
    category, the rule fitted on the others' queries rates that category's (its right
    answers and its absent queries); the figures summed over the folds, and how the fitted
    weights vary from fold to fold."""
    categories = sorted({a.category for asked in by_alike.values() for a in asked})
    held: list[bool] = []  # per held-out answer: matched; with its kind
    kinds: list[str] = []
    rules = []
    for category in categories:
        rule = fit_rule(
            {k: [a for a in asked if a.category != category] for k, asked in by_alike.items()}
        )
        if rule is None:
            continue
        rules.append(rule)
        for a in by_alike[rule.alike_cosine]:
            if a.category == category:
                held.append(any(s.relevance(rule) >= CONFIDENT for s in a.standings))
                kinds.append(a.kind)
    matched = np.array(held, bool)
    kind = np.array(kinds)

    def rate(chosen: np.ndarray) -> float:
        return round(float(matched[chosen].mean()), 4) if chosen.any() else 0.0

    weights = {
        f: [getattr(r, f) for r in rules]
        for f in ("w_z", "w_gap", "w_name", "bias", "alike_cosine")
    }
    return {
        "folds": len(rules),
        "right_answers_match": rate(kind == "right"),
        "right_answers": int((kind == "right").sum()),
        "false_match_rate": rate(np.isin(kind, ("absent", "negative"))),
        "queries_absent_or_negative": int(np.isin(kind, ("absent", "negative")).sum()),
        "weights": {
            f: {
                "min": round(min(v), 4),
                "median": round(float(np.median(v)), 4),
                "max": round(max(v), 4),
            }
            for f, v in weights.items()
        },
        "folds_w_z_negative": sum(w < 0 for w in weights["w_z"]),
    }


def _logistic(x: np.ndarray, y: np.ndarray, l2: float = 1e-3, steps: int = 50) -> list[float]:
    """Weights and bias [k + 1] of a logistic regression of y {0, 1} [n] on x [n, k]
    (Newton's method, a little ridge), each class weighted to half the total."""
    features = np.c_[x, np.ones(len(x))]
    sample_weight = np.where(y == 1, 0.5 / max(y.sum(), 1), 0.5 / max((1 - y).sum(), 1))
    w = np.zeros(features.shape[1])
    for _ in range(steps):
        p = 1.0 / (1.0 + np.exp(-(features @ w)))
        gradient = features.T @ (sample_weight * (p - y)) + l2 * w
        hessian = (features * (sample_weight * p * (1 - p))[:, None]).T @ features
        w -= np.linalg.solve(hessian + l2 * np.eye(len(w)), gradient)
    return [round(float(v), 4) for v in w]


def write_calibration(encoder: TextEncoder, rule: MatchRule, training: dict) -> Path:
    """The rule into the package's record (other towers' records kept), the background's
    label texts beside it and the tower's embeddings of them (float16, with the texts)."""
    model_id = encoder.model_id
    package = Path(__file__).resolve().parents[1] / "app" / "answering"
    path = package / RULES_RESOURCE
    record = json.loads(path.read_text("utf-8")) if path.is_file() else {"towers": {}}
    entry = {
        **asdict(rule),
        "calibrated_on": "world.categories names and paraphrases (python -m bench.relevance "
        "--calibrate)",
        "training": {k: round(v, 4) if isinstance(v, float) else v for k, v in training.items()},
    }
    static = is_static_model_id(model_id)
    # A static tower's rule also stands for its other distillations (another hash); it
    # embeds the background in milliseconds, so none is shipped for it.
    for key in (model_id, STATIC_RULE_KEY) if static else (model_id,):
        record["towers"][key] = entry
    path.write_text(json.dumps(record, indent=1, sort_keys=True) + "\n", "utf-8")
    texts = {label: list(label_texts(label)) for label in background_vocabulary()}
    (package / BACKGROUND_TEXTS_RESOURCE).write_text(
        json.dumps(texts, indent=0, sort_keys=True) + "\n", "utf-8"
    )
    background_texts.cache_clear()
    if not static:
        write_background_embeddings(encoder)
    return path


def write_background_embeddings(encoder: TextEncoder) -> Path:
    """The tower's embeddings of the package's background texts (float16, with the texts
    they embed), which every end reads instead of embedding them at start."""
    package = Path(__file__).resolve().parents[1] / "app" / "answering"
    shipped = background_text_list()
    folder = package / BACKGROUND_EMBEDDINGS_DIR
    folder.mkdir(exist_ok=True)
    path = folder / background_embeddings_name(encoder.model_id)
    np.savez_compressed(
        path, texts=np.array(shipped), embeddings=encoder.encode(shipped).astype(np.float16)
    )
    return path


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--maps", type=int, default=5, help="random maps (default 5)")
    parser.add_argument("--objects", type=int, default=20, help="categories per map (default 20)")
    parser.add_argument("--out", default="out", help="folder for relevance.json (default out)")
    parser.add_argument(
        "--calibrate",
        action="store_true",
        help="fit this tower's match rule on the training wordings and write it to the package",
    )
    parser.add_argument(
        "--cv",
        action="store_true",
        help="cross-validate the calibration, leaving one category out at a time",
    )
    parser.add_argument(
        "--tower",
        choices=("minilm", "static"),
        default="minilm",
        help="the text tower measured (default minilm)",
    )
    parser.add_argument(
        "--static-tower",
        metavar="FILE",
        help="with --tower static: this tower file (default: the tower cache's)",
    )
    parser.add_argument(
        "--failures",
        action="store_true",
        help="print every answer the rule gets wrong with its standings (always in the JSON)",
    )
    args = parser.parse_args(argv)
    encoder = text_tower(args.tower, args.static_tower)
    cv = None
    if args.calibrate or args.cv:
        by_alike = asked_per_alike(encoder, args.maps, args.objects)
        if args.cv:
            cv = cross_validate(by_alike)
            print(
                f"leave-one-category-out ({cv['folds']} folds): right answers match "
                f"{cv['right_answers_match']:.1%} over {cv['right_answers']}; false matches "
                f"{cv['false_match_rate']:.1%} over {cv['queries_absent_or_negative']}; "
                f"w_z < 0 in {cv['folds_w_z_negative']} folds; weights {cv['weights']}"
            )
        if args.calibrate:
            rule, training = calibrate(by_alike)
            print(f"calibrated {encoder.model_id}: {rule}")
            print(f"written to {write_calibration(encoder, rule, training)}")
    rater = QueryRater(encoder)  # the shipped rule and background texts
    outside, negatives = outside_wordings()
    asked_training = ask(encoder, rater, training_wordings(), [], args.maps, args.objects)
    asked_outside = ask(encoder, rater, outside, negatives, args.maps, args.objects)
    training, held_out = figures(asked_training, rater.rule), figures(asked_outside, rater.rule)
    no_keys = [c for c in _categories() if c != "keys"]
    no_keys_embeddings = encoder.encode_labels(no_keys)
    fixed = {}
    for text in MUST_MATCH + MUST_NOT_MATCH:
        embedding = encoder.encode_query(text)
        top = [no_keys[i] for i in np.argsort(-(no_keys_embeddings @ embedding))[:5]]
        fixed[text] = rater.rate(embedding, top, {c: label_texts(c) for c in top}).match
    document = {
        "machine": machine(),
        "tower": args.tower,
        "encoder": encoder.model_id,
        "rule": asdict(rater.rule),
        "maps": args.maps,
        "objects_per_map": args.objects,
        "training": training,
        "outside": held_out,
        # the training figures at the top level, as before
        "recall": training["recall"],
        "right_answers_match": training["right_answers_match"],
        "false_match_rate": training["false_match_rate"],
        # what the rule gets wrong, query by query, with the top-1's standings
        "training_failures": failures(asked_training, rater.rule),
        "outside_failures": failures(asked_outside, rater.rule),
        "cross_validation": cv,
        "fixed_queries_match": fixed,
        "fixed_queries_right": all(fixed[t] for t in MUST_MATCH)
        and not any(fixed[t] for t in MUST_NOT_MATCH),
    }
    for name, got in (("training", training), ("outside", held_out)):
        print(
            f"{name:>8}: top-1 {got['top1']:.1%}; right answers match {got['right_answers_match']:.1%} over "
            f"{got['right_answers']}; recall {got['recall']:.1%} over {got['queries_present']}; "
            f"false matches {got['false_match_rate']:.1%} over "
            f"{got['queries_absent_or_negative']} (negatives {got['negatives_false_match_rate']:.1%}"
            f" over {got['negatives']})"
        )
    if args.failures:
        for name in ("training", "outside"):
            for f in document[f"{name}_failures"]:
                print(
                    f"{name:>8} {f['kind']:<15} {f['query']!r} -> {f['label']} (top-1 {f['top'][0]}) "
                    f"(z {f['z']:.2f}, gap {f['gap']:.2f}, z_name {f['z_name']:.2f}, "
                    f"relevance {f['relevance']:.2f}; {f['maps']} of {args.maps} maps)"
                    + (f"; rival {f['rival'][0]} by {f['rival'][1]!r}" if f["rival"] else "")
                )
    print(f"fixed queries right: {document['fixed_queries_right']} {fixed}")
    write_outputs(args.out, "relevance" if args.tower == "minilm" else "relevance_static", document)
    return document


if __name__ == "__main__":
    main()
