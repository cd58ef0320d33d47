// Depth onto the protocol's grid: the colour image's size divided by the session's
// `depth_downsampling_ratio`, each depth pixel standing for the centre pixel of its
// ratio x ratio block (app/mapping/geometry.py reads it that way; the Python device's
// "nearest" downsampling keeps that pixel). Pure functions: they run in the encode Worker.

/** RGB pixel of depth pixel index i on a grid of `ratio` (the block's centre pixel). */
export function blockCentre(i, ratio) {
  return i * ratio + Math.floor(ratio / 2);
}

/** Metres per raw value of a CPU depth buffer's data, as a typed array of its format. */
export function rawDepthValues(buffer, format) {
  // WebXR Depth Sensing, "XRDepthDataFormat": luminance-alpha is 2 bytes per value read as
  // one unsigned 16-bit integer, unsigned-short 16-bit, float32 32-bit; times rawValueToMeters.
  if (format === "float32") return new Float32Array(buffer);
  if (format === "luminance-alpha" || format === "unsigned-short") return new Uint16Array(buffer);
  throw new Error(`unknown depth data format ${format}`);
}

/**
 * Resample a CPU depth buffer (WebXR Depth Sensing, XRCPUDepthInformation) onto the grid of
 * a width x height colour image of the same view, divided by `ratio`. `normDepthFromNormView`
 * is the buffer's normDepthBufferFromNormView.matrix (column-major): it takes normalized view
 * coordinates (origin top-left, x right, y down, 0..1 over the view) to normalized depth
 * buffer coordinates, which times the buffer's width and height index it (row-major). Nearest
 * value, never an average (an average across a silhouette invents a surface). Returns
 * Float32Array metres (0 = invalid) of (width / ratio) x (height / ratio).
 */
export function resampleCpuDepth({ values, depthWidth, depthHeight, rawValueToMeters, normDepthFromNormView }, width, height, ratio) {
  const w = Math.floor(width / ratio);
  const h = Math.floor(height / ratio);
  const m = normDepthFromNormView;
  const out = new Float32Array(w * h);
  for (let j = 0; j < h; j++) {
    const y = (blockCentre(j, ratio) + 0.5) / height;
    for (let i = 0; i < w; i++) {
      const x = (blockCentre(i, ratio) + 0.5) / width;
      const dx = m[0] * x + m[4] * y + m[12];
      const dy = m[1] * x + m[5] * y + m[13];
      const col = Math.floor(dx * depthWidth);
      const row = Math.floor(dy * depthHeight);
      if (col < 0 || row < 0 || col >= depthWidth || row >= depthHeight) continue;
      const metres = values[row * depthWidth + col] * rawValueToMeters;
      out[j * w + i] = Number.isFinite(metres) && metres > 0 ? metres : 0;
    }
  }
  return out;
}

/**
 * Reproject metric depth seen from one view (a headset's depth view) into another camera (the
 * colour camera), on the colour image's grid divided by `ratio`.
 *
 * depth: Float32Array metres, depthWidth x depthHeight, row 0 = normalized depth-buffer y 0
 * (every `stride`-th value: a GL readback of RGBA texels has stride 4), or row 0 = the
 * bottom (`bottomUp`: a GL texture's rows, as a headset's GPU depth comes);
 * normDepthFromNormView: the depth information's matrix (column-major); depthProjection and
 * depthTransform: the depth view's projectionMatrix and transform.matrix (column-major,
 * WebXR's camera: -z forward, +y up); camera: the colour camera in the protocol's convention
 * ({pose: row-major OpenCV camera-to-world, intrinsics [fx, fy, cx, cy]}) of a width x height
 * image. Every depth texel becomes a 3D point; each lands in the block of the colour pixel it
 * projects to, and the one nearest the block's centre pixel is kept (ties: the nearer
 * surface), so no depth is invented between surfaces. Returns Float32Array metres.
 */
export function reprojectDepth({ depth, depthWidth, depthHeight, stride = 1, bottomUp = false, normDepthFromNormView, depthProjection, depthTransform }, camera, width, height, ratio) {
  const w = Math.floor(width / ratio);
  const h = Math.floor(height / ratio);
  const out = new Float32Array(w * h);
  const best = new Float32Array(w * h).fill(Infinity); // squared pixel distance to the centre
  const inv = invertAffine2d(normDepthFromNormView);
  const P = depthProjection;
  const T = depthTransform;
  const C = camera.pose;
  const [fx, fy, cx, cy] = camera.intrinsics;
  const half = Math.floor(ratio / 2);
  for (let r = 0; r < depthHeight; r++) {
    for (let c = 0; c < depthWidth; c++) {
      const z = depth[(r * depthWidth + c) * stride];
      if (!(z > 0) || !Number.isFinite(z)) continue;
      const bx = (c + 0.5) / depthWidth;
      const by = bottomUp ? 1 - (r + 0.5) / depthHeight : (r + 0.5) / depthHeight;
      const xn = inv[0] * bx + inv[2] * by + inv[4];
      const yn = inv[1] * bx + inv[3] * by + inv[5];
      const xNdc = 2 * xn - 1;
      const yNdc = 1 - 2 * yn;
      // On the view's -z axis at distance z: X / -Z = (x_ndc + P[8]) / P[0], likewise Y.
      const vx = (z * (xNdc + P[8])) / P[0];
      const vy = (z * (yNdc + P[9])) / P[5];
      const vz = -z;
      const wx = T[0] * vx + T[4] * vy + T[8] * vz + T[12];
      const wy = T[1] * vx + T[5] * vy + T[9] * vz + T[13];
      const wz = T[2] * vx + T[6] * vy + T[10] * vz + T[14];
      const dx = wx - C[3];
      const dy = wy - C[7];
      const dz = wz - C[11];
      const x = C[0] * dx + C[4] * dy + C[8] * dz;
      const y = C[1] * dx + C[5] * dy + C[9] * dz;
      const zc = C[2] * dx + C[6] * dy + C[10] * dz;
      if (!(zc > 0)) continue;
      const u = (fx * x) / zc + cx;
      const v = (fy * y) / zc + cy;
      const i = Math.floor((u + 0.5) / ratio);
      const j = Math.floor((v + 0.5) / ratio);
      if (i < 0 || j < 0 || i >= w || j >= h) continue;
      const du = u - (i * ratio + half);
      const dv = v - (j * ratio + half);
      const d2 = du * du + dv * dv;
      const k = j * w + i;
      if (d2 < best[k] - 1e-9 || (Math.abs(d2 - best[k]) <= 1e-9 && zc < out[k])) {
        best[k] = d2;
        out[k] = zc;
      }
    }
  }
  return out;
}

/** The 2D affine part (x, y) of a column-major 4x4 acting on (x, y, 0, 1), inverted:
 * [a, b, c, d, e, f] with x' = a x + c y + e, y' = b x + d y + f. */
function invertAffine2d(m) {
  const a = m[0], b = m[1], c = m[4], d = m[5], e = m[12], f = m[13];
  const det = a * d - b * c;
  if (Math.abs(det) < 1e-12) throw new Error("normDepthBufferFromNormView is not invertible in x, y");
  const ia = d / det, ib = -b / det, ic = -c / det, id = a / det;
  return [ia, ib, ic, id, -(ia * e + ic * f), -(ib * e + id * f)];
}

/** Metres to the protocol's uint16 depth units of `scaleM` metres (0 stays invalid). */
export function toUint16(metres, scaleM) {
  const out = new Uint16Array(metres.length);
  for (let k = 0; k < metres.length; k++) {
    const units = Math.round(metres[k] / scaleM);
    out[k] = units > 65535 ? 0 : units; // beyond the range: invalid rather than wrong
  }
  return out;
}
