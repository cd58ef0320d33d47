// Asynchronous GPU readback (WebGL2): readPixels into a pixel-pack buffer, a fence, and the
// copy out once the GPU has finished, a frame or two later, so the XR frame loop never waits
// on the GPU. Rows come back bottom row first (readPixels' framebuffer order): the caller
// says so to whoever turns them into an image.

export class Readback {
  constructor(gl) {
    this.gl = gl;
    this.framebuffer = gl.createFramebuffer();
    this.jobs = [];
    // Kinds of attachment (target, format) already seen complete: checkFramebufferStatus is a
    // round trip that waits for the GPU (15 ms p95 here), so each kind is checked once.
    this.checked = new Set();
  }

  /**
   * Start reading a width x height texture (TEXTURE_2D, or one `layer` of a TEXTURE_2D_ARRAY)
   * as `format`/`type` (RGBA/UNSIGNED_BYTE for colour, RED/FLOAT for a float target) into a
   * new typed array of `ArrayType`. `tag` travels with the result.
   */
  start(texture, width, height, { layer = null, format, type, ArrayType, channels, tag }) {
    const gl = this.gl;
    const previous = gl.getParameter(gl.FRAMEBUFFER_BINDING);
    gl.bindFramebuffer(gl.FRAMEBUFFER, this.framebuffer);
    if (layer === null) gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, texture, 0);
    else gl.framebufferTextureLayer(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, texture, 0, layer);
    const kind = `${layer === null ? "2d" : "layer"}:${format}:${type}`;
    if (!this.checked.has(kind)) {
      const status = gl.checkFramebufferStatus(gl.FRAMEBUFFER);
      if (status !== gl.FRAMEBUFFER_COMPLETE) {
        gl.bindFramebuffer(gl.FRAMEBUFFER, previous);
        throw new Error(`cannot read this texture back (framebuffer status 0x${status.toString(16)})`);
      }
      this.checked.add(kind);
    }
    const bytes = width * height * channels * ArrayType.BYTES_PER_ELEMENT;
    const buffer = gl.createBuffer();
    gl.bindBuffer(gl.PIXEL_PACK_BUFFER, buffer);
    gl.bufferData(gl.PIXEL_PACK_BUFFER, bytes, gl.STREAM_READ);
    gl.readPixels(0, 0, width, height, format, type, 0);
    gl.bindBuffer(gl.PIXEL_PACK_BUFFER, null);
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, null, 0);
    gl.bindFramebuffer(gl.FRAMEBUFFER, previous);
    // No flush: the browser flushes at the end of this frame's task, and a flush here waits.
    const fence = gl.fenceSync(gl.SYNC_GPU_COMMANDS_COMPLETE, 0);
    this.jobs.push({ buffer, fence, length: bytes / ArrayType.BYTES_PER_ELEMENT, ArrayType, tag });
  }

  /** The readbacks the GPU has finished since the last call: [{tag, data}]. */
  collect() {
    const gl = this.gl;
    const done = [];
    while (this.jobs.length) {
      const job = this.jobs[0];
      const state = gl.clientWaitSync(job.fence, 0, 0);
      if (state === gl.TIMEOUT_EXPIRED) break;
      this.jobs.shift();
      gl.deleteSync(job.fence);
      const data = new job.ArrayType(job.length);
      gl.bindBuffer(gl.PIXEL_PACK_BUFFER, job.buffer);
      gl.getBufferSubData(gl.PIXEL_PACK_BUFFER, 0, data);
      gl.bindBuffer(gl.PIXEL_PACK_BUFFER, null);
      gl.deleteBuffer(job.buffer);
      done.push({ tag: job.tag, data });
    }
    return done;
  }

  get busy() {
    return this.jobs.length > 0;
  }
}
