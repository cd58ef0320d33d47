// Answering a question (wire protocol v1, docs/protocol.md "Query answers" and "Questions
// about how things stand"): the server's answer when it can be reached, else the honest
// best the page can do from its local copy of the map (updates.mjs), and the answer in
// words as the dashboard (static/app.js) and the viewer (viewer/scene.py, viewer/app.py)
// say it.
//
// Offline, a session with a static text tower answers plain questions as the server does
// (offline.mjs: the tower's ranking of the local map, rated by the match rule: same hits, same
// order, same `match`) and says that a question about how things stand needs the server
// (`needs_server`). A MiniLM session has no encoder on the page: its local answer is by label
// words only, the objects whose label shares a word with the question, best first, with no
// calibrated relevance (`relevance` is null) and no relations; `note` says which it is.

import { agoWords, CONFIDENT_DEGREE, CONFIDENT_RELEVANCE, relationWords } from "../common/words.mjs";
import { ApiError, request } from "./api.mjs";

export { CONFIDENT_DEGREE, CONFIDENT_RELEVANCE, relationWords };

export const ASK_TIMEOUT_MS = 4000; // longer than this, the server is taken as out of reach
const UNREACHABLE_STATUS = new Set([502, 503, 504]); // a gateway or shard that cannot answer now

/**
 * Ask the map. Resolves to an answer:
 *
 *   {text, match, source: "server" | "local", note: string | null, now_t?, latency_ms?,
 *    needs_server?: true (offline, a question about how things stand), ranked_by?,
 *    results: [{id, label, score, relevance, bbox [6], centroid [3],
 *               points: Float32Array (N*3, metres) | null, relation, place?, state?,
 *               last_seen_t?}]}
 *
 * best first. From the server (`source: "server"`, `note` null) each hit is as
 * `GET /v1/sessions/{sid}/query?points=true` answers it, points flattened, and `relation`
 * ({kind, anchors: [{id, label, bbox?, centroid?, points?}], degree} or null) with each
 * anchor's geometry filled in from the hits or the follower's objects where known (the
 * floor, id 0, has none). When the network is down or the server does not answer within
 * `timeoutMs` (or answers 502/503/504), the answer is `answerByLabelWords` of the follower's
 * objects (`source: "local"`), or, given `offline` (an OfflineAnswerer of the session's static
 * tower, offline.mjs), its answer. Any other refusal (403, 422) throws the ApiError.
 *
 * from: where the asker stands, [x, y, z] world metres (or {x, y, z}), for questions seen from
 * the asker ("the lamp closest to me"); sent as `from=x,y,z`, as the Python device sends it.
 * rerank: on a static-tower session, the server re-ranks and rates with the tower the static
 * one was distilled from (MiniLM; the answer's `ranked_by` says which); no effect on others,
 * nor on a local answer.
 */
export async function ask(text, { sid, follower = null, offline = null, k = 5, from = null, rerank = false, timeoutMs = ASK_TIMEOUT_MS } = {}) {
  const objects = follower ? follower.objects : new Map();
  const params = { text, k, points: "true" };
  if (from !== null) params.from = fromParam(from);
  if (rerank) params.rerank = "true";
  const signal = AbortSignal.timeout(timeoutMs);
  let body;
  try {
    body = await request("GET", `/v1/sessions/${encodeURIComponent(sid)}/query`, { sid, params, signal });
  } catch (err) {
    if (err instanceof ApiError && !UNREACHABLE_STATUS.has(err.status)) throw err;
    // network down, timed out, or no server behind
    return offline ? offline.answer(text, objects, k) : answerByLabelWords(text, objects, k);
  }
  return answerFromServer(body, objects);
}

export const ASK_ALOUD_TIMEOUT_MS = 30000; // an upload and its recognition take longer than a typed question

/**
 * Ask the map aloud: `audio`, a Blob typed as it was recorded ("audio/webm;codecs=opus"),
 * goes to `POST /v1/sessions/{sid}/query/speech`, which recognises it offline and answers
 * the text it heard as `ask` answers typed text (`k`, `from`, `rerank` as there). Resolves to that
 * answer (`source: "server"`) with what was heard: `transcript`, `confidence` (null when the
 * recogniser gives none), `asr_ms`, and `recognised: "server"`. There is no local answer:
 * the page cannot recognise speech by itself, so a refusal (415 type, 413 size, 400 empty or
 * undecodable, 422 too long or no speech, 503 busy with `retryAfterS`) throws the ApiError,
 * a network down a TypeError, and a server silent for `timeoutMs` a TimeoutError.
 */
export async function askAloud(audio, { sid, follower = null, k = 5, from = null, rerank = false, timeoutMs = ASK_ALOUD_TIMEOUT_MS } = {}) {
  const params = { k, points: "true" };
  if (from !== null) params.from = fromParam(from);
  if (rerank) params.rerank = "true";
  const path = `/v1/sessions/${encodeURIComponent(sid)}/query/speech`;
  const body = await request("POST", path, { sid, params, body: audio, signal: AbortSignal.timeout(timeoutMs) });
  return {
    ...answerFromServer(body, follower ? follower.objects : new Map()),
    transcript: body.transcript,
    confidence: body.confidence ?? null,
    asr_ms: body.asr_ms ?? null,
    recognised: "server",
  };
}

/** "x,y,z" of a position: each number's shortest round-trip text (Python's repr does the same). */
export function fromParam(from) {
  const xyz = Array.isArray(from) || ArrayBuffer.isView(from) ? Array.from(from) : [from?.x, from?.y, from?.z];
  if (xyz.length !== 3 || !xyz.every((v) => typeof v === "number" && Number.isFinite(v))) {
    throw new TypeError("from: give [x, y, z], three finite numbers (world metres)");
  }
  return xyz.map(String).join(",");
}

const flatPoints = (points) => (Array.isArray(points) ? Float32Array.from(points.flat()) : null);

/**
 * The server's query answer (parsed JSON) as `ask` resolves it: points flattened to
 * Float32Array, relation anchors with their geometry where the hits or `objects` (Map id ->
 * {bbox, centroid, points}) hold it.
 */
export function answerFromServer(body, objects = new Map()) {
  const results = body.results.map((hit) => ({ ...hit, points: flatPoints(hit.points), relation: hit.relation ?? null }));
  const known = new Map(results.map((hit) => [hit.id, hit]));
  for (const hit of results) {
    if (!hit.relation) continue;
    const anchors = hit.relation.anchors.map((anchor) => {
      const object = known.get(anchor.id) || objects.get(anchor.id);
      return object ? { ...anchor, bbox: object.bbox, centroid: object.centroid, points: object.points ?? null } : { ...anchor };
    });
    hit.relation = { ...hit.relation, anchors };
  }
  return {
    text: body.text,
    match: Boolean(body.match),
    results,
    source: "server",
    note: null,
    now_t: body.now_t ?? null,
    latency_ms: body.latency_ms ?? null,
    ranked_by: body.ranked_by ?? null,
  };
}

// --- the local answer: label words ----------------------------------------------------------

// Words that name no thing: they never make a label match ("the mug on the desk" shares
// "the" with no label worth finding).
const STOP_WORDS = new Set(
  ("a an the my your our his her their its this that these those some any of on in under " +
    "above below over near next to by at from with without between behind front left right " +
    "of and or is are was were be been where what which who whose how when show find me i you " +
    "it there here did do does leave left put keep kept closest farthest biggest smallest " +
    "highest lowest nearest top bottom side")
    .split(" "),
);

/** A word as labels are compared: lower case, a plural's "s"/"es" dropped ("mugs", "boxes"). */
function stem(word) {
  if (word.length > 4 && /(ches|shes|xes|sses)$/.test(word)) return word.slice(0, -2);
  if (word.length > 3 && word.endsWith("s") && !word.endsWith("ss")) return word.slice(0, -1);
  return word;
}

/** The words of a question or label that can name a thing, stemmed, in order. */
export function labelWords(text) {
  const words = String(text).toLowerCase().match(/[\p{L}\p{N}]+/gu) || [];
  return words.filter((w) => !STOP_WORDS.has(w)).map(stem);
}

/**
 * The local answer: the objects (Map id -> follower object) whose label shares a word with
 * the question, best first by how many words they share, then by how much of the label the
 * question names ("table" before "dining table" for "the table"), then by where in the
 * question the word comes (the thing asked about is named first: "the mug on the desk"),
 * then by id. `match` is true when any label shares a word; `relevance` is null (nothing
 * calibrates a label-word match), `score` the share of the label's words named.
 */
export function answerByLabelWords(text, objects, k = 5) {
  const asked = labelWords(text);
  const ranked = [];
  for (const object of objects.values()) {
    const words = [...new Set(labelWords(object.label))];
    const positions = words.map((w) => asked.indexOf(w)).filter((i) => i >= 0);
    if (positions.length === 0) continue;
    ranked.push({ object, shared: positions.length, share: positions.length / words.length, first: Math.min(...positions) });
  }
  ranked.sort((a, b) => b.shared - a.shared || b.share - a.share || a.first - b.first || a.object.id - b.object.id);
  const results = ranked.slice(0, k).map(({ object, share }) => ({
    id: object.id,
    label: object.label,
    score: share,
    relevance: null,
    bbox: object.bbox,
    centroid: object.centroid,
    points: object.points ?? null,
    relation: null,
  }));
  const n = objects.size;
  return {
    text,
    match: results.length > 0,
    results,
    source: "local",
    note: `offline: answered from the local copy by label words; ${n} object${n === 1 ? "" : "s"} held`,
    now_t: null,
    latency_ms: null,
  };
}

// --- in words (static/app.js and viewer/scene.py say the same) -------------------------------

/**
 * How strongly a hit answers, in [0, 1]: its relevance, times its relation's degree in a
 * relational answer (the mug on the shelf is no answer to "the mug on the desk"); null for a
 * local hit (no calibrated relevance).
 */
export function hitStrength(hit) {
  if (typeof hit.relevance !== "number") return null;
  const strength = hit.relevance * (hit.relation ? hit.relation.degree : 1);
  return Math.min(Math.max(strength, 0), 1);
}

// A hit's relation in words, "not ..." under CONFIDENT_DEGREE, with its degree: said of what
// was asked about (a confident hit, or the best hit of a matching answer); "" otherwise.
function relationSaid(hit, about) {
  const relation = hit.relation;
  if (!relation || !about || relation.anchors.some((a) => a.id === hit.id)) return "";
  const words = relationWords(relation.kind, relation.anchors.map((a) => String(a.label)));
  return `${relation.degree >= CONFIDENT_DEGREE ? "" : "not "}${words} (${relation.degree.toFixed(2)})`;
}

/**
 * A hit in words, as its label in the room shows it: "mug (0.93)" (its relevance), "mug — on
 * the desk (0.93)" (a relational hit: the relation's degree), "mug (by label)" (a local
 * hit). `best`: the best hit of a matching answer (its relation is said whatever its
 * relevance).
 */
export function hitWords(hit, { best = false } = {}) {
  if (typeof hit.relevance !== "number") return `${hit.label} (by label)`;
  const relation = relationSaid(hit, best || hit.relevance >= CONFIDENT_RELEVANCE);
  return relation ? `${hit.label} — ${relation}` : `${hit.label} (${hit.relevance.toFixed(2)})`;
}

// Where a hit is and since when, from the server's `place` and `last_seen_t`: "on the dining
// table, 10 min ago" (static/app.js answerWords); "" without them.
function whereWhen(hit, nowT) {
  const parts = [];
  const place = hit.place;
  if (place && typeof place.label === "string") parts.push(`${place.relation === "on" ? "on" : "near"} the ${place.label}`);
  if (typeof nowT === "number" && typeof hit.last_seen_t === "number") parts.push(agoWords(nowT - hit.last_seen_t));
  return parts.join(", ");
}


/**
 * The answer as one sentence for the page to show:
 *   "mug — on the desk (0.93)"                      a relational match
 *   "laptop (0.88) — on the dining table, 10 min ago" a plain match, where and when
 *   "mug (0.93) (offline)"                           a local match by the static tower
 *   "mug (by label, offline)"                        a local match by label words
 *   "“the mug on the desk” asks how things stand: that needs the server (...)"  offline
 *   "no match for “keys” — closest: mug (0.12)"      no confident match: said as such
 *   "no match for “keys” (offline: no label held shares a word)"
 */
export function answerWords(answer) {
  if (answer.needs_server) return `“${answer.text}” asks how things stand: that needs the server (offline, ask for a thing by name)`;
  if (answer.source === "local" && answer.ranked_by) return `${answerWords({ ...answer, source: "server" })} (offline)`;
  const best = answer.results[0];
  const local = answer.source === "local"; // by label words
  if (!answer.match || !best) {
    const said = `no match for “${answer.text}”`;
    if (local) return `${said} (offline: no label held shares a word)`;
    if (!best) return `${said} — the map holds nothing yet`;
    const relation = relationSaid(best, best.relevance >= CONFIDENT_RELEVANCE);
    const closest = relation ? `${best.label}, ${relation}` : `${best.label} (${best.relevance.toFixed(2)})`;
    return `${said} — closest: ${closest}`;
  }
  if (local) return `${best.label} (by label, offline)`;
  const words = hitWords(best, { best: true });
  if (best.relation) return words;
  const where = whereWhen(best, answer.now_t);
  return where ? `${words} — ${where}` : words;
}

/**
 * The hits to draw in the room, best first: none for `match: false` (the page says "no
 * match" instead of drawing a weak guess); for a match, the best hit and the other confident
 * ones (strength >= CONFIDENT_RELEVANCE: the other mugs on desks), or, by label words, the
 * others that share as many label words as the best. A relational answer's anchors are not hits.
 */
export function shownHits(answer) {
  if (!answer || !answer.match || answer.results.length === 0) return [];
  const [best, ...rest] = answer.results;
  const anchorIds = new Set((best.relation?.anchors || []).map((a) => a.id));
  const words = (hit) => labelWords(hit.label).filter((w) => labelWords(answer.text).includes(w)).length;
  const others = rest.filter((hit) => {
    if (anchorIds.has(hit.id)) return false;
    if (typeof best.relevance !== "number") return words(hit) === words(best); // by label words
    return hitStrength(hit) >= CONFIDENT_RELEVANCE;
  });
  return [best, ...others];
}
