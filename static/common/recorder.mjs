// Recording a spoken question for the server to recognise (POST /v1/sessions/{sid}/query/speech,
// docs/protocol.md), shared by the dashboard's mic button (static/app.js) and the real-device
// page's push-to-talk (static/xr/voice.mjs): the microphone through getUserMedia, opened for
// one recording and released after it, recorded by MediaRecorder in a type the server decodes.

/** What MediaRecorder may record, best first, spelled as MediaRecorder.isTypeSupported takes
 * them: Opus in WebM (Chrome, Firefox), Opus in Ogg (Firefox), AAC in MP4 (Safari). The
 * server takes each, with or without its `codecs` parameter. */
export const RECORDING_TYPES = ["audio/webm;codecs=opus", "audio/ogg;codecs=opus", "audio/mp4"];
export const MAX_RECORDING_MS = 29_000; // the server refuses a question over 30 s: stop before
export const MIN_RECORDING_MS = 250; // shorter holds no word: said so, not sent

/** The microphone's processing, for a recogniser rather than a call: the browser's noise
 * suppression garbles words for the server's (espeak-ng questions through Chromium's fake
 * microphone: 2 of 6 heard right with it, 5 of 6 without); its gain control stays (without
 * it, quieter words were lost: "where is the chair" heard as "where is look you"). */
export const MICROPHONE = { noiseSuppression: false };

/** The first of RECORDING_TYPES this browser records, or null. */
export function recordingType(isTypeSupported = (type) => MediaRecorder.isTypeSupported(type)) {
  return RECORDING_TYPES.find((type) => isTypeSupported(type)) ?? null;
}

/** Why this page cannot record a question, in words, or null when it can. */
export function microphoneProblem() {
  if (!window.isSecureContext) return "the microphone needs a secure page (https, or localhost)";
  if (!navigator.mediaDevices || !navigator.mediaDevices.getUserMedia) return "this browser gives the page no microphone";
  if (typeof MediaRecorder === "undefined") return "this browser cannot record audio (no MediaRecorder)";
  if (!recordingType()) return `this browser records none of ${RECORDING_TYPES.join(", ")}`;
  return null;
}

/**
 * Open the microphone and start recording. Resolves, once recording, to `{type, stop()}`;
 * `stop()` resolves to `{blob, durationMs}` (the blob typed as recorded, e.g.
 * "audio/webm;codecs=opus") and releases the microphone. `onLimit` is called when the
 * recording reaches `maxMs` (the caller stops it). Rejects as getUserMedia does
 * (NotAllowedError: refused; NotFoundError: no microphone).
 */
export async function startRecording({ maxMs = MAX_RECORDING_MS, onLimit = () => {} } = {}) {
  const type = recordingType();
  if (!type) throw new Error(microphoneProblem() || "no recording type");
  const stream = await navigator.mediaDevices.getUserMedia({ audio: MICROPHONE, video: false });
  const release = () => stream.getTracks().forEach((track) => track.stop());
  let recorder;
  try {
    recorder = new MediaRecorder(stream, { mimeType: type });
  } catch (error) {
    release();
    throw error;
  }
  const chunks = [];
  recorder.addEventListener("dataavailable", (event) => {
    if (event.data && event.data.size > 0) chunks.push(event.data);
  });
  const stopped = new Promise((resolve, reject) => {
    recorder.addEventListener("stop", resolve);
    recorder.addEventListener("error", (event) => reject(event.error || new Error("the recording failed")));
  });
  recorder.start();
  const startedMs = performance.now();
  const limit = setTimeout(onLimit, maxMs);
  return {
    type,
    async stop() {
      clearTimeout(limit);
      if (recorder.state !== "inactive") recorder.stop();
      try {
        await stopped;
      } finally {
        release();
      }
      const durationMs = performance.now() - startedMs;
      return { blob: new Blob(chunks, { type: recorder.mimeType || type }), durationMs };
    },
  };
}

/** The blob of a recording `stop()` resolved to; an Error saying so when it is too short to
 * hold a question. */
export function recordedQuestion({ blob, durationMs }) {
  if (blob.size === 0 || durationMs < MIN_RECORDING_MS) {
    throw new Error("too short to hold a question: hold the button while you speak, or tap it, speak, and tap again");
  }
  return blob;
}

/** A recording that could not start or failed, in words (getUserMedia's error names). */
export function recordingErrorWords(error) {
  const name = error && error.name;
  if (name === "NotAllowedError") return "the microphone was refused: allow it for this page and try again";
  if (name === "NotFoundError") return "no microphone was found";
  if (name === "NotReadableError") return "the microphone is in use by something else";
  return (error && error.message) || String(error);
}
