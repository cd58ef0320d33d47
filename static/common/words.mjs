// How the pages say an answer, shared by the dashboard (static/app.js) and the real-device
// page (static/xr/answers.mjs); viewer/scene.py says the same in Python.

export const CONFIDENT_RELEVANCE = 0.5; // app.answering.relevance.CONFIDENT: a confident match from here
export const CONFIDENT_DEGREE = 0.5; // a hit stands in its relation from here (viewer/app.py says the same)

const RELATION_PHRASES = {
  next_to: "next to",
  left_of: "left of",
  right_of: "right of",
  in_front_of: "in front of",
  closest: "closest to",
  farthest: "farthest from",
};
const TO_THE_ASKER = {
  // measured from the asker: "the lamp closest to me"
  near: "near you",
  next_to: "next to you",
  left_of: "on your left",
  right_of: "on your right",
  in_front_of: "in front of you",
  behind: "behind you",
  closest: "closest to you",
  farthest: "farthest from you",
};
const SUPERLATIVES_WITHIN_CATEGORY = new Set(["biggest", "smallest", "highest", "lowest"]);

/** "on the desk", "between the chair and the sofa", "closest to you", "the biggest"; a kind
 * the pages do not know is said with its name. */
export function relationWords(kind, anchorLabels) {
  const name = String(kind);
  if (SUPERLATIVES_WITHIN_CATEGORY.has(name)) return `the ${name}`;
  if (anchorLabels.length === 0) return TO_THE_ASKER[name] || `${name.replaceAll("_", " ")} you`;
  const names = anchorLabels.map((label) => `the ${label}`);
  const listed = names.length === 1 ? names[0] : `${names.slice(0, -1).join(", ")} and ${names.at(-1)}`;
  return `${RELATION_PHRASES[name] || name.replaceAll("_", " ")} ${listed}`;
}

/** "just now", "42 s ago", "10 min ago", "3 h ago", "2 days ago". */
export function agoWords(seconds) {
  const s = Math.max(0, seconds);
  if (s < 5) return "just now";
  if (s < 90) return `${Math.round(s)} s ago`;
  if (s < 5400) return `${Math.round(s / 60)} min ago`;
  if (s < 172800) return `${Math.round(s / 3600)} h ago`;
  return `${Math.round(s / 86400)} days ago`;
}

/** Where a spoken question was recognised, as the pages say it. */
export const RECOGNISED = {
  server: "recognised on the server (offline)", // the server's own recogniser: no cloud service
  device: "recognised on this device", // the browser's on-device recognition (processLocally)
};

/**
 * What was heard of a spoken question, and where: "heard “where is the fridge” (0.82) ·
 * recognised on the server (offline) in 412 ms". `confidence` and `asr_ms` are said when
 * known (the answer of POST /v1/sessions/{sid}/query/speech carries them).
 */
export function heardWords({ transcript, confidence = null, asr_ms = null }, where = "server") {
  const sure = typeof confidence === "number" ? ` (${confidence.toFixed(2)})` : "";
  const took = typeof asr_ms === "number" ? ` in ${Math.round(asr_ms)} ms` : "";
  return `heard “${transcript}”${sure} · ${RECOGNISED[where]}${took}`;
}
