// How well a plain question's hits answer it, on the page: app/answering/relevance.py's rating,
// step for step, so an offline answer says `relevance` and `match` as the server does.
//
// A hit's label is scored by its best cosine over its texts (the label, its synonyms, what
// it is: the upserts carry them, the background's come with the answering data); the
// background labels likewise. In standard deviations of the question's scores over the
// background:
//   z      how far the label (over its texts) stands out,
//   gap    how far it trails the best background label not alike it (names at cosine >=
//          alike_cosine),
//   z_name how far the label's name alone stands out;
// relevance = clip(0.5 + (w_z z + w_gap gap + w_name z_name + bias) / (2 RAMP), 0, 1),
// rounded to 5 decimals; a match when some hit reaches CONFIDENT.
//
// The rule and the background come from `GET /v1/answering/{model_id}`; the page embeds the
// background's texts with the session's tower (or takes the tower's shipped embeddings when
// the server's rater uses them, so both read the same rows).

import { float16ToFloat32 } from "./updates.mjs";

export const RAMP = 2.0;
export const CONFIDENT = 0.5;
/** Longest model id asked for (the route refuses longer). */
export const MAX_MODEL_ID_CHARS = 128;

/** Python's round(x, 5): correctly rounded, an exact tie to even (toFixed takes it up). */
export function round5(x) {
  const scaled = x * 1e5;
  if (Number.isInteger(x * 64) && scaled % 1 === 0.5) {
    const down = Math.floor(scaled); // x is an exact tie (only multiples of 1/64 can be)
    return (down % 2 === 0 ? down : down + 1) / 1e5;
  }
  return Number(x.toFixed(5));
}

/** A label's relevance from its rule score (relevance_of). */
export function relevanceOf(score) {
  return round5(Math.min(Math.max(CONFIDENT + score / (2 * RAMP), 0), 1));
}

/** The float32 cosine of a[aOffset ...] and b, unit Float32Arrays of `dim`: summed in float64
 * by four accumulators (independent adds: about twice as fast as one chain), rounded once
 * (within float32 rounding of numpy's float32 product). */
export function dot(a, b, dim, aOffset = 0) {
  let s0 = 0;
  let s1 = 0;
  let s2 = 0;
  let s3 = 0;
  let i = 0;
  for (; i + 3 < dim; i += 4) {
    s0 += a[aOffset + i] * b[i];
    s1 += a[aOffset + i + 1] * b[i + 1];
    s2 += a[aOffset + i + 2] * b[i + 2];
    s3 += a[aOffset + i + 3] * b[i + 3];
  }
  for (; i < dim; i += 1) s0 += a[aOffset + i] * b[i];
  return Math.fround(s0 + s1 + (s2 + s3));
}

/** A label's texts: the label first, then its given texts (else the fallback's), each once
 * (texts_of). */
export function textsOf(label, given, fallback = null) {
  let texts = given ? given.get(label) : undefined;
  if (texts == null && fallback) texts = fallback.get(label);
  return [label, ...(texts || []).filter((t) => t !== label)];
}

function base64Bytes(text) {
  const binary = atob(text);
  const bytes = new Uint8Array(binary.length);
  for (let i = 0; i < binary.length; i += 1) bytes[i] = binary.charCodeAt(i);
  return bytes;
}

/**
 * Rates a plain question's hits as app.answering.relevance.QueryRater does, with `tower` (a
 * StaticTower: embed(text) -> Float32Array) and `data` (GET /v1/answering/{model_id}).
 */
export class QueryRater {
  constructor(tower, data) {
    const rule = data.rule;
    for (const key of ["w_z", "w_gap", "w_name", "bias", "alike_cosine"]) {
      if (typeof rule?.[key] !== "number") throw new TypeError(`answering data: rule.${key} must be a number`);
    }
    this.tower = tower;
    this.dim = tower.dim;
    this.rule = rule;
    this.alike = Math.fround(rule.alike_cosine); // numpy compares float32 cosines in float32
    this.vocabulary = data.background.map(([label]) => label);
    this.vocabularyTexts = new Map(data.background.map(([label, texts]) => [label, texts]));
    this.shipped = new Map();
    const shipped = data.background_embeddings;
    if (shipped && shipped.dim === this.dim) {
      const bytes = base64Bytes(shipped.rows);
      const rows = shipped.dtype === "float16" ? float16ToFloat32(bytes) : new Float32Array(bytes.buffer);
      shipped.texts.forEach((text, i) => this.shipped.set(text, rows.subarray(i * this.dim, (i + 1) * this.dim)));
    }
    this.cache = new Map(); // text -> embedding, the labels' texts met so far
    const texts = this.vocabulary.map((label) => textsOf(label, this.vocabularyTexts));
    const flat = texts.flat();
    this.textOwner = Int32Array.from(texts.flatMap((ts, v) => ts.map(() => v)));
    this.textEmbeddings = this.matrix(flat);
    this.nameEmbeddings = this.matrix(this.vocabulary);
  }

  /** The embedding of a text: the shipped row of a background text, else the tower's. */
  embed(text) {
    const shipped = this.shipped.get(text);
    if (shipped) return shipped;
    let embedding = this.cache.get(text);
    if (!embedding) {
      embedding = this.tower.embed(text);
      if (this.cache.size > 4096) this.cache.clear();
      this.cache.set(text, embedding);
    }
    return embedding;
  }

  matrix(texts) {
    const out = new Float32Array(texts.length * this.dim);
    texts.forEach((t, i) => out.set(this.embed(t), i * this.dim));
    return out;
  }

  /**
   * query: Float32Array [dim]; labels: the hits' labels, best first; labelTexts: Map label ->
   * texts as the upserts carried them (a label without: the background's, else itself).
   * {relevance: [per hit], match}.
   */
  rate(query, labels, labelTexts = new Map()) {
    const standings = this.standing(query, labels, labelTexts);
    if (standings === null) return { relevance: labels.map(() => 0), match: false };
    const { w_z, w_gap, w_name, bias } = this.rule;
    const relevance = standings.map(([z, gap, zName]) => relevanceOf(w_z * z + w_gap * gap + w_name * zName + bias));
    return { relevance, match: relevance.some((r) => r >= CONFIDENT) };
  }

  /** Per label [z, gap, z_name]; null for no labels or a question scoring the background alike. */
  standing(query, labels, labelTexts = new Map()) {
    if (labels.length === 0) return null;
    const dim = this.dim;
    const nLabels = this.vocabulary.length;
    const scores = new Float64Array(nLabels).fill(-Infinity);
    for (let t = 0; t < this.textOwner.length; t += 1) {
      const v = this.textOwner[t];
      const s = dot(this.textEmbeddings, query, dim, t * dim);
      if (s > scores[v]) scores[v] = s;
    }
    let mean = 0;
    for (const s of scores) mean += s;
    mean /= nLabels;
    let variance = 0;
    for (const s of scores) variance += (s - mean) ** 2;
    const spread = Math.sqrt(variance / nLabels);
    if (spread < 1e-6) return null;
    const byLabel = new Map();
    for (const label of new Set(labels)) {
      const name = this.embed(label);
      let best = -Infinity;
      let rivals = 0;
      for (let v = 0; v < nLabels; v += 1) {
        if (dot(this.nameEmbeddings, name, dim, v * dim) >= this.alike) continue; // alike: no rival
        rivals += 1;
        if (scores[v] > best) best = scores[v];
      }
      let score = -Infinity;
      for (const text of textsOf(label, labelTexts, this.vocabularyTexts)) {
        const s = dot(this.embed(text), query, dim);
        if (s > score) score = s;
      }
      if (rivals === 0) best = score;
      const nameScore = dot(name, query, dim);
      byLabel.set(label, [(score - mean) / spread, (best - score) / spread, (nameScore - mean) / spread]);
    }
    return labels.map((label) => byLabel.get(label));
  }
}
