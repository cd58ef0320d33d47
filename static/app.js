// The session dashboard: lists the server's sessions with live stats, asks queries, plots
// objects top-down. Plain browser JavaScript, no build step, no dependencies.
//
// Safety rule for this file: text from the server (session names, object labels, error
// details) is user data. It only ever reaches the page through textContent, attributes set
// with setAttribute on fixed names, or canvas fillText; never through innerHTML.
"use strict";

(() => {
  const POLL_MS = 2000; // the list and stats refresh period (the brief's "about 2 s")
  const QUERY_K = 5;
  const CHANGES_SHOWN = 20; // the newest changes the timeline lists
  const CONFIDENT_RELEVANCE = 0.5; // app.mapping.relevance.CONFIDENT: a confident match from here
  const STORE_API_KEY = "semanticxr.apiKey";
  const STORE_TOKENS = "semanticxr.tokens"; // {session id: token}

  const $ = (selector, root = document) => root.querySelector(selector);

  // --- HTTP -----------------------------------------------------------------------------

  class HttpError extends Error {
    constructor(status, detail) {
      super(status ? `HTTP ${status}: ${detail}` : `server unreachable: ${detail}`);
      this.status = status;
    }
  }

  // Every error answer is {"detail": "<what is wrong>"} (422s included).
  function formatDetail(body, fallback) {
    const detail = body && typeof body === "object" ? body.detail : undefined;
    if (typeof detail === "string") return detail;
    return fallback || "no detail";
  }

  async function api(path, credential) {
    const headers = { Accept: "application/json" };
    if (credential) headers.Authorization = `Bearer ${credential}`;
    let response;
    try {
      response = await fetch(path, { headers, cache: "no-store" });
    } catch (err) {
      throw new HttpError(0, err.message || "network error");
    }
    let body = null;
    try {
      body = await response.json();
    } catch {
      body = null; // an error page that is not JSON: the status text says enough
    }
    if (!response.ok) throw new HttpError(response.status, formatDetail(body, response.statusText));
    return body;
  }

  // --- credentials (this tab only) -------------------------------------------------------

  const auth = {
    apiKey() {
      return sessionStorage.getItem(STORE_API_KEY) || "";
    },
    setApiKey(key) {
      if (key) sessionStorage.setItem(STORE_API_KEY, key);
      else sessionStorage.removeItem(STORE_API_KEY);
    },
    tokens() {
      try {
        const parsed = JSON.parse(sessionStorage.getItem(STORE_TOKENS) || "{}");
        return parsed && typeof parsed === "object" && !Array.isArray(parsed) ? parsed : {};
      } catch {
        return {};
      }
    },
    setToken(sid, token) {
      const tokens = auth.tokens();
      if (token) tokens[sid] = token;
      else delete tokens[sid];
      sessionStorage.setItem(STORE_TOKENS, JSON.stringify(tokens));
    },
    // A session's own token wins; the API key is accepted for every session too.
    forSession(sid) {
      return auth.tokens()[sid] || auth.apiKey();
    },
  };

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

  // How long ago, from seconds of the device clock: "just now", "40 s ago", "10 min ago".
  function agoWords(seconds) {
    const s = Math.max(0, seconds);
    if (s < 5) return "just now";
    if (s < 90) return `${Math.round(s)} s ago`;
    if (s < 5400) return `${Math.round(s / 60)} min ago`;
    if (s < 172800) return `${Math.round(s / 3600)} h ago`;
    return `${Math.round(s / 86400)} days ago`;
  }

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
  // strong as its relevance (a weak hit is a faint outline, a confident one a bold box).
  function drawPlot(canvas, labelLayer, objects, hits) {
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
      surface: cssColor("--surface"),
    };
    ctx.font = "12px system-ui, sans-serif";

    const all = [...objects, ...hits];
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
    for (const o of objects) {
      if (hitIds.has(o.id)) continue;
      ctx.strokeStyle = colors.object;
      ctx.globalAlpha = 0.55;
      ctx.strokeRect(sx(o.bbox[0]), sy(o.bbox[4]), (o.bbox[3] - o.bbox[0]) * scale, (o.bbox[4] - o.bbox[1]) * scale);
      ctx.globalAlpha = 1;
      ctx.fillStyle = colors.object;
      ctx.beginPath();
      ctx.arc(sx(o.centroid[0]), sy(o.centroid[1]), 2.5, 0, 2 * Math.PI);
      ctx.fill();
    }
    // Hits last, best last, so the best match is never hidden under a worse one.
    [...hits].reverse().forEach((h, reversedIndex) => {
      const rank = hits.length - reversedIndex;
      const [left, top] = [sx(h.bbox[0]), sy(h.bbox[4])];
      const [w, hgt] = [(h.bbox[3] - h.bbox[0]) * scale, (h.bbox[4] - h.bbox[1]) * scale];
      const relevance = Math.min(Math.max(h.relevance ?? 1, 0), 1);
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

    // The hits' labels, best first, where they overlap no other label.
    const scaleBar = { left: 0, top: heightPx - 20, right: marginPx + scale + 40, bottom: heightPx };
    const boxes = placeLabels(ctx, hits.map((h, i) => ({
      text: `${i + 1} ${h.label}`,
      short: `${i + 1}`,
      x: sx(h.centroid[0]),
      y: sy(h.centroid[1]),
    })), widthPx, heightPx, [scaleBar]);
    labelLayer.replaceChildren(...boxes.map((b) => {
      const span = document.createElement("span");
      span.className = "plot-label";
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
  // placed boxes {text, left, top, right, bottom} in CSS pixels of the plot.
  function placeLabels(ctx, labels, widthPx, heightPx, obstacles = []) {
    const placed = [];
    const h = LABEL_HEIGHT_PX;
    for (const label of labels) {
      for (const text of [label.text, label.short]) {
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
          .map(([left, top]) => ({ text, left: Math.round(left), top: Math.round(top) }))
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
      this.nowT = null; // the query answer's now_t: what its hits' "last seen" counts from
      this.objectsSeq = null; // update_seq the plotted objects are from
      this.createdAt = 0;
      this.loaded = false; // stats arrived at least once
      $(".query-form", this.root).addEventListener("submit", (event) => {
        event.preventDefault();
        this.query($(".query-input", this.root).value.trim());
      });
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

    async refresh() {
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
      const meta = $(".query-meta", this.root);
      const button = $(".query-button", this.root);
      meta.classList.remove("error");
      meta.textContent = "asking…";
      button.disabled = true;
      const params = new URLSearchParams({ text, k: String(QUERY_K), points: "false" });
      if ($(".query-removed", this.root).checked) params.set("include", "removed");
      try {
        const answer = await api(this.path(`/query?${params}`), auth.forSession(this.sid));
        this.hits = answer.results;
        this.nowT = answer.now_t;
        this.renderResults();
        const n = answer.results.length;
        const found = `${n} result${n === 1 ? "" : "s"} for “${answer.text}” in ${formatMs(answer.latency_ms)}`;
        // The hits of a query nothing answers are still listed, but said to be weak.
        meta.classList.toggle("no-match", !answer.match);
        meta.textContent = answer.match ? found : `no confident match · ${found}`;
      } catch (err) {
        this.hits = [];
        this.renderResults();
        meta.classList.remove("no-match");
        meta.classList.add("error");
        meta.textContent = err.message;
      } finally {
        button.disabled = false;
      }
      this.redraw();
    }

    renderResults() {
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
        tr.classList.toggle("weak", hit.relevance < CONFIDENT_RELEVANCE);
        tr.classList.toggle("removed", hit.state === "removed");
        return tr;
      });
      $("tbody", table).replaceChildren(...rows);
      table.hidden = rows.length === 0;
    }

    redraw() {
      drawPlot($(".plot-canvas", this.root), $(".plot-labels", this.root), this.objects, this.hits);
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
