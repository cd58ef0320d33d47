// Drawing an answer in the room: WebGL2 over the camera image of an `immersive-ar` session.
//
// For each hit of a matching answer (`shownHits`): its box (12 edges) and its points, the
// best hit orange (viewer/scene.py TARGET_RGB), the other confident ones a dimmer orange; a
// relational answer's anchors teal (ANCHOR_RGB) with a line from the best hit's centre to
// each anchor's; the best hit's label ("mug (0.93)", "mug — on the desk (0.93)") on a quad
// facing the viewer above its box. Nothing for `match: false`: the page says "no match" in
// its DOM overlay, and a weak guess is never drawn as if it were an answer.
//
// Depth test off: the layer holds no depth of the real room (the camera image is composited
// under it by the user agent), so a depth test would only sort our own lines, and the thing
// asked for must show through whatever stands in front of it (the mug in the cupboard). What
// overlaps is ordered by drawing: the dimmer hits, the anchors, the relation lines, the best
// hit, its label last. Colours are premultiplied by alpha (an XRWebGLLayer's framebuffer, like
// a default WebGL canvas, is composited as premultiplied), blended ONE, ONE_MINUS_SRC_ALPHA;
// where nothing is drawn the layer keeps the caller's clear (alpha 0: the camera shows).
//
// Lines are quads of a width in pixels (WebGL's own lines are one pixel wide on most GPUs),
// expanded in the vertex shader and clipped at the near plane first; sizes follow the
// viewport's height, so a phone's dense framebuffer gets lines as visible as a small one's.
// Buffers and the label's texture are made once per answer (`setAnswer`); `draw` only sets
// uniforms and issues three draw calls.

import { hitWords, shownHits } from "./answers.mjs";

/** Colours, RGBA in [0, 1] (not premultiplied). */
export const BEST_RGBA = Object.freeze([235 / 255, 80 / 255, 0, 1]);
export const OTHER_HIT_RGBA = Object.freeze([235 / 255, 80 / 255, 0, 0.45]);
export const ANCHOR_RGBA = Object.freeze([0, 150 / 255, 136 / 255, 1]);

// Sizes in pixels of a viewport 1000 pixels high (scaled with the viewport's height, at least 2 px).
const BEST_LINE_PX = 6;
const OTHER_LINE_PX = 4;
const ANCHOR_LINE_PX = 5;
const RELATION_LINE_PX = 4;
const BEST_POINT_PX = 7;
const OTHER_POINT_PX = 5;
const LABEL_HEIGHT = 0.05; // of the viewport's height
const LABEL_GAP_PX = 10; // between the box's top and the label (at 1000 px)
const LABEL_MAX_CHARS = 60;

// The 12 edges of a box as pairs of corner indices; corner k has x = bit 0, y = bit 1, z = bit 2
// (viewer/scene.py _BOX_EDGES).
const BOX_EDGES = [[0, 1], [2, 3], [4, 5], [6, 7], [0, 2], [1, 3], [4, 6], [5, 7], [0, 4], [1, 5], [2, 6], [3, 7]];

/** The 12 edges of an axis-aligned box [x0, y0, z0, x1, y1, z1]: Float32Array(72), 12 x (start, end). */
export function boxSegments(bbox) {
  const corner = (k) => [0, 1, 2].map((axis) => bbox[(k >> axis) & 1 ? axis + 3 : axis]);
  return Float32Array.from(BOX_EDGES.flatMap(([a, b]) => [...corner(a), ...corner(b)]));
}

/** The centre of a box [x0, y0, z0, x1, y1, z1]. */
export function boxCentre(bbox) {
  return [0, 1, 2].map((i) => (bbox[i] + bbox[i + 3]) / 2);
}

/** Where a box's label stands: its centre lifted to its top along `up` ("+y", "-z", ...). */
export function labelAnchor(bbox, up = "+y") {
  const axis = { x: 0, y: 1, z: 2 }[up[1]];
  const point = boxCentre(bbox);
  point[axis] = up[0] === "+" ? bbox[axis + 3] : bbox[axis];
  return point;
}

// --- shaders ---------------------------------------------------------------------------------

const SEGMENT_VS = `#version 300 es
layout(location = 0) in vec2 a_corner;  // (0 at the start .. 1 at the end, -1 .. 1 across)
layout(location = 1) in vec3 a_start;
layout(location = 2) in vec3 a_end;
layout(location = 3) in vec4 a_start_rgba;
layout(location = 4) in vec4 a_end_rgba;
layout(location = 5) in float a_width;  // pixels at a 1000-pixel-high viewport
uniform mat4 u_projection;
uniform mat4 u_view;
uniform vec2 u_viewport;  // pixels
out vec4 v_rgba;
void main() {
  vec4 a = u_projection * u_view * vec4(a_start, 1.0);
  vec4 b = u_projection * u_view * vec4(a_end, 1.0);
  float da = a.z + a.w;  // >= 0 on the near plane's visible side
  float db = b.z + b.w;
  if (da < 0.0 && db < 0.0) {  // wholly behind the near plane
    gl_Position = vec4(0.0, 0.0, 2.0, 1.0);
    return;
  }
  if (da < 0.0) a = mix(a, b, da / (da - db));
  if (db < 0.0) b = mix(b, a, db / (db - da));
  vec2 half_viewport = 0.5 * u_viewport;
  vec2 along = b.xy / b.w * half_viewport - a.xy / a.w * half_viewport;
  along = length(along) > 1e-4 ? normalize(along) : vec2(1.0, 0.0);
  vec2 across = vec2(-along.y, along.x);
  float half_width = 0.5 * max(2.0, a_width * u_viewport.y / 1000.0);
  vec4 p = mix(a, b, a_corner.x);
  // across by half the width, and past each end by as much so that box corners close
  vec2 offset_px = (across * a_corner.y + along * (2.0 * a_corner.x - 1.0)) * half_width;
  p.xy += offset_px / half_viewport * p.w;
  gl_Position = p;
  v_rgba = mix(a_start_rgba, a_end_rgba, a_corner.x);
}`;

const POINT_VS = `#version 300 es
layout(location = 0) in vec3 a_position;
layout(location = 1) in vec4 a_rgba;
layout(location = 2) in float a_size;  // pixels at a 1000-pixel-high viewport
uniform mat4 u_projection;
uniform mat4 u_view;
uniform vec2 u_viewport;
out vec4 v_rgba;
void main() {
  gl_Position = u_projection * u_view * vec4(a_position, 1.0);
  gl_PointSize = max(2.0, a_size * u_viewport.y / 1000.0);
  v_rgba = a_rgba;
}`;

const COLOUR_FS = `#version 300 es
precision mediump float;
in vec4 v_rgba;
out vec4 out_rgba;
void main() {
  out_rgba = vec4(v_rgba.rgb * v_rgba.a, v_rgba.a);  // premultiplied
}`;

const LABEL_VS = `#version 300 es
layout(location = 0) in vec2 a_corner;  // (0..1, 0..1), y up
uniform mat4 u_projection;
uniform mat4 u_view;
uniform vec2 u_viewport;
uniform vec3 u_anchor;  // world metres: the bottom centre of the label
uniform vec2 u_size_px;
uniform float u_gap_px;
out vec2 v_uv;
void main() {
  vec4 p = u_projection * u_view * vec4(u_anchor, 1.0);
  if (p.z + p.w < 0.0) {  // behind the viewer: no label
    gl_Position = vec4(0.0, 0.0, 2.0, 1.0);
    return;
  }
  vec2 offset_px = vec2((a_corner.x - 0.5) * u_size_px.x, a_corner.y * u_size_px.y + u_gap_px);
  p.xy += offset_px / (0.5 * u_viewport) * p.w;
  p.z = 0.0;  // never clipped by depth: it faces the viewer, in front of everything
  gl_Position = p;
  v_uv = vec2(a_corner.x, 1.0 - a_corner.y);  // the canvas's first row is its top
}`;

const LABEL_FS = `#version 300 es
precision mediump float;
uniform sampler2D u_texture;
in vec2 v_uv;
out vec4 out_rgba;
void main() {
  out_rgba = texture(u_texture, v_uv);  // premultiplied on upload
}`;

function compile(gl, vertexSource, fragmentSource) {
  const program = gl.createProgram();
  for (const [type, source] of [[gl.VERTEX_SHADER, vertexSource], [gl.FRAGMENT_SHADER, fragmentSource]]) {
    const shader = gl.createShader(type);
    gl.shaderSource(shader, source);
    gl.compileShader(shader);
    if (!gl.getShaderParameter(shader, gl.COMPILE_STATUS)) {
      throw new Error(`draw.mjs: a shader did not compile: ${gl.getShaderInfoLog(shader)}`);
    }
    gl.attachShader(program, shader);
    gl.deleteShader(shader); // freed with the program
  }
  gl.linkProgram(program);
  if (!gl.getProgramParameter(program, gl.LINK_STATUS)) {
    throw new Error(`draw.mjs: a program did not link: ${gl.getProgramInfoLog(program)}`);
  }
  const uniforms = {};
  for (let i = 0; i < gl.getProgramParameter(program, gl.ACTIVE_UNIFORMS); i += 1) {
    const name = gl.getActiveUniform(program, i).name;
    uniforms[name] = gl.getUniformLocation(program, name);
  }
  return { program, uniforms };
}

// --- what an answer draws (pure) -------------------------------------------------------------

/**
 * The geometry of an answer, in drawing order: {segments: Float32Array (per segment: start
 * [3], end [3], start RGBA [4], end RGBA [4], width [1]), points: Float32Array (per point:
 * position [3], RGBA [4], size [1]), label: {text, anchor [3]} | null}. Empty for no match.
 * objects: Map id -> {bbox, centroid, points} (the follower's) for anchors the answer holds
 * no geometry of, or the MapFollower itself.
 */
export function answerGeometry(answer, objects = null, up = "+y") {
  if (objects && !(objects instanceof Map)) objects = objects.objects ?? null; // a MapFollower
  const hits = shownHits(answer);
  const segments = [];
  const points = [];
  if (hits.length === 0) return { segments: new Float32Array(0), points: new Float32Array(0), label: null };
  const [best, ...others] = hits;
  const addBox = (bbox, rgba, width) => {
    const edges = boxSegments(bbox);
    for (let i = 0; i < edges.length; i += 6) segments.push(...edges.subarray(i, i + 6), ...rgba, ...rgba, width);
  };
  const addPoints = (xyz, rgba, size) => {
    for (let i = 0; xyz && i + 2 < xyz.length; i += 3) points.push(xyz[i], xyz[i + 1], xyz[i + 2], ...rgba, size);
  };
  const held = (id) => (objects ? objects.get(id) : undefined);
  const pointsOf = (hit) => hit.points ?? held(hit.id)?.points ?? null;

  for (const hit of others) {
    addPoints(pointsOf(hit), OTHER_HIT_RGBA, OTHER_POINT_PX);
    addBox(hit.bbox, OTHER_HIT_RGBA, OTHER_LINE_PX);
  }
  const anchors = (best.relation?.anchors || [])
    .filter((anchor) => anchor.id !== best.id)
    .map((anchor) => (anchor.bbox ? anchor : { ...anchor, ...held(anchor.id) }))
    .filter((anchor) => Array.isArray(anchor.bbox)); // the floor (id 0) or an anchor not held yet
  for (const anchor of anchors) {
    addPoints(anchor.points, ANCHOR_RGBA, OTHER_POINT_PX);
    addBox(anchor.bbox, ANCHOR_RGBA, ANCHOR_LINE_PX);
    const from = best.centroid ?? boxCentre(best.bbox);
    const to = anchor.centroid ?? boxCentre(anchor.bbox);
    segments.push(...from, ...to, ...BEST_RGBA, ...ANCHOR_RGBA, RELATION_LINE_PX);
  }
  addPoints(pointsOf(best), BEST_RGBA, BEST_POINT_PX);
  addBox(best.bbox, BEST_RGBA, BEST_LINE_PX);
  const text = hitWords(best, { best: true });
  return {
    segments: Float32Array.from(segments),
    points: Float32Array.from(points),
    label: { text: text.length > LABEL_MAX_CHARS ? `${text.slice(0, LABEL_MAX_CHARS - 1)}…` : text, anchor: labelAnchor(best.bbox, up) },
  };
}

const SEGMENT_FLOATS = 15;
const POINT_FLOATS = 8;

// The label's picture: white text on a dark plate edged in the best hit's orange.
function labelCanvas(text) {
  const fontPx = 40;
  const pad = 14;
  const font = `600 ${fontPx}px system-ui, sans-serif`;
  const make = (w, h) => (typeof OffscreenCanvas === "function" ? new OffscreenCanvas(w, h) : Object.assign(document.createElement("canvas"), { width: w, height: h }));
  const measure = make(1, 1).getContext("2d");
  measure.font = font;
  const width = Math.ceil(measure.measureText(text).width) + 2 * pad;
  const height = Math.round(fontPx * 1.25) + 2 * pad;
  const canvas = make(width, height);
  const ctx = canvas.getContext("2d");
  ctx.fillStyle = "rgba(16, 16, 16, 0.82)";
  ctx.strokeStyle = `rgb(${BEST_RGBA.slice(0, 3).map((c) => Math.round(c * 255)).join(", ")})`;
  ctx.lineWidth = 4;
  ctx.beginPath();
  if (ctx.roundRect) ctx.roundRect(2, 2, width - 4, height - 4, 12);
  else ctx.rect(2, 2, width - 4, height - 4);
  ctx.fill();
  ctx.stroke();
  ctx.font = font;
  ctx.fillStyle = "#ffffff";
  ctx.textBaseline = "middle";
  ctx.fillText(text, pad, height / 2);
  return canvas;
}

// --- the renderer ----------------------------------------------------------------------------

/**
 * Draws one answer at a time in an XR-compatible WebGL2 context.
 *
 *   const renderer = new AnswerRenderer(gl, {up: "+y"});
 *   renderer.setAnswer(answer, follower.objects);   // when an answer arrives (or null)
 *   renderer.draw(view.projectionMatrix, view.transform.inverse.matrix);  // per view, per frame
 *   renderer.dispose();
 *
 * The map's world frame must be the reference space the views are taken in (the frame the
 * page streams its poses in). `up` names that frame's up axis as the protocol does ("+y" for
 * XR reference spaces): the label stands on the box's top along it.
 */
export class AnswerRenderer {
  constructor(gl, { up = "+y" } = {}) {
    this.gl = gl;
    this.up = up;
    this.segmentProgram = compile(gl, SEGMENT_VS, COLOUR_FS);
    this.pointProgram = compile(gl, POINT_VS, COLOUR_FS);
    this.labelProgram = compile(gl, LABEL_VS, LABEL_FS);

    // one quad's corners: for the segments (along, across) and the label (x, y)
    this.segmentCorners = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, this.segmentCorners);
    gl.bufferData(gl.ARRAY_BUFFER, new Float32Array([0, -1, 1, -1, 1, 1, 0, -1, 1, 1, 0, 1]), gl.STATIC_DRAW);
    this.labelCorners = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, this.labelCorners);
    gl.bufferData(gl.ARRAY_BUFFER, new Float32Array([0, 0, 1, 0, 1, 1, 0, 0, 1, 1, 0, 1]), gl.STATIC_DRAW);

    this.segmentBuffer = gl.createBuffer();
    this.segmentVao = gl.createVertexArray();
    gl.bindVertexArray(this.segmentVao);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.segmentCorners);
    gl.enableVertexAttribArray(0);
    gl.vertexAttribPointer(0, 2, gl.FLOAT, false, 0, 0);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.segmentBuffer);
    const segmentStride = SEGMENT_FLOATS * 4;
    for (const [location, size, offset] of [[1, 3, 0], [2, 3, 3], [3, 4, 6], [4, 4, 10], [5, 1, 14]]) {
      gl.enableVertexAttribArray(location);
      gl.vertexAttribPointer(location, size, gl.FLOAT, false, segmentStride, offset * 4);
      gl.vertexAttribDivisor(location, 1); // one segment per instance
    }

    this.pointBuffer = gl.createBuffer();
    this.pointVao = gl.createVertexArray();
    gl.bindVertexArray(this.pointVao);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.pointBuffer);
    const pointStride = POINT_FLOATS * 4;
    for (const [location, size, offset] of [[0, 3, 0], [1, 4, 3], [2, 1, 7]]) {
      gl.enableVertexAttribArray(location);
      gl.vertexAttribPointer(location, size, gl.FLOAT, false, pointStride, offset * 4);
    }

    this.labelVao = gl.createVertexArray();
    gl.bindVertexArray(this.labelVao);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.labelCorners);
    gl.enableVertexAttribArray(0);
    gl.vertexAttribPointer(0, 2, gl.FLOAT, false, 0, 0);
    gl.bindVertexArray(null);
    gl.bindBuffer(gl.ARRAY_BUFFER, null);

    this.labelTexture = gl.createTexture();
    this.segmentCount = 0;
    this.pointCount = 0;
    this.label = null; // {anchor, aspect}
  }

  /**
   * Show `answer` (as `ask` resolves it; null shows nothing). objects: the MapFollower (or
   * its `objects`), for anchors the answer holds no geometry of. Call it again when the
   * follower changes to draw an anchor that arrived since; the label's texture is remade
   * only when its text changes.
   */
  setAnswer(answer, objects = null) {
    const gl = this.gl;
    const geometry = answer ? answerGeometry(answer, objects, this.up) : answerGeometry(null);
    this.segmentCount = geometry.segments.length / SEGMENT_FLOATS;
    this.pointCount = geometry.points.length / POINT_FLOATS;
    gl.bindBuffer(gl.ARRAY_BUFFER, this.segmentBuffer);
    gl.bufferData(gl.ARRAY_BUFFER, geometry.segments, gl.STATIC_DRAW);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.pointBuffer);
    gl.bufferData(gl.ARRAY_BUFFER, geometry.points, gl.STATIC_DRAW);
    gl.bindBuffer(gl.ARRAY_BUFFER, null);
    const text = geometry.label && geometry.label.text;
    if (text && this.label && this.label.text === text) {
      this.label = { ...this.label, anchor: geometry.label.anchor };
    } else if (!text) {
      this.label = null;
    } else {
      const canvas = labelCanvas(text);
      gl.bindTexture(gl.TEXTURE_2D, this.labelTexture);
      const premultiply = gl.getParameter(gl.UNPACK_PREMULTIPLY_ALPHA_WEBGL);
      const flip = gl.getParameter(gl.UNPACK_FLIP_Y_WEBGL);
      gl.pixelStorei(gl.UNPACK_PREMULTIPLY_ALPHA_WEBGL, true);
      gl.pixelStorei(gl.UNPACK_FLIP_Y_WEBGL, false);
      gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA, gl.RGBA, gl.UNSIGNED_BYTE, canvas);
      gl.pixelStorei(gl.UNPACK_PREMULTIPLY_ALPHA_WEBGL, premultiply);
      gl.pixelStorei(gl.UNPACK_FLIP_Y_WEBGL, flip);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.LINEAR);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
      gl.bindTexture(gl.TEXTURE_2D, null);
      this.label = { anchor: geometry.label.anchor, text, aspect: canvas.width / canvas.height };
    }
  }

  /** Whether `draw` would draw anything (the answer matched). */
  get drawing() {
    return this.segmentCount > 0 || this.pointCount > 0;
  }

  /**
   * Draw into the bound framebuffer and viewport. projectionMatrix, viewMatrix: Float32Array(16),
   * column-major (an XRView's projectionMatrix and transform.inverse.matrix). Leaves depth
   * test, blending and face culling as it found them; the blend function is left
   * ONE, ONE_MINUS_SRC_ALPHA and no program, vertex array or texture bound.
   */
  draw(projectionMatrix, viewMatrix) {
    if (!this.drawing) return;
    const gl = this.gl;
    const viewport = gl.getParameter(gl.VIEWPORT);
    const size = [viewport[2], viewport[3]];
    const restore = [gl.DEPTH_TEST, gl.BLEND, gl.CULL_FACE].map((cap) => [cap, gl.isEnabled(cap)]);
    gl.disable(gl.DEPTH_TEST);
    gl.disable(gl.CULL_FACE);
    gl.enable(gl.BLEND);
    gl.blendFunc(gl.ONE, gl.ONE_MINUS_SRC_ALPHA);

    const use = ({ program, uniforms }) => {
      gl.useProgram(program);
      gl.uniformMatrix4fv(uniforms.u_projection, false, projectionMatrix);
      gl.uniformMatrix4fv(uniforms.u_view, false, viewMatrix);
      gl.uniform2f(uniforms.u_viewport, size[0], size[1]);
      return uniforms;
    };
    if (this.pointCount) {
      use(this.pointProgram);
      gl.bindVertexArray(this.pointVao);
      gl.drawArrays(gl.POINTS, 0, this.pointCount);
    }
    if (this.segmentCount) {
      use(this.segmentProgram);
      gl.bindVertexArray(this.segmentVao);
      gl.drawArraysInstanced(gl.TRIANGLES, 0, 6, this.segmentCount);
    }
    if (this.label) {
      const uniforms = use(this.labelProgram);
      const heightPx = Math.max(20, LABEL_HEIGHT * size[1]);
      gl.uniform3fv(uniforms.u_anchor, this.label.anchor);
      gl.uniform2f(uniforms.u_size_px, heightPx * this.label.aspect, heightPx);
      gl.uniform1f(uniforms.u_gap_px, Math.max(4, (LABEL_GAP_PX * size[1]) / 1000));
      gl.activeTexture(gl.TEXTURE0);
      gl.bindTexture(gl.TEXTURE_2D, this.labelTexture);
      gl.uniform1i(uniforms.u_texture, 0);
      gl.bindVertexArray(this.labelVao);
      gl.drawArrays(gl.TRIANGLES, 0, 6);
      gl.bindTexture(gl.TEXTURE_2D, null);
    }
    gl.bindVertexArray(null);
    gl.useProgram(null);
    for (const [cap, enabled] of restore) (enabled ? gl.enable : gl.disable).call(gl, cap);
  }

  dispose() {
    const gl = this.gl;
    for (const buffer of [this.segmentCorners, this.labelCorners, this.segmentBuffer, this.pointBuffer]) gl.deleteBuffer(buffer);
    for (const vao of [this.segmentVao, this.pointVao, this.labelVao]) gl.deleteVertexArray(vao);
    for (const { program } of [this.segmentProgram, this.pointProgram, this.labelProgram]) gl.deleteProgram(program);
    gl.deleteTexture(this.labelTexture);
    this.segmentCount = this.pointCount = 0;
    this.label = null;
  }
}
