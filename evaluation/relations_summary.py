"""The relations scenario's summary: the judged questions' records pooled into the figures of
its document, and the table `semanticxr eval --scenario relations` prints."""

from __future__ import annotations

from collections import Counter

import numpy as np

POSITIVE_FAMILIES = ("relational", "any")
"""Question families with a right answer in the room (negatives have none; plain ones are
scored apart)."""


def share(values) -> float | None:
    """Percentage of true values (None when there are none)."""
    values = list(values)
    return 100.0 * sum(bool(v) for v in values) / len(values) if values else None


def pct(value: float | None, width: int = 6) -> str:
    return f"{'n/a':>{width + 1}}" if value is None else f"{value:{width}.1f}%"


def _percentiles(values: list[float]) -> dict[str, float] | None:
    if not values:
        return None
    arr = np.asarray(values, np.float64)
    return {
        "p50": float(np.percentile(arr, 50)),
        "p95": float(np.percentile(arr, 95)),
        "mean": float(arr.mean()),
    }


def summarize(
    records: list[dict],
    index_ms: list[float],
    update_ms: list[float],
    changed: list[int],
    objects_at_end: list[int],
) -> dict:
    positive = [r for r in records if r["family"] in POSITIVE_FAMILIES]
    lq_asked = [r for r in records if "lq_equals_sq" in r]
    negative = [r for r in records if r["family"] == "negative"]
    plain = [r for r in records if r["family"] == "plain"]
    right = [r for r in positive + plain if r["right"]]
    by_wording = {
        wording: {
            "asked": len(group),
            "top1": share(r["right"] for r in group),
            "top1_perfect_map": share(r["perfect_map_right"] for r in group),
        }
        for wording in ("category names", "other names")
        for group in [[r for r in positive if r["wording"] == wording]]
    }
    by_kind: dict[str, dict] = {}
    for r in positive + negative:
        key = f"{r['family']}:{r['kind']}"
        slot = by_kind.setdefault(key, {"asked": 0, "right": 0})
        slot["asked"] += 1
        slot["right"] += bool(r["right"])
        slot["perfect_map"] = slot.get("perfect_map", 0) + bool(r["perfect_map_right"])
    for slot in by_kind.values():
        slot["percent"] = 100.0 * slot["right"] / slot["asked"]
        slot["perfect_map"] = 100.0 * slot["perfect_map"] / slot["asked"]
    keys = ("seed", "question", "family", "kind", "expected", "got", "reason", "detail")
    failed = [
        {**{k: r[k] for k in keys}, "perfect_map_right": r["perfect_map_right"]}
        for r in records
        if not r["right"]
    ]
    perfect_failed = [
        {
            **{k: r[k] for k in ("seed", "question", "family", "kind", "expected")},
            "reason": r["perfect_map_reason"],
            "detail": r["perfect_map_detail"],
        }
        for r in records
        if not r["perfect_map_right"]
    ]
    unmatched = [
        {k: r[k] for k in ("seed", "question", "family", "kind", "expected", "got")}
        for r in right
        if not r["match"]
    ]
    return {
        "top1": share(r["right"] for r in positive),
        "top1_perfect_map": share(r["perfect_map_right"] for r in positive),
        "negatives_no_match": share(r["right"] for r in negative),
        "negatives_no_match_perfect_map": share(r["perfect_map_right"] for r in negative),
        "right_answers_match": share(r["match"] for r in right),
        "right_answers_match_relational": share(
            r["match"] for r in right if r["family"] in POSITIVE_FAMILIES
        ),
        "right_answers_match_plain": share(r["match"] for r in right if r["family"] == "plain"),
        "plain_top1": share(r["right"] for r in plain),
        "plain_path_top1": share(r["plain_path_right"] for r in plain),
        "plain_same_top1": share(r["same_as_plain_path"] for r in plain),
        "plain_read_as_relational": [r["question"] for r in plain if r["relational_path"]],
        "plain_changed": [
            {
                "seed": r["seed"],
                "question": r["question"],
                "right": r["right"],
                "plain_path_right": r["plain_path_right"],
            }
            for r in plain
            if not r["same_as_plain_path"]
        ],
        "lq_equals_sq": share(r["lq_equals_sq"] for r in lq_asked) if lq_asked else None,
        "lq_equals_sq_up_to_ties": share(r["lq_up_to_ties"] for r in lq_asked)
        if lq_asked
        else None,
        "lq_asked": len(lq_asked),
        "lq_differences": [
            {k: r[k] for k in ("seed", "question", "family", "kind", "lq_detail", "lq_up_to_ties")}
            for r in lq_asked
            if not r["lq_equals_sq"]
        ],
        "index_update_ms": _percentiles(index_ms),
        "index_update_only_ms": _percentiles(update_ms),
        "index_changed_per_keyframe": _percentiles([float(c) for c in changed]),
        "index_objects_at_end": objects_at_end,
        "questions": len(records),
        "asked": {
            "relational": sum(r["family"] == "relational" for r in records),
            "any": sum(r["family"] == "any" for r in records),
            "negative": len(negative),
            "plain": len(plain),
        },
        "by_kind": dict(sorted(by_kind.items())),
        "top1_by_wording": by_wording,
        "failure_reasons": dict(
            Counter(
                f"{f['family']}: {f['reason']}"
                + ("" if f["perfect_map_right"] else " (also on a perfect map)")
                for f in failed
            ).most_common()
        ),
        "failures": failed,
        "perfect_map_failure_reasons": dict(
            Counter(f"{f['family']}: {f['reason']}" for f in perfect_failed).most_common()
        ),
        "perfect_map_failures": perfect_failed,
        "right_without_match": unmatched,
    }


def format_relations_table(result: dict) -> str:
    """The stdout table of `eval --scenario relations`."""
    rel = result["relations"]
    index = rel["index_update_ms"] or {"p50": float("nan"), "p95": float("nan")}
    asked = rel["asked"]
    lq = pct(rel["lq_equals_sq"])
    lines = [
        f"relation rooms, seeds {result['seeds']}: {result['keyframes']} keyframes of "
        f"{result['frames']} frames each, noise {result['noise']}; {rel['questions']} questions "
        f"({asked['relational']} relational, {asked['any']} 'what is ...', "
        f"{asked['negative']} negatives, {asked['plain']} plain)",
        f"{'':<28} {'map':>7} {'perfect map':>12}",
        f"{'relational top-1':<28} {pct(rel['top1'])} {pct(rel['top1_perfect_map'], 11)}",
        f"{'negatives match=false':<28} {pct(rel['negatives_no_match'])} "
        f"{pct(rel['negatives_no_match_perfect_map'], 11)}",
        f"{'right answers match=true':<28} {pct(rel['right_answers_match'])}",
        f"{'plain top-1 (plain path)':<28} {pct(rel['plain_top1'])} "
        f"(plain path{pct(rel['plain_path_top1'])}, same top-1{pct(rel['plain_same_top1'])})",
        f"{'LQ = SQ':<28} {lq} of {rel['lq_asked']} relational, 'what is' and negatives "
        f"({pct(rel['lq_equals_sq_up_to_ties']).strip()} up to exact ties)",
        f"{'index update p50 / p95':<28} {index['p50']:6.2f} / {index['p95']:.2f} ms",
        *(
            f"{'  named by ' + wording:<28} {pct(slot['top1'])} "
            f"{pct(slot['top1_perfect_map'], 11)}  ({slot['asked']} questions)"
            for wording, slot in rel["top1_by_wording"].items()
        ),
        f"{'kind':<22} {'asked':>6} {'right':>7} {'perfect map':>12}",
    ]
    for kind, slot in rel["by_kind"].items():
        lines.append(
            f"{kind:<22} {slot['asked']:6d} {pct(slot['percent'])} {pct(slot['perfect_map'], 11)}"
        )
    reasons = list(rel["failure_reasons"].items())
    lines.append("failures by why:" + ("" if reasons else " none"))
    lines += [f"  {count:4d}  {reason}" for reason, count in reasons]
    for diff in rel["lq_differences"]:
        if not diff["lq_up_to_ties"]:
            lines.append(f"LQ != SQ: {diff['question']!r}: {diff['lq_detail']}")
    return "\n".join(lines)
