"""Relational local queries on the device: relational LQ vs plain LQ at 10k objects.

    python -m bench.relations_device [--out out/] [--objects 10000] [--reps 30]

One `LocalMap` (the device defaults: 200 points an object, 384-d int8 embeddings) is fed by
v1 deltas of 1,000 objects: the tiled floor of bench.relations (6 m rooms of 20 objects each:
a table with a mug, a book, a laptop and a plate on it, a bag and a box under it and a lamp
over it, four chairs, a sofa with a bag on it and a side table by it, a bookcase with two
books in it, a plant, a bin), its labels embedded by the session's text encoder (MiniLM), the
user standing in the middle room. Timed, both as `client_sim.querying.QueryRouter` answers
offline and with the same encoder:

- plain LQ: the query embedded (`encode_query`), the local map's similarity search
  (`query_embedding`, k=5) and the hits rated (`rate_hits`), over everyday questions;
- relational LQ: the phrases embedded (`app.answering.phrases.phrases_of`, one `encoder.encode` call)
  and `LocalMap.relational_query` (k=5), per question, warm (as a device asks: its labels
  and phrases already in the encoder's cache, the relation bodies of the last questions
  kept within `relation_cache_mb`) and cold (the phrases embedded anew and no body kept:
  every question starts from nothing).

Target (a benchmark, not a test): relational LQ <= 2x a plain LQ at 10k objects.
The machine may be shared: p50 and p95 are both recorded.
"""

from __future__ import annotations

import os
import time

import numpy as np

from app.protocol import UpsertEntry, pack_delta
from bench.common import bench_parser, check, machine, timed_ms, write_outputs
from bench.relations import ROOM_M, floor_of

DELTA_OBJECTS = 1000
PLAIN_QUESTIONS = [
    "where are my keys",
    "a place to sit",
    "something to drink from",
    "the red backpack",
    "my laptop",
    "a book about birds",
    "where can I put my cup",
    "a lamp",
]
RELATIONAL_QUESTIONS = [
    "the mug on the table",
    "the bag under the table",
    "the bag on the sofa",
    "the book in the bookcase",
    "what is on the table",
    "the lamp closest to me",
    "the chair left of the sofa",
    "the biggest table",
]


def build_local_map(objects: int, encoder, seed: int):
    """A LocalMap holding `objects` objects of the tiled floor, fed by deltas; the user's
    position in the middle room."""
    from client_sim.local_map import LocalMap

    world = floor_of(objects, np.random.default_rng(seed))
    labels = sorted({label for label, _ in world})
    embedding = dict(zip(labels, encoder.encode(labels), strict=True))
    local = LocalMap(dim=encoder.dim, max_points_per_object=200, budget_mb=10_000)
    for seq, start in enumerate(range(0, len(world), DELTA_OBJECTS), start=1):
        upserts = [
            UpsertEntry(
                id=i,
                version=1,
                label=label,
                embedding=embedding[label],
                points=points,
                bbox=(*points.min(axis=0).tolist(), *points.max(axis=0).tolist()),
                n_obs=3,
            )
            for i, (label, points) in enumerate(world[start : start + DELTA_OBJECTS], start=start)
        ]
        local.apply_delta(pack_delta(seq, upserts, full=seq == 1))
    rooms = -(-objects // 20)
    side = int(np.ceil(np.sqrt(rooms)))
    middle = rooms // 2
    local.set_user_position([ROOM_M * (middle % side) + 3.0, ROOM_M * (middle // side) + 3.0, 1.6])
    return local


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    parser = bench_parser(__doc__)
    parser.add_argument("--objects", type=int, default=10_000, help="objects in the local map")
    parser.add_argument("--reps", type=int, default=30, help="timed repeats per question")
    parser.add_argument("--seed", type=int, default=0, help="seed of the floor's points")
    parser.add_argument("--out", default="out", help="folder for relations_device.json")
    args = parser.parse_args(argv)

    import torch

    from app.answering.phrases import phrases_of
    from app.answering.relevance import rate_hits, rater_for
    from app.relations.grammar import parse
    from app.semantics import get_text_encoder

    encoder = get_text_encoder()
    rater_for(encoder)  # the vocabulary embedded once, as a device does on its first query
    start = time.perf_counter()
    local = build_local_map(args.objects, encoder, args.seed)
    build_s = time.perf_counter() - start
    empty_bytes = local.memory_bytes()
    print(
        f"relational LQ on the device: {len(local)} objects ({empty_bytes / 1e6:.1f} MB, fed "
        f"in {build_s:.1f} s), torch threads {torch.get_num_threads()}, k=5"
    )

    plain_texts = iter([f"{text} {i}" for i in range(100_000) for text in PLAIN_QUESTIONS])

    def plain_lq() -> None:
        embedding = encoder.encode_query(next(plain_texts))
        hits = local.query_embedding(embedding, 5)
        rate_hits(encoder, embedding, [hit.label for hit in hits])

    plain = timed_ms(plain_lq, 3 * args.reps)
    print(f"  plain LQ: p50 {plain['p50']:.1f} ms, p95 {plain['p95']:.1f} ms")

    rows = []
    for text in RELATIONAL_QUESTIONS:
        reading = parse(text)
        phrases = phrases_of(reading)

        def relational_lq(reading=reading, phrases=phrases) -> object:
            encoder.encode(phrases)  # what the router does off its loop
            return local.relational_query(reading, encoder, k=5)

        def forget(phrases=phrases) -> None:  # cold: phrases embedded anew, no body kept
            with encoder._lock:
                for phrase in phrases:
                    encoder._cache.pop(phrase, None)
            local._forget_relations()

        hits = relational_lq()
        assert hits is not None, f"{text!r} was answered as plain"
        warm = timed_ms(relational_lq, args.reps)
        cold = timed_ms(relational_lq, args.reps, before=forget)
        best = hits[0]
        rows.append(
            {
                "question": text,
                "warm_ms": warm,
                "cold_ms": cold,
                "kept_bodies": len(local._bodies),
                "top1": {"id": best.id, "label": best.label, "kind": best.relation.kind},
            }
        )
        print(
            f"  {text!r:32} warm p50 {warm['p50']:5.1f} / p95 {warm['p95']:5.1f} ms, cold p50 "
            f"{cold['p50']:5.1f} / p95 {cold['p95']:5.1f} ms  ({best.label} {best.id} "
            f"{best.relation.kind}, degree {best.relation.degree:.2f})"
        )
    relational_lq()  # the last question again: what it keeps
    kept_bytes = local.memory_bytes() - empty_bytes

    def overall(key: str, stat: str) -> float:
        return float(np.median([row[key][stat] for row in rows]))

    summary = {
        "plain_p50_ms": plain["p50"],
        "plain_p95_ms": plain["p95"],
        "relational_warm_p50_ms": overall("warm_ms", "p50"),
        "relational_warm_p95_ms": overall("warm_ms", "p95"),
        "relational_cold_p50_ms": overall("cold_ms", "p50"),
        "relational_cold_p95_ms": overall("cold_ms", "p95"),
        "worst_cold_p95_ms": max(row["cold_ms"]["p95"] for row in rows),
        "kept_bytes": kept_bytes,
    }
    for name in ("warm", "cold"):
        p50, p95 = summary[f"relational_{name}_p50_ms"], summary[f"relational_{name}_p95_ms"]
        print(
            f"  relational LQ {name} (median over the questions): p50 {p50:.1f} ms, p95 "
            f"{p95:.1f} ms; ratio to plain LQ p50 {p50 / plain['p50']:.2f}x, p95 "
            f"{p95 / plain['p95']:.2f}x"
        )
    print(
        f"  worst question cold p95 {summary['worst_cold_p95_ms']:.1f} ms; kept for the next "
        f"question: {kept_bytes / 1e6:.2f} MB (in memory_bytes)"
    )
    targets = [
        check(
            f"relational LQ p50 / plain LQ p50 at {args.objects} objects (warm)",
            summary["relational_warm_p50_ms"] / plain["p50"],
            "<=",
            2.0,
            "x",
        ),
        check(
            f"relational LQ p50 / plain LQ p50 at {args.objects} objects (cold)",
            summary["relational_cold_p50_ms"] / plain["p50"],
            "<=",
            2.0,
            "x",
        ),
    ]
    document = {
        "bench": "relations_device",
        "machine": machine(),
        "config": {
            "objects": len(local),
            "reps": args.reps,
            "torch_threads": torch.get_num_threads(),
            "model": encoder.model_id,
        },
        "targets": targets,
        "plain_ms": plain,
        "questions": rows,
        "summary": summary,
    }
    write_outputs(args.out, "relations_device", document)
    return 0 if all(target["ok"] for target in targets) else 1


if __name__ == "__main__":
    raise SystemExit(main())
