// The real-device page: pick or create a session, start AR, stream keyframes, follow the
// map, ask it, and draw the answer where it is. The stages are modules of their own, in the
// Python device's order: capture (capture.mjs) -> encode (encode-worker.mjs) -> send
// (stream.mjs) -> follow the updates (updates.mjs) -> answer (answers.mjs, draw.mjs).

import { ApiError, auth, request, sessionFromFragment } from "./api.mjs";
import { heardWords } from "../common/words.mjs";
import { ask, askAloud, answerWords } from "./answers.mjs";
import { Capture } from "./capture.mjs";
import { AnswerRenderer } from "./draw.mjs";
import { FrameSampler, isKeyframe } from "./keyframes.mjs";
import { FrameStream } from "./stream.mjs";
import { OfflineAnswerer } from "./offline.mjs";
import { MapFollower } from "./updates.mjs";
import { wireVoice } from "./voice.mjs";

/** The Python device's defaults (client_sim/encoder.py, `semanticxr device`), so a page and
 * the emulator send alike: 5 frames a second sampled, JPEG quality 50, depth in 1 cm units,
 * colour at most 640 px on its longer side. */
export const STREAM_DEFAULTS = { fps: 5, jpegQuality: 50, depthScaleM: 0.01, maxSide: 640 };

/** The stream settings, from the defaults and the page's query (?fps=&jpeg=&side=), which
 * are checked: a bad value is said, and the default kept. */
function streamSettings(query = new URLSearchParams(location.search)) {
  const settings = { ...STREAM_DEFAULTS };
  const bounds = { fps: ["fps", 0.2, 30], jpeg: ["jpegQuality", 1, 100], side: ["maxSide", 64, 4096] };
  const problems = [];
  for (const [param, [key, low, high]] of Object.entries(bounds)) {
    if (!query.has(param)) continue;
    const value = Number(query.get(param));
    if (Number.isFinite(value) && value >= low && value <= high) settings[key] = value;
    else problems.push(`?${param}= must be a number in ${low}..${high}; using ${settings[key]}`);
  }
  return { settings, problems };
}

const $ = (selector) => document.querySelector(selector);
const UPSTREAM_WINDOW_MS = 5000;
const COST_HISTORY = 600;

const state = {
  sid: null,
  record: null, // GET /v1/sessions/{sid}
  xr: null, // the running AR: {session, gl, space, capture, stream, ...}
  follower: null,
  offline: null, // an OfflineAnswerer of the session's static text tower, once loaded
  offlineState: "none", // "none" (no static tower), "loading", "ready" or the error's words
  answer: null,
  costs: [], // main-thread ms the page spent in each XR frame that captured, collected or sent
  runtimeCosts: [], // of those frames, ms inside the runtime's getCameraImage / getDepthInformation
  upstream: [], // [timeMs, messageBytes, payloadBytes] samples
  voice: null, // the push-to-talk (voice.mjs)
};

// ------------------------------------------------------------------ page state, for people and tests
function setConnection(text, name) {
  const pill = $("#connection");
  pill.textContent = text;
  pill.dataset.state = name;
}

function showBanner(message) {
  const banner = $("#banner");
  banner.textContent = message || "";
  banner.hidden = !message;
}

function percentile(values, q) {
  if (!values.length) return null;
  const sorted = [...values].sort((a, b) => a - b);
  return sorted[Math.min(sorted.length - 1, Math.floor(q * sorted.length))];
}

function kbits(bytes, ms) {
  return ms > 0 ? (bytes * 8) / ms : 0; // bytes per ms * 8 = kbit/s
}

function renderStats() {
  const xr = state.xr;
  const c = xr ? xr.stream.counters : null;
  $("#stat-frames").textContent = c ? String(c.frames) : "0";
  $("#stat-keyframes").textContent = c ? `${c.keyframes}${c.skipped ? ` (${c.skipped} skipped: link busy)` : ""}` : "0";
  const up = upstreamKbits();
  $("#stat-upstream").textContent = up ? `${up.whole.toFixed(0)} kbit/s whole · ${up.payload.toFixed(0)} kbit/s payload` : "—";
  const objects = state.follower ? state.follower.objects.size : c && c.objects !== null ? c.objects : null;
  $("#stat-objects").textContent = objects === null ? "—" : String(objects);
  if (xr) {
    const cost = percentile(state.costs, 0.95);
    const skew = xr.lastSkewS === null ? "" : ` · pose ${Math.abs(xr.lastSkewS * 1000).toFixed(0)} ms from the image`;
    $("#stat-capture").textContent = `${xr.capture.describe()}${skew}${cost === null ? "" : ` · ${cost.toFixed(1)} ms/frame p95`}`;
  }
}

function upstreamKbits() {
  const samples = state.upstream;
  if (samples.length < 2) return null;
  const [t0, m0, p0] = samples[0];
  const [t1, m1, p1] = samples[samples.length - 1];
  return { whole: kbits(m1 - m0, t1 - t0), payload: kbits(p1 - p0, t1 - t0) };
}

/** What tests and benchmarks read: the page's own counts, as it shows them. */
window.semanticxr = {
  get counters() {
    const xr = state.xr || state.lastXr; // after AR ends, what it sent
    return xr ? { ...xr.stream.counters } : null;
  },
  get costs() {
    return [...state.costs];
  },
  get runtimeCosts() {
    return [...state.runtimeCosts];
  },
  get streaming() {
    return Boolean(state.xr && state.xr.streaming);
  },
  get sessionId() {
    return state.sid;
  },
  get objects() {
    return state.follower ? state.follower.objects.size : null;
  },
  get answer() {
    return state.answer;
  },
  get offline() {
    return state.offlineState;
  },
};

// ------------------------------------------------------------------ sessions
async function listSessions() {
  const select = $("#session-select");
  let sessions = [];
  try {
    sessions = await request("GET", "/v1/sessions");
  } catch (error) {
    if (!(error instanceof ApiError && (error.status === 401 || error.status === 403))) throw error;
    // Without the API key the list is closed; sessions this page holds a token for still open.
  }
  const known = new Map(sessions.map((s) => [s.session_id, s.name]));
  for (const sid of Object.keys(auth.tokens())) if (!known.has(sid)) known.set(sid, sid);
  if (state.sid && !known.has(state.sid)) known.set(state.sid, state.sid);
  const options = [new Option("—", "")];
  for (const [sid, name] of known) options.push(new Option(name === sid ? sid : `${name} (${sid.slice(0, 8)})`, sid));
  select.replaceChildren(...options);
  select.value = state.sid || "";
}

async function chooseSession(sid) {
  state.sid = sid || null;
  state.record = null;
  state.offline = null;
  state.offlineState = "none";
  state.voice.setSession(state.sid);
  $("#start-ar").disabled = true;
  if (!sid) {
    $("#session-info").textContent = "No session chosen.";
    return;
  }
  try {
    state.record = await request("GET", `/v1/sessions/${encodeURIComponent(sid)}`, { sid });
  } catch (error) {
    $("#session-info").textContent = `Session ${sid}: ${error.message}`;
    return;
  }
  const r = state.record;
  const lines = [`“${r.name}”: ${r.objects} objects, ${r.frames} frames, perception ${r.perception}.`];
  if (r.perception !== "models") lines.push("It maps a device's own detections; a page sends none, so create a session for this page.");
  for (const warning of r.warnings || []) lines.push(`Server: ${warning}`);
  if (r.frames > 0) lines.push("Start AR maps into a new session: this one was mapped in another AR session, whose coordinates this one does not share.");
  $("#session-info").textContent = lines.join(" ");
  $("#start-ar").disabled = !state.xrSupported;
  startFollowing(sid);
  prepareOffline(sid, r);
}

/** With a static text tower, load it (once per browser: cached by hash) and the match rule,
 * so a plain question is answered as the server would when the server is out of reach. */
function prepareOffline(sid, record) {
  if (!record.embedding || !String(record.embedding.model).startsWith("static-")) return;
  state.offlineState = "loading";
  OfflineAnswerer.forRecord(record).then(
    (answerer) => {
      if (state.sid !== sid) return;
      state.offline = answerer;
      state.offlineState = "ready";
    },
    (error) => {
      if (state.sid !== sid) return;
      state.offlineState = `failed: ${error.message}`;
      $("#session-info").textContent += ` Offline answers by label words only: the text tower did not load (${error.message}).`;
    },
  );
}

async function createSession(name) {
  // A page has no detections: the server's perception finds the objects. Y is up in WebXR.
  const body = { name: name || "real device", perception: "models", up: "+y" };
  const created = await request("POST", "/v1/sessions", { body });
  auth.setToken(created.session_id, created.token);
  history.replaceState(null, "", `#session=${encodeURIComponent(created.session_id)}`);
  await listSessions();
  $("#session-select").value = created.session_id;
  await chooseSession(created.session_id);
  return created.session_id;
}

function startFollowing(sid) {
  if (state.follower) state.follower.stop();
  state.follower = new MapFollower({
    sid,
    onChange: () => {
      renderStats();
      if (state.xr && state.answer) state.xr.renderer.setAnswer(state.answer, state.follower);
    },
    onState: () => renderStats(),
  });
  state.follower.start();
}

// ------------------------------------------------------------------ AR
async function detectXr() {
  const note = $("#xr-support");
  if (!window.isSecureContext) {
    state.xrSupported = false;
    note.textContent = "WebXR needs a secure page: open it over https (semanticxr serve --https) or on localhost.";
    return;
  }
  state.xrSupported = Boolean(navigator.xr) && (await navigator.xr.isSessionSupported("immersive-ar").catch(() => false));
  note.textContent = state.xrSupported
    ? ""
    : "This browser has no WebXR immersive-ar: use Chrome on an ARCore Android phone or the Quest Browser. On iPhone or iPad, record with a LiDAR capture app and map the file (README, “iPhone and iPad”).";
}

async function startAr() {
  showBanner("");
  let sid = state.sid;
  if (!sid) return;
  if (state.record && state.record.frames > 0) sid = await createSession(`${state.record.name} (AR ${new Date().toLocaleTimeString()})`);
  const record = state.record;
  if (record.perception !== "models") {
    showBanner("This session maps a device's own detections (perception: detections); a page sends none. Create a session on this page.");
    return;
  }
  const overlay = $("#overlay");
  const session = await navigator.xr.requestSession("immersive-ar", {
    requiredFeatures: ["depth-sensing"],
    optionalFeatures: ["camera-access", "local-floor", "dom-overlay"],
    domOverlay: { root: overlay },
    depthSensing: {
      usagePreference: ["cpu-optimized", "gpu-optimized"],
      dataFormatPreference: ["luminance-alpha", "float32", "unsigned-short"],
    },
  });
  const canvas = $("#xr-canvas");
  const gl = canvas.getContext("webgl2", { xrCompatible: true, alpha: true, antialias: false });
  await gl.makeXRCompatible();
  session.updateRenderState({ baseLayer: new XRWebGLLayer(session, gl) });
  let space;
  try {
    space = await session.requestReferenceSpace("local-floor");
  } catch {
    space = await session.requestReferenceSpace("local");
  }
  let video = null;
  if (!(session.enabledFeatures || []).includes("camera-access")) video = await headsetCamera();
  const capture = new Capture({ session, gl, space, video });
  const stream = new FrameStream({ sid, onState: (s, detail) => onStreamState(s, detail), onAck: () => renderStats() });
  await stream.open();
  const knobs = record.knobs || {};
  const worker = new Worker(new URL("./encode-worker.mjs", import.meta.url), { type: "module" });
  const xr = {
    session,
    gl,
    space,
    capture,
    stream,
    worker,
    sampler: new FrameSampler(state.settings.fps),
    keyframeInterval: knobs.keyframe_interval || 5,
    options: {
      ratio: knobs.depth_downsampling_ratio || 5,
      depthScaleM: state.settings.depthScaleM,
      jpegQuality: state.settings.jpegQuality,
      maxSide: state.settings.maxSide,
    },
    encoding: 0,
    nextSeq: 0,
    lastSkewS: null,
    streaming: true,
    renderer: new AnswerRenderer(gl),
  };
  state.xr = xr;
  worker.onmessage = (event) => onEncoded(xr, event.data);
  space.addEventListener("reset", () => stopStreaming(xr, "The tracking origin moved (the reference space was reset): streaming stopped so the map is not mixed with a moved frame. End AR and start again: a new session will be made."));
  session.addEventListener("end", () => endAr(xr));
  document.body.classList.add("in-ar");
  setConnection("streaming", "streaming");
  if (state.answer) xr.renderer.setAnswer(state.answer, state.follower);
  session.requestAnimationFrame((time, frame) => onXrFrame(xr, time, frame));
}

async function headsetCamera() {
  // Quest Browser: the passthrough cameras under the headset-cameras permission.
  const media = await navigator.mediaDevices.getUserMedia({ video: { width: { ideal: 1280 }, height: { ideal: 960 }, facingMode: "environment" }, audio: false });
  const video = document.createElement("video");
  video.muted = true;
  video.playsInline = true;
  video.srcObject = media;
  await video.play();
  return video;
}

function onXrFrame(xr, time, frame) {
  xr.session.requestAnimationFrame((t, f) => onXrFrame(xr, t, f));
  const pose = frame.getViewerPose(xr.space);
  if (pose) {
    const started = performance.now();
    const runtimeBefore = xr.capture.runtimeMs;
    let worked = false;
    xr.capture.notePose(time, pose);
    const p = pose.transform.position;
    xr.lastPosition = [p.x, p.y, p.z];
    const { done, failed } = xr.capture.collect();
    for (const reason of failed) showBanner(reason);
    for (const job of done) {
      worked = true;
      encode(xr, job);
    }
    if (xr.streaming && xr.sampler.take(time)) {
      const index = xr.sampler.sampled - 1;
      const keyframe = !xr.stream.pickKeyframes || isKeyframe(index, xr.keyframeInterval);
      if (keyframe) {
        if (xr.capture.busy || xr.encoding > 0 || !xr.stream.ready) xr.stream.counters.skipped += 1;
        else worked = xr.capture.begin(frame, pose, time) || worked;
      }
    }
    if (worked) {
      // The page's own work: what the runtime spends producing an image or depth is not ours.
      const runtime = xr.capture.runtimeMs - runtimeBefore;
      state.costs.push(performance.now() - started - runtime);
      state.runtimeCosts.push(runtime);
      if (state.costs.length > COST_HISTORY) state.costs.shift();
      if (state.runtimeCosts.length > COST_HISTORY) state.runtimeCosts.shift();
    }
    drawAnswer(xr, pose);
  }
}

function encode(xr, job) {
  xr.encoding += 1;
  xr.lastSkewS = job.poseSkewS;
  const transfer = [];
  if (job.colour.kind === "pixels") transfer.push(job.colour.rgba);
  else transfer.push(job.colour.bitmap);
  if (job.depth.kind === "cpu") transfer.push(job.depth.buffer);
  else transfer.push(job.depth.depth);
  // One frame encodes at a time (a capture waits for it), so seqs leave in order.
  const seq = xr.nextSeq++;
  xr.worker.postMessage(
    { id: seq, seq, t: job.t, camera: job.camera, colour: job.colour, depth: job.depth, options: { ...xr.options, poseSkewS: job.poseSkewS } },
    transfer,
  );
}

function onEncoded(xr, result) {
  xr.encoding -= 1;
  if (result.error) {
    showBanner(`A frame could not be encoded: ${result.error}`);
    return;
  }
  if (!xr.streaming) return;
  const sent = performance.now();
  xr.stream.send(result.seq, result.message, result.payload, true);
  state.costs.push(performance.now() - sent);
  if (state.costs.length > COST_HISTORY) state.costs.shift();
  const c = xr.stream.counters;
  state.upstream.push([performance.now(), c.messageBytes, c.payloadBytes]);
  while (state.upstream.length > 2 && state.upstream[state.upstream.length - 1][0] - state.upstream[0][0] > UPSTREAM_WINDOW_MS) state.upstream.shift();
  renderStats();
}

function drawAnswer(xr, pose) {
  const gl = xr.gl;
  const layer = xr.session.renderState.baseLayer;
  gl.bindFramebuffer(gl.FRAMEBUFFER, layer.framebuffer);
  gl.clearColor(0, 0, 0, 0);
  gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
  for (const view of pose.views) {
    const viewport = layer.getViewport(view);
    gl.viewport(viewport.x, viewport.y, viewport.width, viewport.height);
    xr.renderer.draw(view.projectionMatrix, view.transform.inverse.matrix);
  }
}

function onStreamState(name, detail) {
  if (name === "closed" && state.xr && state.xr.streaming) {
    setConnection("disconnected", "error");
    showBanner(`The stream closed: ${detail}. The map and its answers stay; end AR and start again to stream.`);
    state.xr.streaming = false;
  }
  renderStats();
}

function stopStreaming(xr, reason) {
  xr.streaming = false;
  xr.stream.close();
  setConnection("stopped", "stopped");
  showBanner(reason);
}

function endAr(xr) {
  xr.streaming = false;
  xr.stream.close();
  xr.capture.close();
  xr.worker.terminate();
  xr.renderer.dispose();
  document.body.classList.remove("in-ar");
  if (state.xr === xr) state.xr = null;
  state.lastXr = xr;
  setConnection("not streaming", "idle");
  if (state.sid) chooseSession(state.sid);
}

// ------------------------------------------------------------------ asking
// A typed question and a spoken one end alike: the answer in words, drawn in the room.
function showAnswer(answer) {
  state.answer = answer;
  const line = $("#answer");
  line.textContent = answerWords(answer);
  line.dataset.match = String(Boolean(answer.match));
  if (state.xr) state.xr.renderer.setAnswer(answer, state.follower);
}

/** What was heard of a spoken question (or why nothing was), null to hide the line. */
function showHeard(text, error = false) {
  const line = $("#heard");
  line.textContent = text || "";
  line.dataset.error = String(error);
  line.hidden = !text;
}

function askerPosition() {
  return state.xr && state.xr.lastPosition ? state.xr.lastPosition : null;
}

// How the page asks: from where the wearer stands, a static session's answer re-ranked by
// MiniLM on the server when online (its own tower offline).
function askOptions() {
  return { sid: state.sid, follower: state.follower, offline: state.offline, k: 5, from: askerPosition(), rerank: true };
}

async function onAsk(text) {
  if (!state.sid || !text) return;
  const answer = await ask(text, askOptions());
  showHeard(null);
  showAnswer(answer);
}

// Recorded: the server recognises it and answers what it heard.
async function onAskAloud(audio) {
  if (!state.sid) return;
  showHeard("recognising on the server…");
  let answer;
  try {
    answer = await askAloud(audio, askOptions());
  } catch (error) {
    showHeard(`not answered: ${spokenErrorWords(error)}`, true);
    return;
  }
  showHeard(heardWords(answer, "server"));
  showAnswer(answer);
}

// Recognised on the device: asked as typed text is (from the page's copy when offline).
async function onRecognised({ transcript, confidence }) {
  if (!state.sid) return;
  const answer = await ask(transcript, askOptions());
  showHeard(heardWords({ transcript, confidence }, "device"));
  showAnswer({ ...answer, transcript, confidence, asr_ms: null, recognised: "device" });
}

function spokenErrorWords(error) {
  if (error instanceof ApiError) {
    const again = error.retryAfterS ? `; try again in ${error.retryAfterS} s` : "";
    return `${error.detail} (${error.status})${again}`;
  }
  if (error.name === "TimeoutError") return "the server did not answer in time";
  // The page cannot recognise speech by itself: a typed question is answered from its copy.
  return `the server is out of reach (${error.message}); type the question instead`;
}

// ------------------------------------------------------------------ start
function wire() {
  $("#api-key").value = auth.apiKey();
  $("#key-form").addEventListener("submit", (event) => {
    event.preventDefault();
    auth.setApiKey($("#api-key").value.trim());
    listSessions().catch((error) => showBanner(error.message));
  });
  $("#refresh").addEventListener("click", () => listSessions().catch((error) => showBanner(error.message)));
  $("#session-select").addEventListener("change", (event) => chooseSession(event.target.value));
  $("#create-form").addEventListener("submit", (event) => {
    event.preventDefault();
    showBanner("");
    createSession($("#session-name").value.trim()).catch((error) => showBanner(`The session could not be created: ${error.message}`));
  });
  $("#start-ar").addEventListener("click", () =>
    startAr().catch((error) => {
      setConnection("not streaming", "error");
      showBanner(`AR could not start: ${error.message || error}`);
    }),
  );
  $("#ask-form").addEventListener("submit", (event) => {
    event.preventDefault();
    onAsk($("#ask-text").value.trim()).catch((error) => showBanner(`The question could not be asked: ${error.message}`));
  });
  state.voice = wireVoice({
    button: $("#talk"),
    onDevice: $("#on-device"),
    note: $("#voice-note"),
    onRecorded: onAskAloud,
    onRecognised,
    onError: (message) => showHeard(`not answered: ${message}`, true),
  });
  setInterval(renderStats, 1000);
}

async function start() {
  const { settings, problems } = streamSettings();
  state.settings = settings;
  if (problems.length) showBanner(problems.join("; "));
  wire();
  const opened = sessionFromFragment();
  if (opened) {
    if (opened.token) auth.setToken(opened.sid, opened.token);
    // Keep the session in the address, not the token (screenshots, shoulder surfers).
    history.replaceState(null, "", `#session=${encodeURIComponent(opened.sid)}`);
    state.sid = opened.sid;
  }
  await detectXr();
  await listSessions().catch((error) => showBanner(error.message));
  if (state.sid) await chooseSession(state.sid);
}

start();
