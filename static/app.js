// The session dashboard: lists the server's sessions with live stats, asks queries, plots
// objects top-down, shows each session's page for a phone as a QR code. A plain ES module, no
// build step; its one dependency, the vendored QR generator, comes through session-qr.mjs.
//
// Safety rule for this file: text from the server (session names, object labels, error
// details) is user data. It only ever reaches the page through textContent, attributes set
// with setAttribute on fixed names, or canvas fillText; never through innerHTML.
import { auth } from "./common/auth.mjs";
import { PushToTalk } from "./common/push-to-talk.mjs";
import { microphoneProblem, recordedQuestion, recordingErrorWords, startRecording } from "./common/recorder.mjs";
import { agoWords, CONFIDENT_DEGREE, CONFIDENT_RELEVANCE, heardWords, relationWords } from "./common/words.mjs";
import { qrDataUrl, sessionPageUrl } from "./session-qr.mjs";

(() => {
  const POLL_MS = 2000; // the list and stats refresh period (the brief's "about 2 s")
  const QUERY_K = 5;
  const CHANGES_SHOWN = 20; // the newest changes the timeline lists

  const $ = (selector, root = document) => root.querySelector(selector);

  // --- HTTP -----------------------------------------------------------------------------

  class HttpError extends Error {
    constructor(status, detail, retryAfterS = null) {
      const again = retryAfterS ? `; try again in ${retryAfterS} s` : "";
      super(status ? `HTTP ${status}: ${detail}${again}` : `server unreachable: ${detail}`);
      this.status = status;
    }
  }

  // Every error answer is {"detail": "<what is wrong>"} (422s included).
  function formatDetail(body, fallback) {
    const detail = body && typeof body === "object" ? body.detail : undefined;
    if (typeof detail === "string") return detail;
    return fallback || "no detail";
  }

  // A GET, or a POST of `body`: a Blob sent as it is, typed by its own type (a recorded
  // question's "audio/webm;codecs=opus").
  async function api(path, credential, { method = "GET", body = undefined } = {}) {
    const headers = { Accept: "application/json" };
    if (credential) headers.Authorization = `Bearer ${credential}`;
    if (body !== undefined) headers["Content-Type"] = body.type;
    let response;
    try {
      response = await fetch(path, { method, headers, body, cache: "no-store" });
    } catch (err) {
      throw new HttpError(0, err.message || "network error");
    }
    let answer = null;
    try {
      answer = await response.json();
    } catch {
      answer = null; // an error page that is not JSON: the status text says enough
    }
    if (!response.ok) {
      const retryAfterS = Number(response.headers.get("Retry-After")) || null; // 503: busy
      throw new HttpError(response.status, formatDetail(answer, response.statusText), retryAfterS);
    }
    return answer;
  }

  // --- formatting ------------------------------------------------------------------------

  function formatBytes(n) {
    if (typeof n !== "number" || !isFinite(n)) return "–";
    const units = ["B", "KiB", "MiB", "GiB", "TiB"];
    let i = 0;
    while (n >= 1024 && i < units.length - 1) {
      n /= 1024;
      i += 1;
    }
    return `${i === 0 ? n : n.toFixed(n < 10 ? 2 : 1)} ${units[i]}`;
  }

  function formatMs(ms) {
    return typeof ms === "number" && isFinite(ms) ? `${ms < 10 ? ms.toFixed(1) : Math.round(ms)} ms` : "–";
  }

  // "rgb 1.2 MiB · depth 310 KiB · …" for a bytes-by-kind dict (total shown separately).
  function bytesBreakdown(byKind) {
    return Object.entries(byKind || {})
      .filter(([kind]) => kind !== "total")
      .map(([kind, n]) => `${kind} ${formatBytes(n)}`)
      .join(" · ");
  }

  function formatAge(createdAtS) {
    const s = Math.max(0, Date.now() / 1000 - createdAtS);
    if (s < 90) return `created ${Math.round(s)} s ago`;
    if (s < 5400) return `created ${Math.round(s / 60)} min ago`;
    if (s < 172800) return `created ${Math.round(s / 3600)} h ago`;
    return `created ${Math.round(s / 86400)} days ago`;
  }

  // --- the living map in words (app/cli/sessions.py says the same) ------------------------

  // A place ({relation, id, label}) in words: "on the dining table", "near the sofa"; where
  // a removed thing was: "from the desk", "from near the sofa". "" without one.
  function placeWords(place, removed = false) {
    if (!place || typeof place !== "object" || typeof place.label !== "string") return "";
    const the = `the ${place.label}`;
    if (removed) return place.relation === "on" ? `from ${the}` : `from near ${the}`;
    return `${place.relation === "on" ? "on" : "near"} ${the}`;
  }

  const isTime = (t) => typeof t === "number" && isFinite(t);

  // "mug moved on the dining table · 10 min ago"
  function changeWords(change, nowT) {
    const where = placeWords(change.place, change.kind === "removed");
    let text = `${change.label} ${change.kind}${where ? ` ${where}` : ""}`;
    if (isTime(nowT) && isTime(change.t)) text += ` · ${agoWords(nowT - change.t)}`;
    return text;
  }

  // A hit's "(removed) · near the sofa · last seen 3 min ago" (parts it has, from an older
  // server none).
  function hitWhereWhen(hit, nowT) {
    const parts = [];
    if (hit.state === "removed") parts.push("(removed)");
    const where = placeWords(hit.place);
    if (where) parts.push(where);
    if (isTime(nowT) && isTime(hit.last_seen_t)) parts.push(`last seen ${agoWords(nowT - hit.last_seen_t)}`);
    return parts.join(" · ");
  }

  // --- relational answers in words (viewer/scene.py `relation_words` says the same) ---------

  // The relation a hit is in, null for a plain hit (or from a server without relations).
  function relationOf(hit) {
    const relation = hit && hit.relation;
    if (!relation || typeof relation !== "object" || !Array.isArray(relation.anchors)) return null;
    return relation;
  }

  // A hit's relation in words, "not ..." under CONFIDENT_DEGREE: "" for a plain hit.
  function hitRelationWords(hit) {
    const relation = relationOf(hit);
    if (!relation) return "";
    const words = relationWords(relation.kind, relation.anchors.map((a) => String(a.label)));
    return relation.degree >= CONFIDENT_DEGREE ? words : `not ${words}`;
  }

  // How strongly a hit answers, in [0, 1]: its relevance, times its relation's degree in a
  // relational answer (the mug on the shelf is no answer to "the mug on the desk").
  function hitStrength(hit) {
    const relation = relationOf(hit);
    const strength = (hit.relevance ?? 1) * (relation ? relation.degree : 1);
    return Math.min(Math.max(strength, 0), 1);
  }

  // The best hit as an answer: "mug — on the desk" (a relational answer), "laptop — on the
  // dining table, 10 min ago" (where it is, or was last seen, and when), else its label.
  function answerWords(hit, nowT) {
    const relation = hitRelationWords(hit);
    if (relation) return `${hit.label} — ${relation}`;
    const where = placeWords(hit.place);
    const when = isTime(nowT) && isTime(hit.last_seen_t) ? agoWords(nowT - hit.last_seen_t) : "";
    const said = [where, when].filter(Boolean).join(", ");
    return said ? `${hit.label} — ${said}` : hit.label;
  }

  // The viewer's address: ?viewer=URL, else port 8080 on this page's host. Only http(s):
  // a javascript: URL in a crafted link must not become a clickable script.
  function viewerUrl() {
    const fallback = new URL(location.href);
    fallback.port = "8080";
    fallback.pathname = "/";
    fallback.search = "";
    fallback.hash = "";
    const wanted = new URLSearchParams(location.search).get("viewer");
    if (!wanted) return fallback.href;
    try {
      const url = new URL(wanted, location.href);
      if (url.protocol === "http:" || url.protocol === "https:") return url.href;
    } catch {
      // fall through to the warning
    }
    showBanner(`ignoring ?viewer=${wanted}: not an http(s) URL`);
    return fallback.href;
  }

  function showBanner(message) {
    const banner = $("#banner");
    banner.textContent = message;
    banner.hidden = !message;
  }

  // --- the top-down plot -----------------------------------------------------------------

  function cssColor(name) {
    return getComputedStyle(document.documentElement).getPropertyValue(name).trim() || "#888";
  }

  // Objects' footprints (bbox x/y extents) and centroids seen from above (the synthetic world
  // and the mapping engine are z-up); query hits drawn on top, numbered by rank, each as
  // strong as its relevance (a weak hit is a faint outline, a confident one a bold box). A
  // relational answer ({target, anchors}: the target's id or null, the anchors' objects)
  // also shows its anchors in a colour of their own, joined to the target by a line.
  function drawPlot(canvas, labelLayer, objects, hits, relation = null) {
    const dpr = window.devicePixelRatio || 1;
    const widthPx = canvas.clientWidth || 320;
    const heightPx = canvas.clientHeight || widthPx;
    canvas.width = Math.round(widthPx * dpr);
    canvas.height = Math.round(heightPx * dpr);
    const ctx = canvas.getContext("2d");
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.clearRect(0, 0, widthPx, heightPx);
    const colors = {
      grid: cssColor("--grid"),
      muted: cssColor("--muted"),
      text: cssColor("--text"),
      hit: cssColor("--accent"),
      object: cssColor("--object"),
      anchor: cssColor("--anchor"),
      surface: cssColor("--surface"),
    };
    const anchors = relation ? relation.anchors : [];
    ctx.font = "12px system-ui, sans-serif";

    const all = [...objects, ...hits, ...anchors];
    labelLayer.replaceChildren();
    if (all.length === 0) {
      ctx.fillStyle = colors.muted;
      ctx.textAlign = "center";
      ctx.fillText("no confirmed objects yet", widthPx / 2, heightPx / 2);
      return;
    }
    let [x0, y0, x1, y1] = [Infinity, Infinity, -Infinity, -Infinity];
    for (const o of all) {
      x0 = Math.min(x0, o.bbox[0]);
      y0 = Math.min(y0, o.bbox[1]);
      x1 = Math.max(x1, o.bbox[3]);
      y1 = Math.max(y1, o.bbox[4]);
    }
    // Equal scale on both axes (a top-down map must not stretch), with a margin.
    const marginPx = 22;
    const spanM = Math.max(x1 - x0, y1 - y0, 0.5);
    const scale = Math.min(widthPx - 2 * marginPx, heightPx - 2 * marginPx) / spanM;
    const cx = (x0 + x1) / 2;
    const cy = (y0 + y1) / 2;
    const sx = (x) => widthPx / 2 + (x - cx) * scale;
    const sy = (y) => heightPx / 2 - (y - cy) * scale; // world +y points up on screen

    // 1 m grid
    ctx.strokeStyle = colors.grid;
    ctx.lineWidth = 1;
    ctx.beginPath();
    for (let gx = Math.ceil(cx - widthPx / 2 / scale); gx <= cx + widthPx / 2 / scale; gx += 1) {
      ctx.moveTo(Math.round(sx(gx)) + 0.5, 0);
      ctx.lineTo(Math.round(sx(gx)) + 0.5, heightPx);
    }
    for (let gy = Math.ceil(cy - heightPx / 2 / scale); gy <= cy + heightPx / 2 / scale; gy += 1) {
      ctx.moveTo(0, Math.round(sy(gy)) + 0.5);
      ctx.lineTo(widthPx, Math.round(sy(gy)) + 0.5);
    }
    ctx.stroke();

    const hitIds = new Set(hits.map((h) => h.id));
    const anchorIds = new Set(anchors.map((a) => a.id));
    for (const o of objects) {
      if (hitIds.has(o.id) || anchorIds.has(o.id)) continue;
      ctx.strokeStyle = colors.object;
      ctx.globalAlpha = 0.55;
      ctx.strokeRect(sx(o.bbox[0]), sy(o.bbox[4]), (o.bbox[3] - o.bbox[0]) * scale, (o.bbox[4] - o.bbox[1]) * scale);
      ctx.globalAlpha = 1;
      ctx.fillStyle = colors.object;
      ctx.beginPath();
      ctx.arc(sx(o.centroid[0]), sy(o.centroid[1]), 2.5, 0, 2 * Math.PI);
      ctx.fill();
    }
    // The anchors under the hits: what the answer is measured against, teal, not a hit.
    for (const a of anchors) {
      const [left, top] = [sx(a.bbox[0]), sy(a.bbox[4])];
      const [w, hgt] = [(a.bbox[3] - a.bbox[0]) * scale, (a.bbox[4] - a.bbox[1]) * scale];
      ctx.globalAlpha = 0.18;
      ctx.fillStyle = colors.anchor;
      ctx.fillRect(left, top, w, hgt);
      ctx.globalAlpha = 1;
      ctx.strokeStyle = colors.anchor;
      ctx.lineWidth = 2.5;
      ctx.setLineDash([6, 3]);
      ctx.strokeRect(left, top, w, hgt);
      ctx.setLineDash([]);
    }
    // Hits last, best last, so the best match is never hidden under a worse one.
    [...hits].reverse().forEach((h, reversedIndex) => {
      const rank = hits.length - reversedIndex;
      const [left, top] = [sx(h.bbox[0]), sy(h.bbox[4])];
      const [w, hgt] = [(h.bbox[3] - h.bbox[0]) * scale, (h.bbox[4] - h.bbox[1]) * scale];
      const relevance = hitStrength(h);
      ctx.globalAlpha = 0.04 + 0.3 * relevance;
      ctx.fillStyle = colors.hit;
      ctx.fillRect(left, top, w, hgt);
      ctx.globalAlpha = 0.3 + 0.7 * relevance;
      ctx.strokeStyle = colors.hit;
      ctx.lineWidth = 1 + 2 * relevance;
      ctx.strokeRect(left, top, w, hgt);
      const [px, py] = [sx(h.centroid[0]), sy(h.centroid[1])];
      ctx.beginPath();
      ctx.arc(px, py, 2.5 + 3 * relevance, 0, 2 * Math.PI);
      ctx.fillStyle = colors.hit;
      ctx.fill();
      ctx.globalAlpha = 1;
    });
    // The target joined to each anchor, centre to centre, from the hit colour to the anchor's.
    const target = relation && relation.target !== null ? hits.find((h) => h.id === relation.target) : null;
    for (const a of target ? anchors : []) {
      const [tx, ty, ax, ay] = [sx(target.centroid[0]), sy(target.centroid[1]), sx(a.centroid[0]), sy(a.centroid[1])];
      const gradient = ctx.createLinearGradient(tx, ty, ax, ay);
      gradient.addColorStop(0, colors.hit);
      gradient.addColorStop(1, colors.anchor);
      ctx.strokeStyle = gradient;
      ctx.lineWidth = 2.5;
      ctx.beginPath();
      ctx.moveTo(tx, ty);
      ctx.lineTo(ax, ay);
      ctx.stroke();
      ctx.beginPath();
      ctx.arc(ax, ay, 4, 0, 2 * Math.PI);
      ctx.fillStyle = colors.anchor;
      ctx.fill();
    }

    // scale bar
    ctx.fillStyle = colors.muted;
    ctx.strokeStyle = colors.muted;
    ctx.lineWidth = 2;
    ctx.beginPath();
    ctx.moveTo(marginPx, heightPx - 8);
    ctx.lineTo(marginPx + scale, heightPx - 8);
    ctx.stroke();
    ctx.textAlign = "left";
    ctx.fillText("1 m", marginPx + scale + 6, heightPx - 4);

    // The hits' labels, best first (the anchors' right after the best), where they overlap
    // no other label.
    const scaleBar = { left: 0, top: heightPx - 20, right: marginPx + scale + 40, bottom: heightPx };
    const labels = hits.map((h, i) => ({
      text: `${i + 1} ${h.label}`,
      short: `${i + 1}`,
      x: sx(h.centroid[0]),
      y: sy(h.centroid[1]),
      kind: "hit",
    })).filter((_, i) => !anchorIds.has(hits[i].id)); // an anchor's own label says it
    const anchorLabels = anchors.map((a) => ({
      text: String(a.label),
      short: "",
      x: sx(a.centroid[0]),
      y: sy(a.centroid[1]),
      kind: "anchor",
    }));
    labels.splice(Math.min(1, labels.length), 0, ...anchorLabels);
    const boxes = placeLabels(ctx, labels, widthPx, heightPx, [scaleBar]);
    labelLayer.replaceChildren(...boxes.map((b) => {
      const span = document.createElement("span");
      span.className = `plot-label ${b.kind}`;
      span.textContent = b.text; // user data: text only
      span.style.left = `${b.left}px`;
      span.style.top = `${b.top}px`;
      return span;
    }));
  }

  const LABEL_HEIGHT_PX = 16;
  const LABEL_PAD_PX = 3; // each side, inside the label's box

  function overlaps(a, b) {
    return a.left < b.right && b.left < a.right && a.top < b.bottom && b.top < a.bottom;
  }

  // Greedy label placement: each label, in order, takes the first of a few spots around its
  // point (right, left, above, below, then farther out) that stays inside the plot and
  // overlaps no label placed before it nor an obstacle; when no spot fits, its short text
  // (the rank) is tried the same way, and when that fails too it is left out. Returns the
  // placed boxes {text, kind, left, top, right, bottom} in CSS pixels of the plot (kind: the
  // label's, "hit" or "anchor"). A label without a short text is left out when it does not fit.
  function placeLabels(ctx, labels, widthPx, heightPx, obstacles = []) {
    const placed = [];
    const h = LABEL_HEIGHT_PX;
    for (const label of labels) {
      for (const text of [label.text, label.short].filter(Boolean)) {
        const w = Math.ceil(ctx.measureText(text).width) + 2 * LABEL_PAD_PX + 2; // 2: font slack
        const [x, y] = [label.x, label.y];
        const spots = [];
        for (const gap of [6, 6 + h, 6 + 2 * h]) {
          spots.push(
            [x + gap, y - h / 2 - gap / 2], // right, a little up
            [x - gap - w, y - h / 2 - gap / 2], // left
            [x - w / 2, y - gap - h], // above
            [x - w / 2, y + gap], // below
            [x + gap, y + gap / 2], // right, down
            [x - gap - w, y + gap / 2], // left, down
          );
        }
        const fits = (box) =>
          box.left >= 0 && box.top >= 0 && box.right <= widthPx && box.bottom <= heightPx &&
          !placed.some((other) => overlaps(box, other)) &&
          !obstacles.some((other) => overlaps(box, other));
        const box = spots
          .map(([left, top]) => ({ text, kind: label.kind, left: Math.round(left), top: Math.round(top) }))
          .map((b) => ({ ...b, right: b.left + w, bottom: b.top + h }))
          .find(fits);
        if (box) {
          placed.push(box);
          break;
        }
      }
    }
    return placed;
  }

  // --- one session's card ----------------------------------------------------------------

  class SessionCard {
    constructor(sid) {
      this.sid = sid;
      this.root = $("#session-card").content.firstElementChild.cloneNode(true);
      this.root.dataset.sid = sid;
      $(".session-id", this.root).textContent = sid;
      this.objects = [];
      this.hits = [];
      this.match = false; // the query answer's match
      this.nowT = null; // the query answer's now_t: what its hits' "last seen" counts from
      this.objectsSeq = null; // update_seq the plotted objects are from
      this.createdAt = 0;
      this.loaded = false; // stats arrived at least once
      this.phoneUrl = null; // the /xr link its QR code shows now
      this.showPhoneLink();
      $(".query-form", this.root).addEventListener("submit", (event) => {
        event.preventDefault();
        this.query($(".query-input", this.root).value.trim());
      });
      // Spoken questions: recorded here, recognised by the server (offline), answered as typed.
      this.talk = new PushToTalk($(".query-mic", this.root), {
        start: ({ onLimit }) => startRecording({ onLimit }),
        onCaptured: (captured) => this.askAloud(recordedQuestion(captured)),
        onError: (error) => this.setHeard(`not asked: ${recordingErrorWords(error)}`, true),
      });
      this.talk.setUnavailable(microphoneProblem());
      new ResizeObserver(() => this.redraw()).observe($(".plot-canvas", this.root));
    }

    path(suffix = "") {
      return `/v1/sessions/${encodeURIComponent(this.sid)}${suffix}`;
    }

    setText(selector, text, title) {
      const node = $(selector, this.root);
      node.textContent = text;
      if (title !== undefined) node.title = title;
    }

    setError(message) {
      const node = $(".card-error", this.root);
      node.textContent = message || "";
      node.hidden = !message;
    }

    // The session's page for a phone, as a link and a QR code. The token goes in only when
    // this tab holds the session's own (never the API key, which opens every session).
    showPhoneLink() {
      const token = auth.tokens()[this.sid] || "";
      const url = sessionPageUrl(location.origin, this.sid, token);
      if (url === this.phoneUrl) return;
      this.phoneUrl = url;
      $(".phone-qr", this.root).setAttribute("src", qrDataUrl(url));
      $(".phone-link", this.root).setAttribute("href", url);
      this.setText(
        ".phone-token",
        token
          ? "It holds the session's token: show it to your own phone only."
          : "No token in it: the phone asks for one where the server needs it.",
      );
    }

    async refresh() {
      this.showPhoneLink(); // a token added or forgotten since
      let stats;
      try {
        stats = await api(this.path(), auth.forSession(this.sid));
      } catch (err) {
        this.setError(err.message);
        // Never loaded: nothing to show but the error. Loaded before: keep the last values.
        this.root.classList.toggle("unavailable", !this.loaded);
        return err;
      }
      this.loaded = true;
      this.root.classList.remove("unavailable");
      this.setError("");
      this.createdAt = stats.created_at;
      this.setText(".session-name", stats.name || "(unnamed)");
      this.setText(".session-mode", stats.mode);
      this.setText(".session-age", formatAge(stats.created_at));
      this.setText(".stat-objects", String(stats.objects));
      this.setText(".stat-frames", `${stats.frames} · ${stats.keyframes}`, `${stats.dropped_frames} keyframes superseded before mapping`);
      // The frames walked, apart: received whole, and as sightings (a server before it: "–").
      this.setText(".stat-apart", stats.sightings == null ? "–" : `${stats.frames_whole} · ${stats.sightings}`, "frames received whole · as sightings (between keyframes, with the sightings extension)");
      this.setText(".stat-fps", stats.fps.toFixed(1));
      const latency = stats.mapping_latency_ms || {};
      this.setText(".stat-latency", formatMs(latency.p50));
      this.setText(".stat-latency-p95", latency.p95 == null ? "" : `p95 ${formatMs(latency.p95)}`);
      this.setText(".stat-up", formatBytes((stats.bytes_in || {}).total), bytesBreakdown(stats.bytes_in));
      this.setText(".stat-down", formatBytes((stats.bytes_out || {}).total), bytesBreakdown(stats.bytes_out));
      this.setText(".stat-subscribers", String(stats.subscribers));
      if (stats.update_seq !== this.objectsSeq) await this.refreshObjects(stats.update_seq);
      await this.refreshChanges();
      return null;
    }

    // The changes timeline, newest first; every poll, since "ago" counts from the session's
    // newest frame time (now_t), which moves with every frame.
    async refreshChanges() {
      const panel = $(".changes", this.root);
      const meta = $(".changes-meta", this.root);
      let answer;
      try {
        answer = await api(this.path(`/changes?limit=${CHANGES_SHOWN}`), auth.forSession(this.sid));
      } catch (err) {
        // A server without the living map has no such call: no panel. Other errors show there.
        panel.hidden = err.status === 404;
        meta.classList.add("error");
        meta.textContent = `changes: ${err.message}`;
        return;
      }
      const changes = Array.isArray(answer && answer.changes) ? answer.changes : [];
      const items = [...changes].reverse().map((change) => {
        const li = document.createElement("li");
        li.dataset.kind = String(change.kind);
        li.textContent = changeWords(change, answer.now_t); // user data: text only
        if (isTime(change.t)) li.title = `t = ${change.t} s (device clock) · object ${change.id}`;
        return li;
      });
      $(".changes-list", this.root).replaceChildren(...items);
      meta.classList.remove("error");
      meta.textContent = items.length ? "" : "none yet";
      panel.hidden = false;
    }

    async refreshObjects(seq) {
      try {
        this.objects = await api(this.path("/objects?points=false"), auth.forSession(this.sid));
        this.objectsSeq = seq;
      } catch (err) {
        this.setError(`objects: ${err.message}`);
        return;
      }
      this.redraw();
    }

    async query(text) {
      if (!text) return;
      this.setHeard("");
      const params = new URLSearchParams({ text });
      await this.ask(params, () => api(this.path(`/query?${params}`), auth.forSession(this.sid)));
    }

    // A recorded question: the server recognises it and answers what it heard, which is
    // shown ("heard …") and put in the query box, where it can be corrected and asked again.
    async askAloud(audio) {
      this.setHeard("recognising on the server…");
      const params = new URLSearchParams();
      const call = () => api(this.path(`/query/speech?${params}`), auth.forSession(this.sid), { method: "POST", body: audio });
      const answer = await this.ask(params, call);
      if (!answer) {
        this.setHeard("");
        return;
      }
      this.setHeard(heardWords(answer, "server"));
      $(".query-input", this.root).value = answer.transcript;
    }

    setHeard(text, error = false) {
      const node = $(".query-heard", this.root);
      node.textContent = text;
      node.classList.toggle("error", error);
      node.hidden = !text;
    }

    // Ask the map with `call` (the query's other parameters added to `params`) and show the
    // answer, typed or spoken alike; the answer, or null when it failed (said in the meta line).
    async ask(params, call) {
      const meta = $(".query-meta", this.root);
      const button = $(".query-button", this.root);
      meta.classList.remove("error");
      meta.textContent = "asking…";
      button.disabled = true;
      params.set("k", String(QUERY_K));
      params.set("points", "false");
      if ($(".query-removed", this.root).checked) params.set("include", "removed");
      let answer = null;
      try {
        answer = await call();
        this.hits = answer.results;
        this.match = Boolean(answer.match);
        this.nowT = answer.now_t;
        this.renderResults();
        const n = answer.results.length;
        const found = `${n} result${n === 1 ? "" : "s"} for “${answer.text}” in ${formatMs(answer.latency_ms)}`;
        // The hits of a query nothing answers are still listed, but said to be weak.
        meta.classList.toggle("no-match", !answer.match);
        meta.textContent = answer.match ? found : `no confident match · ${found}`;
      } catch (err) {
        answer = null;
        this.hits = [];
        this.match = false;
        this.renderResults();
        meta.classList.remove("no-match");
        meta.classList.add("error");
        meta.textContent = err.message;
      } finally {
        button.disabled = false;
      }
      this.redraw();
      return answer;
    }

    renderResults() {
      // The best hit in words, when it is a confident answer ("mug — on the desk").
      const said = $(".query-answer", this.root);
      said.textContent = this.match && this.hits.length ? answerWords(this.hits[0], this.nowT) : "";
      said.hidden = !said.textContent;
      const table = $(".results", this.root);
      const rows = this.hits.map((hit, i) => {
        const tr = document.createElement("tr");
        for (const [value, cls] of [
          [String(i + 1), "num"],
          [String(hit.id), "num"],
          [hit.label, "label"],
          [hit.relevance.toFixed(2), "num relevance"],
          [hit.score.toFixed(3), "num"],
          [hitWhereWhen(hit, this.nowT), "seen"],
        ]) {
          const td = document.createElement("td");
          td.className = cls;
          td.textContent = value;
          tr.append(td);
        }
        // "mug — on the desk", "mug — not on the desk": said of what was asked about (a
        // confident hit, or the answer), not of the desk itself nor of a weak hit
        const about = hit.relevance >= CONFIDENT_RELEVANCE || (i === 0 && this.match);
        const anchor = relationOf(hit) !== null && relationOf(hit).anchors.some((a) => a.id === hit.id);
        const relation = about && !anchor ? hitRelationWords(hit) : "";
        if (relation) {
          const span = document.createElement("span");
          span.className = "relation";
          span.textContent = ` — ${relation}`;
          const label = $("td.label", tr);
          label.append(span);
          label.title = `degree ${relationOf(hit).degree.toFixed(2)}: how much it stands in the relation (0 to 1)`;
        }
        // weak: not what was asked for, or not in the relation asked about
        const outOfRelation = relationOf(hit) !== null && relationOf(hit).degree < CONFIDENT_DEGREE;
        tr.classList.toggle("weak", hit.relevance < CONFIDENT_RELEVANCE || outOfRelation);
        tr.classList.toggle("removed", hit.state === "removed");
        return tr;
      });
      $("tbody", table).replaceChildren(...rows);
      table.hidden = rows.length === 0;
    }

    // A relational answer as the plot draws it: the target (the best hit, when the answer is a
    // confident match) and its anchors, from the objects held (else from the hits); null for a
    // plain answer.
    plotRelation() {
      const relation = relationOf(this.hits[0]);
      if (!relation) return null;
      const known = new Map([...this.hits, ...this.objects].map((o) => [o.id, o]));
      const anchors = relation.anchors.map((a) => known.get(a.id)).filter((o) => o && Array.isArray(o.bbox));
      return { target: this.match ? this.hits[0].id : null, anchors };
    }

    redraw() {
      const plot = [$(".plot-canvas", this.root), $(".plot-labels", this.root)];
      drawPlot(...plot, this.objects, this.hits, this.plotRelation());
    }
  }

  // --- the page --------------------------------------------------------------------------

  const cards = new Map(); // session id -> SessionCard

  function setStatus(state, text) {
    const status = $("#status");
    status.dataset.state = state;
    status.textContent = text;
  }

  // Cards newest first; nodes are only moved when the order changes, so a query being typed
  // keeps its focus.
  function placeCards(ids) {
    const container = $("#sessions");
    const wanted = [...ids].map((sid) => cards.get(sid)).sort((a, b) => b.createdAt - a.createdAt);
    const current = [...container.children];
    if (wanted.length === current.length && wanted.every((card, i) => card.root === current[i])) return;
    for (const card of wanted) container.append(card.root);
  }

  let lastIds = new Set();

  async function poll() {
    let listed = null;
    let listError = null;
    try {
      listed = await api("/v1/sessions", auth.apiKey());
    } catch (err) {
      listError = err;
    }
    const ids = new Set(Object.keys(auth.tokens()));
    if (listed) for (const s of listed) ids.add(s.session_id);
    // Unreachable is transient: keep what is shown. A refused list (401/403) is not.
    else if (listError.status === 0) for (const sid of lastIds) ids.add(sid);

    for (const [sid, card] of cards) {
      if (!ids.has(sid)) {
        card.root.remove();
        cards.delete(sid);
      }
    }
    for (const sid of ids) if (!cards.has(sid)) cards.set(sid, new SessionCard(sid));
    await Promise.all([...ids].map((sid) => cards.get(sid).refresh()));
    placeCards(ids);
    lastIds = ids;

    if (listError) {
      const help =
        listError.status === 401 || listError.status === 403
          ? " — enter the API key under Access, or add a session with its token."
          : "";
      showBanner(`Listing sessions failed: ${listError.message}${help}`);
      if (listError.status === 401 || listError.status === 403) $("#access").open = true;
      setStatus("error", listError.status === 0 ? "server unreachable, retrying" : "sessions not listed");
    } else {
      showBanner("");
      const time = new Date().toLocaleTimeString();
      setStatus("live", `live · ${ids.size} session${ids.size === 1 ? "" : "s"} · ${time}`);
    }
    $("#empty").hidden = !(listed && ids.size === 0);
  }

  // Self-scheduling (not setInterval): a slow server never gets overlapping polls.
  async function pollForever() {
    try {
      await poll();
    } catch (err) {
      setStatus("error", `dashboard error: ${err.message}`);
      console.error(err);
    }
    setTimeout(pollForever, POLL_MS);
  }

  function renderTokenList() {
    const items = Object.keys(auth.tokens()).map((sid) => {
      const li = document.createElement("li");
      const code = document.createElement("code");
      code.textContent = sid;
      const forget = document.createElement("button");
      forget.type = "button";
      forget.className = "quiet";
      forget.textContent = "forget token";
      forget.addEventListener("click", () => {
        auth.setToken(sid, null);
        renderTokenList();
        poll();
      });
      li.append(code, " ", forget);
      return li;
    });
    $("#token-list").replaceChildren(...items);
  }

  function wireAccessForms() {
    const keyInput = $("#api-key");
    keyInput.value = auth.apiKey();
    $("#key-form").addEventListener("submit", (event) => {
      event.preventDefault();
      auth.setApiKey(keyInput.value.trim());
      poll();
    });
    $("#key-forget").addEventListener("click", () => {
      keyInput.value = "";
      auth.setApiKey("");
      poll();
    });
    $("#token-form").addEventListener("submit", (event) => {
      event.preventDefault();
      const sid = $("#token-sid").value.trim();
      const token = $("#token-value").value.trim();
      if (!sid || !token) return;
      auth.setToken(sid, token);
      $("#token-sid").value = "";
      $("#token-value").value = "";
      renderTokenList();
      poll();
    });
    renderTokenList();
  }

  async function showVersion() {
    try {
      const health = await api("/healthz");
      $("#version").textContent = `SemanticXR ${health.version}`;
    } catch {
      // the status line already tells when the server is unreachable
    }
  }

  function start() {
    const link = $("#viewer-link");
    link.href = viewerUrl();
    wireAccessForms();
    showVersion();
    pollForever();
  }

  start();
})();
