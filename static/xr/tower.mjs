// The session's static text tower on the page (app/semantics/static.py is the other end): one
// int8 row per WordPiece token, a question the sum of its tokens' rows. The page encodes a
// question as the server and the Python device do, to the same float32 bits, so its offline
// answer ranks and rates as theirs:
//   1. BERT's basic tokenisation (HF BertNormalizer with lowercasing + BertPreTokenizer):
//      NUL, U+FFFD and control characters (category C*, but \t \n \r) dropped, whitespace
//      (White_Space) made spaces, CJK ideographs padded with spaces, NFD and marks (Mn)
//      dropped, each character lowercased by itself (no context: a final sigma stays σ, as
//      HF's Rust lowercases), split on spaces and around every punctuation character (ASCII
//      !-/ :-@ [-` {-~ and category P*);
//   2. WordPiece per word over code points: greedy longest match first, later pieces with the
//      "##" prefix; a word longer than max_word_chars, or with a piece not in the vocabulary,
//      is unknown;
//   3. unknown words dropped, at most MAX_TOKENS ids kept (the first);
//   4. the ids' int8 rows summed as integers (exact);
//   5. each sum divided by the sum's norm in float64, rounded to float32 (Math.fround): the
//      squares' sum is an exact integer (< 2^53), IEEE division and sqrt are exact to the bit.
//
// The tower file (msgpack, GET /v1/text-towers/{sha256}) is fetched once and checked against
// its sha256; the browser's HTTP cache keeps it (the server sends it immutable, by hash).

import { decode } from "../vendor/msgpack-msgpack@3.1.3/dist.esm/index.mjs";

export const TOWER_FORMAT = "semanticxr-static-tower";
export const TOWER_VERSION = 1;
export const STATIC_PREFIX = "static-";
/** Ids kept of a text (the first), as app/semantics/static.py MAX_TOKENS. */
export const MAX_TOKENS = 512;
/** Largest tower file read (a 256-d table of 30k tokens is ~7.6 MB). */
export const MAX_TOWER_BYTES = 64 * 1024 * 1024;
const MAX_VOCAB = 1_000_000;
const MAX_DIM = 4096;
const SHA256_HEX = /^[0-9a-f]{64}$/;

/** A tower file that cannot be used; the message names what is wrong. */
export class TowerError extends Error {
  constructor(message) {
    super(message);
    this.name = "TowerError";
  }
}

// --- step 1: BERT basic tokenisation -------------------------------------------------------

const CONTROL = /^\p{C}$/u;
const WHITE_SPACE = /^\p{White_Space}$/u;
const MARK_NONSPACING = /^\p{Mn}$/u;
const PUNCTUATION = /^\p{P}$/u;
const ASCII_ONLY = /^[\x00-\x7f]*$/;

const isAsciiPunctuation = (cp) => (cp >= 33 && cp <= 47) || (cp >= 58 && cp <= 64) || (cp >= 91 && cp <= 96) || (cp >= 123 && cp <= 126);

function isCjk(cp) {
  return (
    (cp >= 0x4e00 && cp <= 0x9fff) ||
    (cp >= 0x3400 && cp <= 0x4dbf) ||
    (cp >= 0x20000 && cp <= 0x2a6df) ||
    (cp >= 0x2a700 && cp <= 0x2b73f) ||
    (cp >= 0x2b740 && cp <= 0x2b81f) ||
    (cp >= 0x2b820 && cp <= 0x2ceaf) ||
    (cp >= 0xf900 && cp <= 0xfaff) ||
    (cp >= 0x2f800 && cp <= 0x2fa1f)
  );
}

const isPunctuation = (ch, cp) => isAsciiPunctuation(cp) || (cp > 127 && PUNCTUATION.test(ch));

// Split space-separated chunks into words, each punctuation character a word of its own.
function splitWords(stripped) {
  const words = [];
  for (const chunk of stripped.split(" ")) {
    let word = "";
    for (const ch of chunk) {
      if (isPunctuation(ch, ch.codePointAt(0))) {
        if (word) words.push(word);
        words.push(ch);
        word = "";
      } else {
        word += ch;
      }
    }
    if (word) words.push(word);
  }
  return words;
}

// ASCII text needs no Unicode tables: controls dropped, \t \n \r made spaces, A-Z lowered.
function asciiWords(text) {
  let cleaned = "";
  for (let i = 0; i < text.length; i += 1) {
    const cp = text.charCodeAt(i);
    if (cp === 9 || cp === 10 || cp === 13) cleaned += " ";
    else if (cp < 32 || cp === 127) continue;
    else cleaned += cp >= 65 && cp <= 90 ? String.fromCharCode(cp + 32) : text[i];
  }
  return splitWords(cleaned);
}

/** Step 1: the words (and punctuation marks, each its own word) of `text`. */
export function basicWords(text) {
  text = String(text);
  if (ASCII_ONLY.test(text)) return asciiWords(text);
  let cleaned = "";
  for (const ch of text) {
    const cp = ch.codePointAt(0);
    if (cp === 0 || cp === 0xfffd) continue;
    if (cp === 9 || cp === 10 || cp === 13) {
      cleaned += " ";
      continue;
    }
    if (CONTROL.test(ch)) continue; // lone surrogates (Cs) too
    if (WHITE_SPACE.test(ch)) cleaned += " ";
    else if (isCjk(cp)) cleaned += ` ${ch} `;
    else cleaned += ch;
  }
  let stripped = "";
  for (const ch of cleaned.normalize("NFD")) {
    if (!MARK_NONSPACING.test(ch)) stripped += ch.toLowerCase(); // one character at a time
  }
  return splitWords(stripped);
}

// --- the tower -------------------------------------------------------------------------------

/** sha256 of bytes, lower-case hex (crypto.subtle: a secure page, https or localhost). */
export async function sha256Hex(bytes) {
  if (!globalThis.crypto?.subtle) throw new TowerError("checking the tower needs a secure page (https or localhost): crypto.subtle is missing");
  const digest = new Uint8Array(await crypto.subtle.digest("SHA-256", bytes));
  return Array.from(digest, (b) => b.toString(16).padStart(2, "0")).join("");
}

/** `embedding.model` of the tower whose file has this sha256. */
export const staticModelId = (sha256) => STATIC_PREFIX + sha256.slice(0, 16);
export const isStaticModelId = (modelId) => typeof modelId === "string" && modelId.startsWith(STATIC_PREFIX);

export class StaticTower {
  /** From the tower file's decoded fields (`parseTower` checks them). */
  constructor({ teacher, dim, vocab, unk, prefix, maxWordChars, rows, sha256 = null }) {
    this.teacher = teacher;
    this.dim = dim;
    this.vocab = vocab;
    this.unk = unk;
    this.prefix = prefix;
    this.maxWordChars = maxWordChars;
    this.rows = rows; // Int8Array [vocab.length * dim]
    this.sha256 = sha256;
    this.modelId = sha256 ? staticModelId(sha256) : null;
    this.index = new Map();
    for (let i = 0; i < vocab.length; i += 1) this.index.set(vocab[i], i);
    if (this.index.size !== vocab.length) throw new TowerError("vocab: a token is listed twice");
    this.unkId = this.index.has(unk) ? this.index.get(unk) : null;
  }

  /** Step 2: the ids of one word, or null when it is unknown. */
  wordIds(word) {
    const chars = Array.from(word);
    if (chars.length > this.maxWordChars) return null;
    const ids = [];
    let start = 0;
    while (start < chars.length) {
      let end = chars.length;
      let found;
      for (; end > start; end -= 1) {
        const piece = chars.slice(start, end).join("");
        found = this.index.get(start === 0 ? piece : this.prefix + piece);
        if (found !== undefined) break;
      }
      if (end === start) return null;
      ids.push(found);
      start = end;
    }
    return ids;
  }

  /** Steps 1-3: the ids of `text`, unknown words dropped, at most MAX_TOKENS. */
  tokenIds(text) {
    const ids = [];
    for (const word of basicWords(text)) {
      const pieces = this.wordIds(word);
      if (pieces !== null) for (const id of pieces) if (id !== this.unkId) ids.push(id);
      if (ids.length >= MAX_TOKENS) break;
    }
    return ids.slice(0, MAX_TOKENS);
  }

  /** Steps 4-5: Float32Array [dim], unit, or all zero when the ids sum to nothing. */
  embedIds(ids) {
    const dim = this.dim;
    const out = new Float32Array(dim);
    if (ids.length === 0) return out;
    const sum = new Int32Array(dim);
    for (const id of ids) {
      const row = this.rows.subarray(id * dim, (id + 1) * dim);
      for (let i = 0; i < dim; i += 1) sum[i] += row[i];
    }
    let squares = 0; // exact: < 512^2 * 127^2 * 4096 < 2^53
    for (let i = 0; i < dim; i += 1) squares += sum[i] * sum[i];
    if (squares === 0) return out;
    const norm = Math.sqrt(squares);
    for (let i = 0; i < dim; i += 1) out[i] = Math.fround(sum[i] / norm);
    return out;
  }

  /** The text's embedding, Float32Array [dim]: the same bits as StaticTower.embed in Python. */
  embed(text) {
    return this.embedIds(this.tokenIds(text));
  }
}

const isInt = (v) => Number.isSafeInteger(v);

/** A tower file's bytes (Uint8Array) as a StaticTower; TowerError naming the bad field.
 * sha256: the hash the file was fetched by, kept as the tower's name (checked by loadTower). */
export function parseTower(bytes, sha256 = null) {
  if (bytes.byteLength > MAX_TOWER_BYTES) throw new TowerError(`tower file: ${bytes.byteLength} bytes, more than ${MAX_TOWER_BYTES}`);
  let record;
  try {
    record = decode(bytes);
  } catch (err) {
    throw new TowerError(`tower file: not msgpack (${err.message})`);
  }
  if (!record || typeof record !== "object" || record.format !== TOWER_FORMAT) throw new TowerError(`format: not a ${TOWER_FORMAT} file`);
  if (record.version !== TOWER_VERSION) throw new TowerError(`version: ${JSON.stringify(record.version)}, this page reads ${TOWER_VERSION}`);
  const { vocab, dim, rows, teacher, unk, prefix } = record;
  if (!Array.isArray(vocab) || !vocab.every((t) => typeof t === "string")) throw new TowerError("vocab: must be a list of strings");
  if (vocab.length < 1 || vocab.length > MAX_VOCAB) throw new TowerError(`vocab: ${vocab.length} tokens, must be 1..${MAX_VOCAB}`);
  if (!isInt(dim) || dim < 1 || dim > MAX_DIM) throw new TowerError(`dim: must be an integer 1..${MAX_DIM}, got ${JSON.stringify(dim)}`);
  if (!(rows instanceof Uint8Array) || rows.byteLength !== vocab.length * dim) throw new TowerError(`rows: must be ${vocab.length} x ${dim} int8 bytes`);
  if (typeof teacher !== "string") throw new TowerError("teacher: must be a string");
  if (typeof unk !== "string" || typeof prefix !== "string") throw new TowerError("unk, prefix: must be strings");
  const maxWordChars = record.max_word_chars;
  if (!isInt(maxWordChars) || maxWordChars < 1) throw new TowerError(`max_word_chars: must be a positive integer, got ${JSON.stringify(maxWordChars)}`);
  const table = new Int8Array(rows.buffer, rows.byteOffset, rows.byteLength);
  return new StaticTower({ teacher, dim, vocab, unk, prefix, maxWordChars, rows: table, sha256 });
}

/**
 * The tower of a session's record (`record.embedding`: {model: "static-<sha16>", dim, sha256}):
 * `GET /v1/text-towers/{sha256}` (the browser's HTTP cache answers a second time), its bytes
 * checked against the hash and the model id, parsed. TowerError naming what is wrong;
 * `fetchBytes(url, signal)` may stand in for the network (tests).
 */
export async function loadTower(embedding, { signal, fetchBytes = fetchTowerBytes } = {}) {
  const sha256 = embedding?.sha256;
  if (typeof sha256 !== "string" || !SHA256_HEX.test(sha256)) throw new TowerError(`embedding.sha256: expected 64 lower-case hex digits, got ${JSON.stringify(sha256)}`);
  if (embedding.model !== staticModelId(sha256)) throw new TowerError(`embedding.model: ${JSON.stringify(embedding.model)} does not name the tower ${sha256}`);
  const bytes = await fetchBytes(`/v1/text-towers/${sha256}`, signal);
  const got = await sha256Hex(bytes);
  if (got !== sha256) throw new TowerError(`tower file: its sha256 is ${got}, not ${sha256} (a corrupted or wrong download)`);
  const tower = parseTower(bytes, sha256);
  if (embedding.dim != null && embedding.dim !== tower.dim) throw new TowerError(`dim: the tower's is ${tower.dim}, the session's ${embedding.dim}`);
  return tower;
}

async function fetchTowerBytes(path, signal) {
  const response = await fetch(new URL(path, location.origin), { signal }); // no credential: content-addressed, public
  if (!response.ok) {
    let detail = `${response.status} ${response.statusText}`;
    try {
      detail = (await response.json()).detail || detail;
    } catch {
      // not JSON: the status says it
    }
    throw new TowerError(`GET ${path}: ${detail}`);
  }
  const declared = Number(response.headers.get("Content-Length"));
  if (declared > MAX_TOWER_BYTES) throw new TowerError(`tower file: ${declared} bytes, more than ${MAX_TOWER_BYTES}`);
  const bytes = new Uint8Array(await response.arrayBuffer());
  if (bytes.byteLength > MAX_TOWER_BYTES) throw new TowerError(`tower file: ${bytes.byteLength} bytes, more than ${MAX_TOWER_BYTES}`);
  return bytes;
}
