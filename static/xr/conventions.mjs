// The one place where WebXR's conventions meet the wire protocol's.
//
// WebXR (WebXR Device API, "Spaces" and "XRView"): reference spaces are right-handed, metres,
// +y up; a view's `transform` is its pose in the reference space with the view looking down
// its -z axis, +x right and +y up; `projectionMatrix` is an OpenGL-style clip projection;
// matrices are column-major Float32Array(16).
// The protocol (docs/protocol.md): `pose` is camera-to-world, row-major, in an OpenCV camera
// (x right, y down, z forward); `intrinsics` are [fx, fy, cx, cy] in pixels of the RGB image,
// pixel centres at integer coordinates, row 0 at the top.
// So the camera's axes turn by diag(1, -1, -1) and the projection's NDC becomes pixels.

/** Row-major copy of a column-major 4x4 (Float64Array). */
export function rowMajor(columnMajor) {
  const m = columnMajor;
  const out = new Float64Array(16);
  for (let row = 0; row < 4; row++) for (let col = 0; col < 4; col++) out[row * 4 + col] = m[col * 4 + row];
  return out;
}

/**
 * The protocol's camera pose and intrinsics of a WebXR view whose image is width x height.
 *
 * `transform`: the view's `transform.matrix` (column-major, camera-to-reference-space, -z
 * forward); `projection`: its `projectionMatrix`. Returns {pose: Float32Array(16) row-major
 * OpenCV camera-to-world, intrinsics: [fx, fy, cx, cy]}.
 *
 * Intrinsics: a point at OpenCV camera coordinates (x, y, z) reaches NDC
 * x_ndc = P[0] x / z - P[8] and y_ndc = -P[5] y / z - P[9] (P column-major, no skew);
 * NDC -1..1 spans the image's edges, so pixel u = (x_ndc + 1) W / 2 - 1/2 and
 * v = (1 - y_ndc) H / 2 - 1/2 (row 0 at the top, centres at integers).
 */
export function protocolCamera(transform, projection, width, height) {
  return { pose: protocolPose(transform), intrinsics: intrinsicsFromProjection(projection, width, height) };
}

/** The protocol's pose (row-major OpenCV camera-to-world) of a WebXR camera transform. */
export function protocolPose(transform) {
  const T = rowMajor(transform);
  const pose = new Float32Array(16);
  for (let row = 0; row < 4; row++) {
    // Columns 1 and 2 (the camera's y and z axes) flip: OpenCV's y is down, z forward.
    pose[row * 4 + 0] = T[row * 4 + 0];
    pose[row * 4 + 1] = -T[row * 4 + 1];
    pose[row * 4 + 2] = -T[row * 4 + 2];
    pose[row * 4 + 3] = T[row * 4 + 3];
  }
  return pose;
}

/** [fx, fy, cx, cy] of a width x height image under an OpenGL projection (column-major). */
export function intrinsicsFromProjection(P, width, height) {
  return [(width / 2) * P[0], (height / 2) * P[5], (width / 2) * (1 - P[8]) - 0.5, (height / 2) * (1 + P[9]) - 0.5];
}

/** Intrinsics of an image scaled by `s` (pixel centres stay at integer coordinates). */
export function scaleIntrinsics([fx, fy, cx, cy], s) {
  return [fx * s, fy * s, (cx + 0.5) * s - 0.5, (cy + 0.5) * s - 0.5];
}

/** Pixel (u, v) of world point p under a protocol camera ({pose, intrinsics}), and its depth z. */
export function projectPoint(camera, p) {
  const T = camera.pose;
  const d = [p[0] - T[3], p[1] - T[7], p[2] - T[11]];
  // The inverse of a rigid pose: R^T (p - t).
  const x = T[0] * d[0] + T[4] * d[1] + T[8] * d[2];
  const y = T[1] * d[0] + T[5] * d[1] + T[9] * d[2];
  const z = T[2] * d[0] + T[6] * d[1] + T[10] * d[2];
  const [fx, fy, cx, cy] = camera.intrinsics;
  return { u: (fx * x) / z + cx, v: (fy * y) / z + cy, z };
}

/** Column-major 4x4 product a * b. */
export function multiply(a, b) {
  const out = new Float64Array(16);
  for (let col = 0; col < 4; col++)
    for (let row = 0; row < 4; row++) {
      let s = 0;
      for (let k = 0; k < 4; k++) s += a[k * 4 + row] * b[col * 4 + k];
      out[col * 4 + row] = s;
    }
  return out;
}

/** Column-major 4x4 times the point (x, y, z, w). */
export function transformPoint(m, x, y, z, w = 1) {
  return [
    m[0] * x + m[4] * y + m[8] * z + m[12] * w,
    m[1] * x + m[5] * y + m[9] * z + m[13] * w,
    m[2] * x + m[6] * y + m[10] * z + m[14] * w,
    m[3] * x + m[7] * y + m[11] * z + m[15] * w,
  ];
}

/** Inverse of a column-major rigid transform (rotation + translation). */
export function invertRigid(m) {
  const out = new Float64Array(16);
  for (let r = 0; r < 3; r++) for (let c = 0; c < 3; c++) out[c * 4 + r] = m[r * 4 + c];
  for (let r = 0; r < 3; r++) out[12 + r] = -(out[r] * m[12] + out[4 + r] * m[13] + out[8 + r] * m[14]);
  out[15] = 1;
  return out;
}
