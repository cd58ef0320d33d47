// A 16-bit greyscale PNG encoder on the browser's own zlib (CompressionStream('deflate') is
// RFC 1950 zlib, what a PNG's IDAT holds). Works in a Worker. The protocol's depth codec
// "png" is a 16-bit greyscale PNG, samples big-endian as PNG stores them.

const CRC_TABLE = (() => {
  const table = new Uint32Array(256);
  for (let n = 0; n < 256; n++) {
    let c = n;
    for (let k = 0; k < 8; k++) c = c & 1 ? 0xedb88320 ^ (c >>> 1) : c >>> 1;
    table[n] = c >>> 0;
  }
  return table;
})();

function crc32(bytes) {
  let c = 0xffffffff;
  for (let i = 0; i < bytes.length; i++) c = CRC_TABLE[(c ^ bytes[i]) & 0xff] ^ (c >>> 8);
  return (c ^ 0xffffffff) >>> 0;
}

function chunk(type, data) {
  const out = new Uint8Array(12 + data.length);
  const view = new DataView(out.buffer);
  view.setUint32(0, data.length);
  for (let i = 0; i < 4; i++) out[4 + i] = type.charCodeAt(i);
  out.set(data, 8);
  view.setUint32(8 + data.length, crc32(out.subarray(4, 8 + data.length)));
  return out;
}

async function zlib(bytes) {
  const stream = new Blob([bytes]).stream().pipeThrough(new CompressionStream("deflate"));
  return new Uint8Array(await new Response(stream).arrayBuffer());
}

/**
 * PNG bytes of a width x height uint16 image (Uint16Array, row-major, row 0 at the top).
 * Each row is filtered with PNG's "Up" filter (byte-wise difference to the row above), which
 * on smooth depth shrinks what zlib sees, as the server's own PNGs do with row prediction.
 */
export async function encodeUint16Png(values, width, height) {
  const stride = width * 2;
  const raw = new Uint8Array((stride + 1) * height);
  let previous = null;
  for (let y = 0; y < height; y++) {
    const row = new Uint8Array(stride);
    for (let x = 0; x < width; x++) {
      const v = values[y * width + x];
      row[2 * x] = v >>> 8;
      row[2 * x + 1] = v & 0xff;
    }
    const at = y * (stride + 1);
    raw[at] = previous ? 2 : 0; // filter type: Up, none for the first row
    for (let i = 0; i < stride; i++) raw[at + 1 + i] = previous ? (row[i] - previous[i]) & 0xff : row[i];
    previous = row;
  }
  const header = new Uint8Array(13);
  const hv = new DataView(header.buffer);
  hv.setUint32(0, width);
  hv.setUint32(4, height);
  header[8] = 16; // bit depth
  header[9] = 0; // colour type: greyscale
  const signature = new Uint8Array([137, 80, 78, 71, 13, 10, 26, 10]);
  const parts = [signature, chunk("IHDR", header), chunk("IDAT", await zlib(raw)), chunk("IEND", new Uint8Array(0))];
  const out = new Uint8Array(parts.reduce((n, p) => n + p.length, 0));
  let at = 0;
  for (const p of parts) {
    out.set(p, at);
    at += p.length;
  }
  return out;
}
