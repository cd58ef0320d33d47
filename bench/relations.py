"""Relation index: update time per keyframe at 100, 500 and 2,000 objects.

    python -m bench.relations [--out out/] [--sizes 100,500,2000] [--keyframes 300]

A synthetic Z-up floor of 6 m rooms, 20 objects each, every object a few boxes with points
sampled on their faces (200 for furniture, 60 to 120 for small things, like the client cap):
a table with a mug, a book, a laptop and a plate on it, a bag and a box under it and a lamp
hanging over it, four chairs, a sofa with a bag on it and a side table beside it, a bookcase
with two books in it, a plant and a bin on the floor. Rooms are tiled until the floor holds
the size asked for.

A keyframe sees one room and changes 5 of its objects (each re-observed: its points jittered
by 5 mm and moved by up to 1 cm). Timed per keyframe:

- update: `RelationIndex.update` of those 5 upserts (bodies prepared, the pairs within reach
  of them marked stale; the index computes a stale pair when it is first read);
- settle: computing all those stale pairs at once (`settle`): what the update costs when
  every pair is recomputed at every keyframe, as if all were read before the next one;
- read: one question's worth of reads after a keyframe ("what is on the table": the
  table's relations), which settles only the pairs it touches.

The index is built and settled once first (both reported). The machine may be shared: p50
and p95 are both recorded.

Target (a benchmark, not a test): index update <= 1 ms p50 per keyframe at 500
objects; checked for the update and, as the stricter reading, for update + settle.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from app.relations.index import ObjectGeometry, RelationIndex
from bench.common import bench_parser, check, machine, write_outputs

ROOM_M = 6.0
CHANGED_PER_KEYFRAME = 5
Box = tuple[tuple[float, float, float], tuple[float, float, float]]


def box_points(parts: list[Box], count: int, rng: np.random.Generator) -> np.ndarray:
    """float32 [count, 3]: points on the faces of the boxes, spread by face area."""
    lo = np.array([p[0] for p in parts], np.float64)
    hi = np.array([p[1] for p in parts], np.float64)
    size = np.maximum(hi - lo, 1e-3)
    face_areas = np.stack(
        [size[:, 1] * size[:, 2], size[:, 0] * size[:, 2], size[:, 0] * size[:, 1]]
    )
    weights = np.repeat(face_areas.T, 2, axis=1).ravel()  # box, axis, side
    pick = rng.choice(len(weights), count, p=weights / weights.sum())
    box, axis, side = pick // 6, (pick % 6) // 2, pick % 2
    points = lo[box] + rng.uniform(0, 1, (count, 3)) * size[box]
    points[np.arange(count), axis] = np.where(side == 0, lo[box, axis], hi[box, axis])
    return points.astype(np.float32)


def table_parts(x: float, y: float, w: float, d: float, h: float) -> list[Box]:
    leg = 0.05
    parts: list[Box] = [((x, y, h - 0.04), (x + w, y + d, h))]
    for lx in (x, x + w - leg):
        for ly in (y, y + d - leg):
            parts.append(((lx, ly, 0.0), (lx + leg, ly + leg, h - 0.04)))
    return parts


def block(x: float, y: float, z: float, w: float, d: float, h: float) -> list[Box]:
    return [((x, y, z), (x + w, y + d, z + h))]


def room(ox: float, oy: float, rng: np.random.Generator) -> list[tuple[str, np.ndarray]]:
    """The 20 objects of one room with its corner at (ox, oy): (label, points)."""
    big, small = 200, 80
    things: list[tuple[str, list[Box], int]] = [
        ("table", table_parts(2.0, 2.0, 1.6, 0.9, 0.75), big),
        ("mug", block(2.3, 2.3, 0.75, 0.08, 0.08, 0.1), 60),
        ("book", block(2.6, 2.5, 0.75, 0.2, 0.25, 0.04), small),
        ("laptop", block(3.0, 2.2, 0.75, 0.33, 0.23, 0.02), small),
        ("plate", block(2.4, 2.6, 0.75, 0.22, 0.22, 0.02), small),
        ("bag", block(2.5, 2.4, 0.0, 0.35, 0.25, 0.4), 120),
        ("box", block(3.1, 2.5, 0.0, 0.3, 0.3, 0.3), small),
        ("lamp", block(2.7, 2.35, 1.7, 0.2, 0.2, 0.15), small),
        ("sofa", block(0.3, 4.6, 0.0, 2.0, 0.9, 0.45) + block(0.3, 5.3, 0.45, 2.0, 0.2, 0.4), big),
        ("bag", block(0.8, 4.8, 0.45, 0.3, 0.35, 0.3), 120),
        ("side table", table_parts(2.4, 4.8, 0.5, 0.5, 0.55), big),
        ("bookcase", _bookcase(4.8, 0.3), big),
        ("book", block(4.9, 0.35, 1.02, 0.04, 0.22, 0.28), small),
        ("book", block(5.1, 0.35, 1.02, 0.05, 0.22, 0.26), small),
        ("plant", block(0.3, 0.3, 0.0, 0.4, 0.4, 1.1), 120),
        ("bin", block(5.2, 5.2, 0.0, 0.3, 0.3, 0.45), small),
    ]
    for cx, cy in ((2.4, 1.5), (3.0, 1.5), (2.4, 3.05), (3.0, 3.05)):  # four chairs
        seat = block(cx, cy, 0.42, 0.42, 0.42, 0.04)
        back = block(cx, cy + (0.38 if cy > 2 else 0.0), 0.46, 0.42, 0.04, 0.45)
        legs = [
            ((cx + dx, cy + dy, 0.0), (cx + dx + 0.04, cy + dy + 0.04, 0.42))
            for dx in (0.0, 0.38)
            for dy in (0.0, 0.38)
        ]
        things.append(("chair", seat + back + legs, big))
    offset = np.array([ox, oy, 0.0], np.float32)
    return [(label, box_points(parts, n, rng) + offset) for label, parts, n in things]


def _bookcase(x: float, y: float) -> list[Box]:
    w, d, h, t = 0.8, 0.3, 2.0, 0.02
    parts: list[Box] = [
        ((x, y, 0.0), (x + t, y + d, h)),
        ((x + w - t, y, 0.0), (x + w, y + d, h)),
        ((x, y + d - t, 0.0), (x + w, y + d, h)),
    ]
    parts += [((x, y, z), (x + w, y + d, z + t)) for z in (0.0, 0.5, 1.0, 1.5, h - t)]
    return parts


def floor_of(objects: int, rng: np.random.Generator) -> list[tuple[str, np.ndarray]]:
    """At least `objects` objects in rooms tiled on a square grid, cut to `objects`."""
    rooms = -(-objects // 20)
    side = int(np.ceil(np.sqrt(rooms)))
    out: list[tuple[str, np.ndarray]] = []
    for r in range(rooms):
        out += room(ROOM_M * (r % side), ROOM_M * (r // side), rng)
    return out[:objects]


def measure(objects: int, keyframes: int, seed: int) -> dict:
    """Build an index of `objects`, then time `keyframes` updates of 5 objects of one room."""
    rng = np.random.default_rng(seed)
    world = floor_of(objects, rng)
    index = RelationIndex()
    start = time.perf_counter()
    index.update({i: ObjectGeometry(label, points) for i, (label, points) in enumerate(world)})
    build_ms = (time.perf_counter() - start) * 1e3
    start = time.perf_counter()
    pairs_within_reach = index.settle()
    build_settle_ms = (time.perf_counter() - start) * 1e3
    tables = [i for i, (label, _) in enumerate(world) if label == "table"]
    update_ms, settle_ms, total_ms, read_ms, stale = [], [], [], [], []
    for keyframe in range(keyframes):
        first = 20 * int(rng.integers(0, -(-objects // 20)))
        in_room = np.arange(first, min(first + 20, objects))
        chosen = rng.choice(in_room, min(CHANGED_PER_KEYFRAME, len(in_room)), replace=False)
        upserts = {}
        for i in chosen:
            label, points = world[i]
            moved = points + rng.uniform(-0.01, 0.01, 3).astype(np.float32)
            moved += rng.normal(0, 0.005, points.shape).astype(np.float32)
            upserts[int(i)] = ObjectGeometry(label, moved)
        start = time.perf_counter()
        index.update(upserts)
        middle = time.perf_counter()
        stale.append(index.settle())
        end = time.perf_counter()
        update_ms.append((middle - start) * 1e3)
        settle_ms.append((end - middle) * 1e3)
        total_ms.append((end - start) * 1e3)
        # a question after a keyframe that re-observed a table: only its pairs are settled
        table = tables[keyframe % len(tables)]
        label, points = world[table]
        seen = points + rng.normal(0, 0.005, points.shape).astype(np.float32)
        index.update({table: ObjectGeometry(label, seen)})
        start = time.perf_counter()
        index.relations_of(table)
        read_ms.append((time.perf_counter() - start) * 1e3)
        index.settle()
    return {
        "objects": objects,
        "pairs_within_reach": pairs_within_reach,
        "pairs_with_a_relation": len(index._degrees),
        "build_ms": build_ms,
        "build_settle_ms": build_settle_ms,
        "keyframes": keyframes,
        "changed_per_keyframe": CHANGED_PER_KEYFRAME,
        "stale_pairs_per_keyframe": float(np.mean(stale)),
        "update_ms": _summary(update_ms),
        "settle_ms": _summary(settle_ms),
        "update_and_settle_ms": _summary(total_ms),
        "read_table_relations_ms": _summary(read_ms),
    }


def _summary(times_ms: list[float]) -> dict:
    times = np.array(times_ms)
    return {
        "p50": float(np.percentile(times, 50)),
        "p95": float(np.percentile(times, 95)),
        "min": float(times.min()),
    }


def main(argv: list[str] | None = None) -> int:
    parser = bench_parser(__doc__)
    parser.add_argument("--out", default="out", help="folder for relations.json")
    parser.add_argument("--sizes", default="100,500,2000", help="object counts")
    parser.add_argument("--keyframes", type=int, default=300, help="timed updates per size")
    parser.add_argument("--seed", type=int, default=0)
    args: argparse.Namespace = parser.parse_args(argv)
    sizes = [int(s) for s in args.sizes.split(",")]
    rows = []
    print(
        f"{'objects':>8} {'pairs':>6} {'stale/kf':>8} {'build+settle ms':>16}"
        f" {'update p50/p95 ms':>18} {'settle p50/p95':>15} {'both p50/p95':>13}"
        f" {'read p50':>9}"
    )
    for objects in sizes:
        row = measure(objects, args.keyframes, args.seed)
        rows.append(row)
        cells = [
            f"{row[key]['p50']:.2f}/{row[key]['p95']:.2f}"
            for key in ("update_ms", "settle_ms", "update_and_settle_ms")
        ]
        print(
            f"{objects:>8} {row['pairs_within_reach']:>6} {row['stale_pairs_per_keyframe']:>8.1f}"
            f" {row['build_ms']:>7.0f}+{row['build_settle_ms']:<8.0f}"
            f" {cells[0]:>18} {cells[1]:>15} {cells[2]:>13}"
            f" {row['read_table_relations_ms']['p50']:>9.2f}"
        )
    checks = []
    for row in rows:
        if row["objects"] == 500:
            checks.append(
                check("update p50 at 500 objects", row["update_ms"]["p50"], "<=", 1.0, " ms")
            )
            checks.append(
                check(
                    "update + settle p50 at 500 objects",
                    row["update_and_settle_ms"]["p50"],
                    "<=",
                    1.0,
                    " ms",
                )
            )
    write_outputs(args.out, "relations", {"machine": machine(), "rows": rows, "checks": checks})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
