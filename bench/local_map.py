"""Device local map: memory and local query (LQ) latency from 80 to 50,000 objects.

    python -m bench.local_map [--out out/] [--sizes 80,1000,5000,10000,25000,50000]

One `LocalMap` is grown by v1 deltas of 1,000 objects (200 float16 points and a random unit
384-d embedding each, in 1 m boxes scattered over a 100 m square). At each size it measures
memory_bytes, the similarity part of a local query (`query_embedding`, k=5), and a local
query end to end (MiniLM `encode_query` + `query_embedding`); text encoding alone is
measured once. The baseline's device map is a full-resolution full copy: 2,000 float32
points and a float32 embedding per object, computed rather than allocated.

Targets (DESIGN.md "Targets", 2 CPU cores): LQ p50 <= 25 ms at 10k objects and <= 40 ms at
50k; 50k objects of 200 points within 128 MB (SI megabytes). The similarity part should
stay near 10 ms or less at 50k, since text encoding takes most of the LQ budget.
"""

from __future__ import annotations

import argparse
import gc
import os
import time
import tracemalloc
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING

import numpy as np

from app.protocol import DEFAULT_EMBEDDING_DIM, UpsertEntry, pack_delta
from bench.common import check, machine, save_plot, write_outputs

if TYPE_CHECKING:
    from app.semantics import TextEncoder

DIM = DEFAULT_EMBEDDING_DIM
POINTS_PER_OBJECT = 200
BASELINE_POINTS_PER_OBJECT = 2000  # the server cap: the baseline ships objects uncapped
DELTA_OBJECTS = 1000
QUERIES = [
    "where are my keys",
    "a place to sit",
    "something to drink from",
    "the lamp by the window",
    "my laptop",
    "a book about birds",
    "the red backpack",
    "where can I sleep",
]


def object_upserts(ids: range, rng: np.random.Generator, version: int = 1) -> list[UpsertEntry]:
    """`upserts[]` entries for `ids`: random unit embeddings, 200 points in a 1 m box."""
    embeddings = rng.standard_normal((len(ids), DIM)).astype(np.float32)
    embeddings /= np.linalg.norm(embeddings, axis=1, keepdims=True)
    corners = rng.uniform(-50, 50, (len(ids), 3))
    points = corners[:, None, :] + rng.uniform(0, 1, (len(ids), POINTS_PER_OBJECT, 3))
    return [
        UpsertEntry(
            id=oid,
            version=version,
            label=f"object {oid % 300}",
            embedding=embeddings[i],
            points=points[i],
            bbox=(*points[i].min(axis=0).tolist(), *points[i].max(axis=0).tolist()),
            n_obs=3,
        )
        for i, oid in enumerate(ids)
    ]


def delta(seq: int, upserts: list[UpsertEntry]) -> dict:
    """The wire `delta` (as msgpack would unpack it) of `upserts`."""
    return pack_delta(seq, upserts)


def timed_ms(run: Callable[[], object], reps: int) -> dict:
    """p50/p99/mean in ms of `reps` calls of `run` (after one warm-up call)."""
    run()
    times_ms = []
    for _ in range(reps):
        start = time.perf_counter_ns()
        run()
        times_ms.append((time.perf_counter_ns() - start) / 1e6)
    return {
        "p50": float(np.percentile(times_ms, 50)),
        "p99": float(np.percentile(times_ms, 99)),
        "mean": float(np.mean(times_ms)),
    }


def baseline_bytes(objects: int) -> int:
    """Device memory of the baseline's full copy: float32 points at full resolution, a float32
    embedding and the same per-object metadata as the local map."""
    from client_sim.local_map import PYTHON_BYTES_PER_OBJECT, LocalMap

    metadata_row_bytes = LocalMap(dim=DIM)._row_bytes() - 2 * DIM  # columns besides embedding
    per_object = BASELINE_POINTS_PER_OBJECT * 3 * 4 + DIM * 4 + metadata_row_bytes
    return objects * (per_object + PYTHON_BYTES_PER_OBJECT)


def traced_memory(objects: int) -> dict:
    """memory_bytes vs what tracemalloc sees the map allocate, for `objects` objects."""
    from client_sim.local_map import LocalMap

    rng = np.random.default_rng(1)
    messages = [
        delta(seq, object_upserts(range(start, min(start + DELTA_OBJECTS, objects)), rng))
        for seq, start in enumerate(range(0, objects, DELTA_OBJECTS), start=1)
    ]
    gc.collect()
    tracemalloc.start()
    try:
        local = LocalMap(dim=DIM, max_points_per_object=POINTS_PER_OBJECT)
        start = tracemalloc.get_traced_memory()[0]
        for message in messages:
            local.apply_delta(message)
        gc.collect()
        traced = tracemalloc.get_traced_memory()[0] - start
    finally:
        tracemalloc.stop()
    accounted = local.memory_bytes()
    return {
        "objects": objects,
        "memory_bytes": accounted,
        "traced_bytes": traced,
        "ratio": traced / accounted,
    }


def points_storage_error(rng: np.random.Generator) -> dict:
    """Max error (m) of float16 world points (what the wire carries and the map stores) and of
    int16 points quantised in the object's box (the alternative, same 6 bytes a point)."""
    corners = rng.uniform(-50, 50, (1000, 1, 3))
    points = corners + rng.uniform(0, 1, (1000, POINTS_PER_OBJECT, 3))
    wire = points.astype(np.float16).astype(np.float64)
    low, high = wire.min(axis=1, keepdims=True), wire.max(axis=1, keepdims=True)
    step = (high - low) / 65535
    quantised = np.round((wire - low) / step) * step + low
    return {
        "float16_max_error_m": float(np.abs(wire - points).max()),
        "int16_in_bbox_max_error_m": float(np.abs(quantised - points).max()),
        "int16_extra_error_over_wire_m": float(np.abs(quantised - wire).max()),
        "bytes_per_point": 6,
    }


def grow_and_measure(
    sizes: list[int],
    encoder: TextEncoder,
    query_texts: Iterator[str],
    rng: np.random.Generator,
    args: argparse.Namespace,
) -> list[dict]:
    """Grow one local map through `sizes` by deltas; memory and latencies at each size."""
    from client_sim.local_map import BYTES_PER_MB, LocalMap

    local = LocalMap(dim=DIM, max_points_per_object=POINTS_PER_OBJECT, budget_mb=10_000)
    rows = []
    seq = 0
    for size in sizes:
        apply_s = 0.0
        added = 0
        while len(local) < size:
            seq += 1
            ids = range(len(local), min(len(local) + DELTA_OBJECTS, size))
            message = delta(seq, object_upserts(ids, rng))
            start = time.perf_counter()
            local.apply_delta(message)
            apply_s += time.perf_counter() - start
            added += len(ids)
        queries = iter(rng.standard_normal((args.similarity_reps + 1, DIM)).astype(np.float32))
        similarity = timed_ms(
            lambda queries=queries: local.query_embedding(next(queries), k=5), args.similarity_reps
        )
        end_to_end = timed_ms(
            lambda: local.query_embedding(encoder.encode_query(next(query_texts)), k=5),
            args.end_to_end_reps,
        )
        row = {
            "objects": len(local),
            "memory_bytes": local.memory_bytes(),
            "baseline_bytes": baseline_bytes(len(local)),
            "similarity_ms": similarity,
            "end_to_end_ms": end_to_end,
            "apply_us_per_object": 1e6 * apply_s / max(added, 1),
        }
        rows.append(row)
        print(
            f"  {row['objects']:>6} objects: {row['memory_bytes'] / BYTES_PER_MB:7.1f} MB "
            f"(baseline {row['baseline_bytes'] / BYTES_PER_MB:8.1f} MB), similarity p50 "
            f"{similarity['p50']:.2f} / p99 {similarity['p99']:.2f} ms, LQ p50 "
            f"{end_to_end['p50']:.1f} / p99 {end_to_end['p99']:.1f} ms, "
            f"apply {row['apply_us_per_object']:.0f} us/object"
        )
    return rows


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--sizes", default="80,1000,5000,10000,25000,50000")
    parser.add_argument("--similarity-reps", type=int, default=300)
    parser.add_argument("--end-to-end-reps", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="out", help="folder for local_map.json and .png")
    args = parser.parse_args(argv)
    sizes = sorted(int(size) for size in args.sizes.split(","))

    import torch

    from app.semantics import get_text_encoder
    from client_sim.local_map import BYTES_PER_MB

    encoder = get_text_encoder()
    rng = np.random.default_rng(args.seed)
    query_texts = iter([f"{text} {i}" for i in range(10_000) for text in QUERIES])
    text_encoding = timed_ms(lambda: encoder.encode_query(next(query_texts)), 100)
    print(
        f"local map: {POINTS_PER_OBJECT} points/object, {DIM}-d float16 embeddings, "
        f"torch threads {torch.get_num_threads()}; text encoding p50 {text_encoding['p50']:.1f} ms"
    )

    rows = grow_and_measure(sizes, encoder, query_texts, rng, args)
    gc.collect()

    accounting = traced_memory(5000)
    print(
        f"  accounting at {accounting['objects']} objects: tracemalloc sees "
        f"{accounting['ratio']:.3f}x memory_bytes"
    )
    points_storage = points_storage_error(rng)

    by_size = {row["objects"]: row for row in rows}
    targets = []
    if 10_000 in by_size:
        targets.append(
            check(
                "LQ p50 at 10k objects", by_size[10_000]["end_to_end_ms"]["p50"], "<=", 25.0, " ms"
            )
        )
    if 50_000 in by_size:
        at_50k = by_size[50_000]
        targets += [
            check("LQ p50 at 50k objects", at_50k["end_to_end_ms"]["p50"], "<=", 40.0, " ms"),
            check(
                "similarity p50 at 50k objects", at_50k["similarity_ms"]["p50"], "<=", 10.0, " ms"
            ),
            check(
                "memory at 50k objects", at_50k["memory_bytes"] / BYTES_PER_MB, "<=", 128.0, " MB"
            ),
        ]
    document = {
        "bench": "local_map",
        "machine": machine(),
        "config": {
            "dim": DIM,
            "points_per_object": POINTS_PER_OBJECT,
            "baseline_points_per_object": BASELINE_POINTS_PER_OBJECT,
            "delta_objects": DELTA_OBJECTS,
            "torch_threads": torch.get_num_threads(),
            "bytes_per_mb": BYTES_PER_MB,
        },
        "targets": targets,
        "text_encoding_ms": text_encoding,
        "sizes": rows,
        "memory_accounting": accounting,
        "points_storage": points_storage,
    }
    write_outputs(args.out, "local_map", document)
    plot(rows, args.out, BYTES_PER_MB)
    return 0 if all(target["ok"] for target in targets) else 1


def plot(rows: list[dict], out_dir: str, bytes_per_mb: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    objects = [row["objects"] for row in rows]
    fig, (memory_ax, latency_ax) = plt.subplots(1, 2, figsize=(11, 4))
    memory_ax.plot(
        objects, [r["memory_bytes"] / bytes_per_mb for r in rows], "o-", label="local map"
    )
    memory_ax.plot(
        objects, [r["baseline_bytes"] / bytes_per_mb for r in rows], "s--", color="tab:red",
        label="baseline full copy (computed)",
    )  # fmt: skip
    memory_ax.axhline(128, color="grey", lw=0.8, ls=":", label="target at 50k: 128 MB")
    memory_ax.set(xscale="log", yscale="log", xlabel="objects", ylabel="device memory (MB)")
    memory_ax.legend(fontsize=8)
    for key, colour, name in (("end_to_end_ms", "tab:blue", "LQ end to end"),
                              ("similarity_ms", "tab:green", "similarity only")):  # fmt: skip
        latency_ax.plot(
            objects, [r[key]["p50"] for r in rows], "o-", color=colour, label=f"{name} p50"
        )
        latency_ax.plot(
            objects, [r[key]["p99"] for r in rows], ":", color=colour, label=f"{name} p99"
        )
    latency_ax.plot([10_000, 50_000], [25, 40], "kx", label="p50 targets")
    latency_ax.set(xscale="log", xlabel="objects", ylabel="latency (ms)")
    latency_ax.legend(fontsize=8)
    fig.suptitle("SemanticXR device local map (2 CPU cores)")
    save_plot(fig, out_dir, "local_map")


if __name__ == "__main__":
    raise SystemExit(main())
