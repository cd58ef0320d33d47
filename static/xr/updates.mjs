// Following the map: the page's local copy of the server's confirmed map, kept by applying
// every delta of the updates socket in order (wire protocol v1, docs/protocol.md, "The
// updates socket: /v1/sessions/{sid}/updates?since=SEQ"). The Python device's local map
// (client_sim/local_map.py) and the viewer (viewer/scene.py) follow the same rules:
//   - a `full` snapshot replaces the map; otherwise `removed` ids go and `upserts` are
//     written, an upsert older than the held version being ignored;
//   - a non-full delta older than the last applied seq is out of order: nothing is applied
//     and the follower resynchronises (a new socket without `since`: a full snapshot);
//   - a dropped socket is opened again after a back-off with `since` = the last applied seq,
//     so the server sends exactly what was missed (or a full snapshot if that history is
//     gone): no update is lost, none applied twice.
// The pure parts (`float16ToFloat32`, `parseDelta`, `applyDelta`) need no socket.

import { decode } from "../vendor/msgpack-msgpack@3.1.3/dist.esm/index.mjs";
import { socketUrl } from "./api.mjs";

/** The keys of every `upserts[]` entry (app/protocol/delta.py UPSERT_KEYS; a test reads both). */
export const UPSERT_KEYS = Object.freeze(["id", "version", "label", "embedding", "points", "bbox", "n_obs"]);

/** First wait before opening a dropped socket again, then doubled up to RETRY_MAX_MS. */
export const RETRY_FIRST_MS = 500;
/** An upsert's optional `label_texts`: at most this many, each at most MAX_LABEL_CHARS long
 * (app/protocol/limits.py MAX_LABEL_TEXTS, MAX_LABEL_CHARS). */
export const MAX_LABEL_TEXTS = 16;
export const MAX_LABEL_CHARS = 200;
export const RETRY_MAX_MS = 8000;

/** A delta the follower cannot apply; `field` names what is wrong (as app/protocol's DeltaError). */
export class DeltaError extends Error {
  constructor(field, message) {
    super(`${field}: ${message}`);
    this.field = field;
  }
}

// --- float16 (IEEE 754 binary16), little-endian, as app/codecs.py writes it ------------------

let halfTable = null; // Float32Array(65536): every binary16 bit pattern's value, built once

function halfValue(bits) {
  const sign = bits & 0x8000 ? -1 : 1;
  const exponent = (bits >> 10) & 0x1f;
  const fraction = bits & 0x3ff;
  if (exponent === 0) return sign * fraction * 2 ** -24; // zero and subnormals
  if (exponent === 31) return fraction ? NaN : sign * Infinity;
  return sign * (1 + fraction / 1024) * 2 ** (exponent - 15);
}

/** float32 values of little-endian float16 bytes (a Uint8Array of even length): [n] for n*2 bytes. */
export function float16ToFloat32(bytes) {
  if (halfTable === null) {
    halfTable = new Float32Array(65536);
    for (let bits = 0; bits < 65536; bits += 1) halfTable[bits] = halfValue(bits);
  }
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const out = new Float32Array(bytes.byteLength >> 1);
  for (let i = 0; i < out.length; i += 1) out[i] = halfTable[view.getUint16(2 * i, true)];
  return out;
}

// --- parsing -------------------------------------------------------------------------------

const isCount = (v) => Number.isSafeInteger(v) && v >= 0; // ids, versions, seqs, n_obs
const isTime = (v) => typeof v === "number" && Number.isFinite(v);

function bytesOf(value, field, multipleOf) {
  if (!(value instanceof Uint8Array)) throw new DeltaError(field, "expected binary data");
  if (value.byteLength % multipleOf) {
    throw new DeltaError(field, `${value.byteLength} bytes is not a whole number of ${multipleOf}-byte items`);
  }
  return value;
}

function bboxOf(value, field) {
  if (!Array.isArray(value) || value.length !== 6 || !value.every(isTime)) {
    throw new DeltaError(field, "expected 6 finite numbers [x0, y0, z0, x1, y1, z1]");
  }
  if (value[0] > value[3] || value[1] > value[4] || value[2] > value[5]) {
    throw new DeltaError(field, "minimum corner exceeds maximum corner");
  }
  return value.slice();
}

/** Mean of N x 3 points (Float32Array), else the box centre, as client_sim/local_map.py holds it. */
export function centroidOf(points, bbox) {
  const n = points.length / 3;
  if (n === 0) return [(bbox[0] + bbox[3]) / 2, (bbox[1] + bbox[4]) / 2, (bbox[2] + bbox[5]) / 2];
  const sum = [0, 0, 0];
  for (let i = 0; i < points.length; i += 3) {
    sum[0] += points[i];
    sum[1] += points[i + 1];
    sum[2] += points[i + 2];
  }
  return sum.map((s) => s / n);
}

function objectOf(raw, field, dim) {
  if (!raw || typeof raw !== "object" || Array.isArray(raw)) throw new DeltaError(field, "expected a map");
  const missing = UPSERT_KEYS.filter((key) => !(key in raw));
  if (missing.length) throw new DeltaError(field, `missing ${missing.join(", ")}`);
  for (const key of ["id", "version", "n_obs"]) {
    if (!isCount(raw[key])) throw new DeltaError(`${field}.${key}`, "expected an integer >= 0");
  }
  if (typeof raw.label !== "string") throw new DeltaError(`${field}.label`, "expected a string");
  const bbox = bboxOf(raw.bbox, `${field}.bbox`);
  const embedding = float16ToFloat32(bytesOf(raw.embedding, `${field}.embedding`, 2));
  if (embedding.length === 0 || (dim !== null && embedding.length !== dim)) {
    throw new DeltaError(`${field}.embedding`, `${embedding.length} values, expected ${dim ?? "at least 1"}`);
  }
  const points = float16ToFloat32(bytesOf(raw.points, `${field}.points`, 6)); // N x 3 float16
  const object = {
    id: raw.id,
    version: raw.version,
    label: raw.label,
    bbox,
    centroid: centroidOf(points, bbox),
    points,
    embedding,
    n_obs: raw.n_obs,
  };
  if (raw.label_texts != null) {
    // The label's texts the server rates it by (its synonyms, what it is); none for a label
    // of the shipped background, whose texts every end holds, and from an older server.
    const texts = raw.label_texts;
    const fits = (t) => typeof t === "string" && (t.length <= MAX_LABEL_CHARS || [...t].length <= MAX_LABEL_CHARS); // code points, as Python counts
    if (!Array.isArray(texts) || texts.length > MAX_LABEL_TEXTS || !texts.every(fits)) {
      throw new DeltaError(`${field}.label_texts`, `expected at most ${MAX_LABEL_TEXTS} strings of at most ${MAX_LABEL_CHARS} characters`);
    }
    object.label_texts = texts.slice();
  }
  for (const key of ["first_seen_t", "last_seen_t"]) {
    if (raw[key] == null) continue; // an older server sends none
    if (!isTime(raw[key])) throw new DeltaError(`${field}.${key}`, "expected a finite number");
    object[key] = raw[key];
  }
  return object;
}

/**
 * A decoded `delta` message (msgpack map, binary fields as Uint8Array) as
 * {seq, full, upserts: [object], removed: [id], changes: [...]}, each object as the follower
 * holds it: {id, version, label, bbox [6], centroid [3], points Float32Array (N*3, metres),
 * embedding Float32Array (dim), n_obs, first_seen_t?, last_seen_t?, label_texts?}. DeltaError naming the
 * first wrong field; no side effects. dim: the embedding dimension held so far, or null.
 */
export function parseDelta(message, dim = null) {
  if (!message || typeof message !== "object" || Array.isArray(message)) {
    throw new DeltaError("message", "expected a map");
  }
  if (message.type !== "delta") throw new DeltaError("type", `expected 'delta', got ${JSON.stringify(message.type)}`);
  if (!isCount(message.seq)) throw new DeltaError("seq", "expected an integer >= 0");
  if (typeof message.full !== "boolean") throw new DeltaError("full", "expected a boolean");
  if (!Array.isArray(message.upserts)) throw new DeltaError("upserts", "expected a list");
  if (!Array.isArray(message.removed) || !message.removed.every(isCount)) {
    throw new DeltaError("removed", "expected a list of ids");
  }
  const upserts = [];
  for (const [i, raw] of message.upserts.entries()) {
    const object = objectOf(raw, `upserts[${i}]`, dim);
    dim = object.embedding.length; // one dimension for every object of a session
    upserts.push(object);
  }
  const ids = new Set(upserts.map((o) => o.id));
  if (ids.size !== upserts.length) throw new DeltaError("upserts", "an id appears more than once");
  if (message.removed.some((id) => ids.has(id))) throw new DeltaError("removed", "an id is also upserted");
  const changes = Array.isArray(message.changes) ? message.changes : [];
  return { seq: message.seq, full: message.full, upserts, removed: message.removed.slice(), changes };
}

/**
 * Apply a parsed delta to `objects` (Map id -> object) in place, after `lastSeq` (null: none
 * applied yet). Returns what changed, {seq, full, added, updated, removed, unchanged: [id],
 * changes}; a non-full delta older than lastSeq throws DeltaError and changes nothing.
 */
export function applyDelta(objects, delta, lastSeq) {
  if (!delta.full && lastSeq !== null && delta.seq < lastSeq) {
    throw new DeltaError("seq", `${delta.seq} is older than the applied seq ${lastSeq} (out of order)`);
  }
  const summary = { seq: delta.seq, full: delta.full, added: [], updated: [], removed: [], unchanged: [], changes: delta.changes };
  if (delta.full) {
    const kept = new Set(delta.upserts.map((o) => o.id));
    for (const id of objects.keys()) if (!kept.has(id)) summary.removed.push(id);
    for (const id of summary.removed) objects.delete(id);
  } else {
    for (const id of delta.removed) if (objects.delete(id)) summary.removed.push(id);
  }
  for (const object of delta.upserts) {
    const held = objects.get(object.id);
    if (held && !delta.full && object.version < held.version) {
      summary.unchanged.push(object.id); // stale: the newer version is held
      continue;
    }
    objects.set(object.id, object);
    (held ? summary.updated : summary.added).push(object.id);
  }
  return summary;
}

// --- the socket ----------------------------------------------------------------------------

/**
 * Follows one session's updates socket and keeps `objects` (Map id -> object, see
 * `parseDelta`) equal to the server's confirmed map at client resolution.
 *
 *   const follower = new MapFollower({sid, onChange, onState});
 *   follower.start();   // opens the socket; reopens it after drops until stop()
 *   follower.stop();
 *
 * onChange(summary): after every applied delta (`applyDelta`'s summary; `summary.changed`
 * tells whether any object was added, updated or removed). onState({state, connected,
 * lastSeq, attempt, retryInMs?, reason?}) on every connection state change; state is
 * "connecting", "open" (the socket is open), "waiting" (dropped, reopening in retryInMs) or
 * "stopped". `lastSeq` is the seq of the last applied delta (null before the first).
 */
export class MapFollower {
  constructor({ sid, onChange = null, onState = null, retryFirstMs = RETRY_FIRST_MS, retryMaxMs = RETRY_MAX_MS } = {}) {
    if (!sid) throw new TypeError("MapFollower needs a session id");
    this.sid = sid;
    this.onChange = onChange;
    this.onState = onState;
    this.retryFirstMs = retryFirstMs;
    this.retryMaxMs = retryMaxMs;
    this.objects = new Map();
    this.lastSeq = null;
    this.state = "stopped";
    this.attempt = 0; // failed or dropped sockets in a row
    this.socket = null;
    this.timer = null;
    this.running = false;
    this.resync = false; // the next socket asks for a full snapshot (after a bad delta)
    this.onOnline = () => {
      if (this.state === "waiting") this.connectNow(); // the network is back: no need to wait
    };
  }

  get connected() {
    return this.state === "open";
  }

  /** The embedding dimension of the held objects (null while none is held). */
  get dim() {
    for (const object of this.objects.values()) return object.embedding.length;
    return null;
  }

  start() {
    if (this.running) return;
    this.running = true;
    globalThis.addEventListener?.("online", this.onOnline);
    this.connectNow();
  }

  stop() {
    this.running = false;
    globalThis.removeEventListener?.("online", this.onOnline);
    clearTimeout(this.timer);
    this.timer = null;
    const socket = this.socket;
    this.socket = null;
    if (socket) socket.close(1000, "stopped");
    this.setState("stopped");
  }

  setState(state, extra = {}) {
    this.state = state;
    this.onState?.({ state, connected: state === "open", lastSeq: this.lastSeq, attempt: this.attempt, ...extra });
  }

  connectNow() {
    clearTimeout(this.timer);
    this.timer = null;
    if (!this.running) return;
    const since = this.resync || this.lastSeq === null ? null : { since: this.lastSeq };
    this.resync = false;
    const path = `/v1/sessions/${encodeURIComponent(this.sid)}/updates`;
    const socket = new WebSocket(socketUrl(path, { sid: this.sid, params: since }));
    socket.binaryType = "arraybuffer";
    this.socket = socket;
    this.setState("connecting");
    // Events of a socket this follower has let go of are ignored: one socket feeds the map.
    socket.onopen = () => {
      if (socket === this.socket) this.setState("open");
    };
    socket.onmessage = (event) => {
      if (socket === this.socket) this.receive(event.data);
    };
    socket.onclose = (event) => {
      if (socket !== this.socket) return;
      this.socket = null;
      this.retry(event.reason || `closed (${event.code})`);
    };
  }

  receive(data) {
    let summary;
    try {
      if (!(data instanceof ArrayBuffer)) throw new DeltaError("message", "a text message; updates are binary msgpack");
      const delta = parseDelta(decode(new Uint8Array(data)), this.dim);
      summary = applyDelta(this.objects, delta, this.lastSeq);
    } catch (err) {
      // Nothing was applied: start again from a full snapshot at once.
      console.warn(`updates: ${err.message}; asking for a full snapshot`);
      this.resync = true;
      const socket = this.socket;
      this.socket = null;
      socket.close(4000, "resync");
      this.connectNow();
      return;
    }
    this.lastSeq = summary.seq;
    this.attempt = 0; // a delta arrived: the connection works
    summary.changed = summary.added.length + summary.updated.length + summary.removed.length > 0;
    this.onChange?.(summary);
  }

  retry(reason) {
    if (!this.running) return;
    // Doubling back-off with jitter, so many pages dropped at once do not return at once.
    const base = Math.min(this.retryMaxMs, this.retryFirstMs * 2 ** this.attempt);
    const retryInMs = Math.round(base * (0.75 + 0.5 * Math.random()));
    this.attempt += 1;
    this.setState("waiting", { retryInMs, reason });
    this.timer = setTimeout(() => this.connectNow(), retryInMs);
  }
}
