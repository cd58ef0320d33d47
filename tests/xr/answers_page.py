"""A test-only page for static/xr/updates.mjs, answers.mjs and draw.mjs: served by the test
itself (Playwright `page.route`) at a same-origin path of a live server, under the server's
own Content-Security-Policy, so the modules load exactly as /xr loads them. Its module puts
the three modules on `window.xr` and adds a few helpers that return plain JSON."""

from __future__ import annotations

import base64

import numpy as np

from app.server.routes.pages import SECURITY_HEADERS

PAGE_PATH = "/__test/answers.html"
MODULE_PATH = "/__test/answers_page.mjs"
CANVAS_PX = 200
"""The test canvas is CANVAS_PX x CANVAS_PX."""

PAGE_HTML = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>xr answers test page</title>
<script type="module" src="{MODULE_PATH}"></script></head>
<body><canvas id="gl" width="{CANVAS_PX}" height="{CANVAS_PX}"></canvas></body></html>
"""

PAGE_MODULE = """
import * as updates from "/static/xr/updates.mjs";
import * as answers from "/static/xr/answers.mjs";
import * as draw from "/static/xr/draw.mjs";
import { decode } from "/static/vendor/msgpack-msgpack@3.1.3/dist.esm/index.mjs";
import { auth } from "/static/xr/api.mjs";

const bytes = (b64) => Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
const plain = (value) => JSON.parse(JSON.stringify(value, (key, v) =>
  ArrayBuffer.isView(v) ? Array.from(v) : v));

// An answer as JSON (typed arrays as lists); `error`: the name, status and message thrown.
async function asked(text, options) {
  try {
    const answer = await answers.ask(text, { ...options, follower: window.follower });
    return { ...plain(answer), words: answers.answerWords(answer) };
  } catch (err) {
    return { error: { name: err.name, status: err.status ?? null, message: err.message } };
  }
}

window.xr = {
  updates, answers, draw, auth, decode, bytes, plain, asked,
  log: { deltas: [], states: [] },

  follow(sid, token) {
    if (token) auth.setToken(sid, token);
    window.follower = new updates.MapFollower({
      sid,
      retryFirstMs: 200,
      retryMaxMs: 1000,
      onChange: (s) => window.xr.log.deltas.push(
        { seq: s.seq, full: s.full, added: s.added, updated: s.updated, removed: s.removed }),
      onState: (s) => window.xr.log.states.push(s.state),
    });
    window.follower.start();
  },

  held() {
    return [...window.follower.objects.values()]
      .sort((a, b) => a.id - b.id)
      .map((o) => plain({ ...o, embedding: o.embedding.length }));
  },

  // Apply base64 msgpack deltas one by one to a fresh map: each step's held objects, or the
  // error that refused it (the map as it was).
  applyAll(messages) {
    const objects = new Map();
    let lastSeq = null;
    return messages.map((b64) => {
      try {
        const dim = objects.size ? objects.values().next().value.embedding.length : null;
        const summary = updates.applyDelta(objects, updates.parseDelta(decode(bytes(b64)), dim), lastSeq);
        lastSeq = summary.seq;
        return { summary: plain(summary), held: plain([...objects.values()].sort((a, b) => a.id - b.id)) };
      } catch (err) {
        return { error: { name: err.name, field: err.field, message: err.message },
                 held: plain([...objects.values()].sort((a, b) => a.id - b.id)) };
      }
    });
  },

  // Draw `answer` (JSON; points as lists) on the page's WebGL2 canvas with the given camera
  // and read it back: base64 RGBA, bottom row first (readPixels order).
  render(answer, projection, view, objects = [], viaFollower = false) {
    const canvas = document.getElementById("gl");
    const gl = canvas.getContext("webgl2", { antialias: false, premultipliedAlpha: true, preserveDrawingBuffer: true });
    const typed = (hit) => ({ ...hit, points: hit.points ? Float32Array.from(hit.points) : null });
    const held = new Map(objects.map((o) => [o.id, typed(o)]));
    const renderer = new draw.AnswerRenderer(gl, { up: "+y" });
    // main.mjs hands the renderer its MapFollower; a Map of objects does as well
    const given = viaFollower ? { objects: held } : held;
    renderer.setAnswer(answer && { ...answer, results: answer.results.map(typed) }, given);
    gl.viewport(0, 0, canvas.width, canvas.height);
    gl.clearColor(0, 0, 0, 0);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    renderer.draw(new Float32Array(projection), new Float32Array(view));
    const pixels = new Uint8Array(canvas.width * canvas.height * 4);
    gl.readPixels(0, 0, canvas.width, canvas.height, gl.RGBA, gl.UNSIGNED_BYTE, pixels);
    const error = gl.getError();
    const label = renderer.label && renderer.label.text;
    renderer.dispose();
    let text = "";
    for (let i = 0; i < pixels.length; i += 8192) text += String.fromCharCode(...pixels.subarray(i, i + 8192));
    return { pixels: btoa(text), glError: error, label };
  },
};
document.documentElement.dataset.ready = "yes";
"""


def open_answers_page(page, server_url: str) -> None:
    """Load the test page from `server_url`'s origin (its two files answered by the test with
    the server's security headers; everything else from the server)."""
    headers = {k: v for k, v in SECURITY_HEADERS.items() if k != "Cache-Control"}
    page.route(
        f"{server_url}{PAGE_PATH}",
        lambda route: route.fulfill(
            body=PAGE_HTML, content_type="text/html; charset=utf-8", headers=headers
        ),
    )
    page.route(
        f"{server_url}{MODULE_PATH}",
        lambda route: route.fulfill(
            body=PAGE_MODULE, content_type="text/javascript; charset=utf-8", headers=headers
        ),
    )
    page.goto(f"{server_url}{PAGE_PATH}")
    page.wait_for_function("() => document.documentElement.dataset.ready === 'yes'")


def image_of(rendered: dict) -> np.ndarray:
    """uint8 [H, W, 4] premultiplied RGBA, top row first, of `render`'s read-back."""
    flat = np.frombuffer(base64.b64decode(rendered["pixels"]), np.uint8)
    return flat.reshape(CANVAS_PX, CANVAS_PX, 4)[::-1]


# --- a known camera ---------------------------------------------------------------------------


def perspective(fov_y_deg: float = 90.0, near: float = 0.1, far: float = 100.0) -> np.ndarray:
    """OpenGL's perspective projection (square viewport), float64 [4, 4], row-major."""
    f = 1.0 / np.tan(np.radians(fov_y_deg) / 2)
    return np.array(
        [
            [f, 0, 0, 0],
            [0, f, 0, 0],
            [0, 0, (far + near) / (near - far), 2 * far * near / (near - far)],
            [0, 0, -1, 0],
        ]
    )


def look_from(eye) -> np.ndarray:
    """The view matrix (world -> eye) of a camera at `eye` looking down -z, y up, row-major."""
    view = np.eye(4)
    view[:3, 3] = -np.asarray(eye, float)
    return view


def column_major(matrix: np.ndarray) -> list[float]:
    """As WebXR gives matrices: Float32Array(16), column after column."""
    return np.asarray(matrix, float).flatten(order="F").tolist()


def pixel_of(point, projection, view) -> tuple[float, float]:
    """Where a world point lands: (column, row) in pixels, row 0 at the top."""
    clip = projection @ view @ np.array([*point, 1.0])
    ndc = clip[:3] / clip[3]
    return (ndc[0] + 1) / 2 * CANVAS_PX, (1 - ndc[1]) / 2 * CANVAS_PX


def near_face_rect(bbox, projection, view) -> tuple[int, int, int, int]:
    """(left, top, right, bottom) pixels of a box's face nearest a camera looking down -z
    (its largest outline from straight ahead)."""
    x0, y0, _, x1, y1, z1 = bbox
    left, top = pixel_of((x0, y1, z1), projection, view)
    right, bottom = pixel_of((x1, y0, z1), projection, view)
    return round(left), round(top), round(right), round(bottom)
