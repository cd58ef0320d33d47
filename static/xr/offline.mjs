// The page's own answer to a plain question, for when the server is out of reach: with a
// session whose text tower is static (record.embedding.model "static-<sha16>"), the question
// is embedded by the tower (tower.mjs) exactly as the server embeds it, ranked against the
// local map's embeddings (float16 on the wire, as the updates carry them), and rated by the
// match rule (relevance.mjs): the same hits in the same order and the same `match` as the
// server's plain answer (LQ = SQ), scores within the wire's float16 rounding.
//
// A question about how things stand ("the mug on the desk", "the biggest lamp") needs the
// server's question reader and relations; the page does not guess a plain answer to it. The
// test is sound without the reader: the reader finds a relation only at one of its relation
// phrases (one that takes an anchor only with a word after it) and a superlative only at one
// of its superlative words (the server lists them in the answering data), so a question
// holding none of them so, word for word, reads as plain there too. One that holds one (even
// as an idiom, "where I wash the dishes by hand") is left to the server: the page says so.

import { request } from "./api.mjs";
import { dot, QueryRater } from "./relevance.mjs";
import { isStaticModelId, loadTower } from "./tower.mjs";

/** The words of a question as the relational test reads them: lower case, runs of letters and
 * digits (finer than the reader's words: "left-hand" is "left", "hand"), "n't" spelt "not". */
export function questionWords(text) {
  const lowered = String(text).toLowerCase().replace(/[\u2019\u2018`]/g, "'").replace(/n't/g, " not ");
  return lowered.match(/[\p{L}\p{N}]+/gu) || [];
}

/** The test of `mayBeRelational` from the answering data's `relational` phrases: a
 * superlative word anywhere, a phrase about the asker anywhere, or a phrase taking an anchor
 * with a word after it. */
export function relationalTest({ anchored, from_asker: fromAsker, superlatives }) {
  const byFirst = new Map();
  for (const [phrases, needsAnchor] of [[anchored, true], [fromAsker, false]]) {
    for (const phrase of phrases) {
      const words = questionWords(phrase);
      if (!byFirst.has(words[0])) byFirst.set(words[0], []);
      byFirst.get(words[0]).push({ words, needsAnchor });
    }
  }
  const extremes = new Set(superlatives);
  return (text) => {
    const words = questionWords(text);
    return words.some(
      (word, i) =>
        extremes.has(word) ||
        (byFirst.get(word) || []).some(
          ({ words: phrase, needsAnchor }) => phrase.every((w, j) => words[i + j] === w) && (!needsAnchor || i + phrase.length < words.length),
        ),
    );
  };
}

/** The answering data of a text tower (GET /v1/answering/{model_id}). */
export function fetchAnsweringData(modelId, { signal } = {}) {
  return request("GET", `/v1/answering/${encodeURIComponent(modelId)}`, { signal });
}

/**
 * Answers plain questions from the local map with the session's static tower.
 *
 *   const offline = await OfflineAnswerer.forRecord(record);  // null: not a static session
 *   offline.answer(text, follower.objects, k)
 */
export class OfflineAnswerer {
  constructor(tower, data) {
    if (data.model !== tower.modelId) throw new Error(`answering data of ${data.model}, not of the tower ${tower.modelId}`);
    this.tower = tower;
    this.modelId = tower.modelId;
    this.rater = new QueryRater(tower, data);
    this.mayBeRelational = relationalTest(data.relational);
  }

  /** The answerer of a session record with a static tower (the tower fetched by hash and
   * checked, the answering data fetched); null for another tower (MiniLM: no local encoder). */
  static async forRecord(record, { signal } = {}) {
    const embedding = record?.embedding;
    if (!embedding || !isStaticModelId(embedding.model)) return null;
    const [tower, data] = await Promise.all([loadTower(embedding, { signal }), fetchAnsweringData(embedding.model, { signal })]);
    return new OfflineAnswerer(tower, data);
  }

  /** The top-k objects (Map id -> follower object) by cosine to the question's embedding,
   * best first, ties by id (as the server's stable sort of its id-ordered objects). */
  rank(query, objects, k) {
    const dim = query.length;
    const top = []; // [{object, score}], best first, at most k
    if (k <= 0) return top;
    for (const object of objects.values()) {
      const e = object.embedding;
      if (e.length !== dim) continue;
      const score = dot(e, query, dim);
      if (top.length === k) {
        const last = top[k - 1];
        if (score < last.score || (score === last.score && object.id > last.object.id)) continue;
        top.pop();
      }
      let at = top.length;
      while (at > 0 && (top[at - 1].score < score || (top[at - 1].score === score && top[at - 1].object.id > object.id))) at -= 1;
      top.splice(at, 0, { object, score });
    }
    return top;
  }

  /** The local answer to `text` (answers.mjs `ask` shape, `source: "local"`). */
  answer(text, objects, k = 5) {
    const started = performance.now();
    const n = objects.size;
    const held = `${n} object${n === 1 ? "" : "s"} held`;
    if (this.mayBeRelational(text)) {
      return {
        text,
        match: false,
        results: [],
        source: "local",
        needs_server: true,
        note: `offline: a question about how things stand needs the server; ${held}`,
        now_t: null,
        latency_ms: performance.now() - started,
      };
    }
    const query = this.tower.embed(text);
    const ranked = this.rank(query, objects, k);
    const labels = ranked.map(({ object }) => object.label);
    const labelTexts = new Map();
    for (const { object } of ranked) if (object.label_texts) labelTexts.set(object.label, object.label_texts);
    const rating = this.rater.rate(query, labels, labelTexts);
    const results = ranked.map(({ object, score }, i) => ({
      id: object.id,
      label: object.label,
      score,
      relevance: rating.relevance[i],
      bbox: object.bbox,
      centroid: object.centroid,
      points: object.points ?? null,
      relation: null,
      last_seen_t: object.last_seen_t ?? null,
    }));
    return {
      text,
      match: rating.match,
      results,
      source: "local",
      ranked_by: this.modelId,
      note: `offline: answered from the local copy with the session's static text tower; ${held}`,
      now_t: null,
      latency_ms: performance.now() - started,
    };
  }
}
