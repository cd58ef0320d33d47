// The encode stage, in a module Worker so the XR frame loop only copies pixels and sends:
// colour to JPEG (OffscreenCanvas), depth onto the protocol's grid and into a 16-bit PNG, and
// the whole v1 `frame` message packed with msgpack (docs/protocol.md, "The stream socket").
//
// In:  {id, seq, t, camera: {pose, intrinsics}, colour, depth, options}
//      colour: {kind: "pixels", rgba: ArrayBuffer, width, height, bottomUp} (a GL readback)
//            | {kind: "bitmap", bitmap: ImageBitmap}                      (a video frame)
//      depth:  {kind: "cpu", buffer, format, depthWidth, depthHeight, rawValueToMeters,
//               normDepthFromNormView}
//            | {kind: "metres", depth: ArrayBuffer (Float32), depthWidth, depthHeight,
//               normDepthFromNormView, depthProjection, depthTransform}   (reprojected)
//      options: {ratio, depthScaleM, jpegQuality, maxSide, poseSkewS?}
// Out: {id, seq, message: ArrayBuffer, payload: {rgb, depth}, encodeMs, size: [W, H]}
//    | {id, seq, error}

import { encode } from "../vendor/msgpack-msgpack@3.1.3/dist.esm/index.mjs";
import { scaleIntrinsics } from "./conventions.mjs";
import { rawDepthValues, reprojectDepth, resampleCpuDepth, toUint16 } from "./depth.mjs";
import { encodeUint16Png } from "./png.mjs";

let canvas = null;

/** The colour image at most `maxSide` pixels on its longer side, and the scale applied. */
function colourCanvas(colour, maxSide) {
  const width = colour.kind === "bitmap" ? colour.bitmap.width : colour.width;
  const height = colour.kind === "bitmap" ? colour.bitmap.height : colour.height;
  const scale = Math.min(1, maxSide / Math.max(width, height));
  const outW = Math.round(width * scale);
  const outH = Math.round(height * scale);
  if (!canvas || canvas.width !== outW || canvas.height !== outH) canvas = new OffscreenCanvas(outW, outH);
  const ctx = canvas.getContext("2d");
  if (colour.kind === "bitmap") {
    ctx.drawImage(colour.bitmap, 0, 0, outW, outH);
    colour.bitmap.close();
  } else {
    const pixels = new Uint8ClampedArray(colour.rgba);
    if (colour.bottomUp) flipRows(pixels, width, height); // readPixels gives the bottom row first
    const image = new ImageData(pixels, width, height);
    if (scale === 1) ctx.putImageData(image, 0, 0);
    else {
      const full = new OffscreenCanvas(width, height);
      full.getContext("2d").putImageData(image, 0, 0);
      ctx.drawImage(full, 0, 0, outW, outH);
    }
  }
  return { canvas, scale, width: outW, height: outH };
}

function flipRows(pixels, width, height) {
  const stride = width * 4;
  const row = new Uint8ClampedArray(stride);
  for (let top = 0, bottom = height - 1; top < bottom; top++, bottom--) {
    row.set(pixels.subarray(top * stride, top * stride + stride));
    pixels.copyWithin(top * stride, bottom * stride, bottom * stride + stride);
    pixels.set(row, bottom * stride);
  }
}

async function encodeFrame({ seq, t, camera, colour, depth, options }) {
  const started = performance.now();
  const image = colourCanvas(colour, options.maxSide);
  const intrinsics = scaleIntrinsics(camera.intrinsics, image.scale);
  const scaled = { pose: camera.pose, intrinsics };
  const blob = await image.canvas.convertToBlob({ type: "image/jpeg", quality: options.jpegQuality / 100 });
  const jpeg = new Uint8Array(await blob.arrayBuffer());
  let metres;
  if (depth.kind === "cpu") {
    const values = rawDepthValues(depth.buffer, depth.format);
    metres = resampleCpuDepth({ ...depth, values }, image.width, image.height, options.ratio);
  } else {
    metres = reprojectDepth({ ...depth, depth: new Float32Array(depth.depth) }, scaled, image.width, image.height, options.ratio);
  }
  const w = Math.floor(image.width / options.ratio);
  const h = Math.floor(image.height / options.ratio);
  const png = await encodeUint16Png(toUint16(metres, options.depthScaleM), w, h);
  const frame = {
    type: "frame",
    seq,
    t,
    pose: new Uint8Array(new Float32Array(camera.pose).buffer),
    intrinsics,
    rgb: { codec: "jpeg", data: jpeg },
    depth: { codec: "png", w, h, scale: options.depthScaleM, data: png },
  };
  if (options.poseSkewS !== undefined && options.poseSkewS !== null) frame.pose_skew_s = options.poseSkewS;
  const packed = encode(frame);
  const message = packed.buffer.slice(packed.byteOffset, packed.byteOffset + packed.byteLength);
  return {
    seq,
    message,
    payload: { rgb: jpeg.byteLength, depth: png.byteLength },
    encodeMs: performance.now() - started,
    size: [image.width, image.height],
    validDepth: metres.reduce((n, m) => n + (m > 0 ? 1 : 0), 0) / metres.length,
  };
}

self.onmessage = async (event) => {
  const job = event.data;
  try {
    const result = await encodeFrame(job);
    self.postMessage({ id: job.id, ...result }, [result.message]);
  } catch (error) {
    self.postMessage({ id: job.id, seq: job.seq, error: String(error && error.message ? error.message : error) });
  }
};
