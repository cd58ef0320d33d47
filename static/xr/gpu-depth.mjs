// GPU depth (WebXR Depth Sensing, "gpu-optimized", XRWebGLBinding.getDepthInformation) read
// back as metres. Quest Browser offers only this: a texture array, one layer per view
// (`imageIndex`), whose values (raw x rawValueToMeters) are not metres but window-space depth
// of the depth view's own projection (OpenXR's XR_META_environment_depth: "the same format as
// described in XR_KHR_composition_layer_depth"; the depth information carries its
// `depthNear`/`depthFar` and `projectionMatrix`), so they are linearised here; a runtime
// whose values are metric (value x rawValueToMeters, as the spec words it) is read as such.
// Texel rows are a GL texture's, bottom row first (OpenXR's depth view "is never flipped",
// and Quest Browser's normDepthBufferFromNormView is the identity): reprojectDepth is told so.
// One full-screen pass writes metres into a float target, read back asynchronously
// (readback.mjs). Formats: float32 (a float texture) and luminance-alpha (two bytes of a
// 16-bit value, low byte in luminance).

const VERTEX = `#version 300 es
void main() {
  vec2 corner = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));
  gl_Position = vec4(corner * 2.0 - 1.0, 0.0, 1.0);
}`;

function fragment(array) {
  return `#version 300 es
precision highp float;
precision highp int;
uniform highp ${array ? "sampler2DArray" : "sampler2D"} depthTexture;
uniform int layer;
uniform int windowDepth;     // 1: [0, 1] window depth of the depth view's projection
uniform int packed16;        // 1: luminance-alpha, a 16-bit value in two normalized bytes
uniform float rawValueToMeters;
uniform float projA;         // the projection's [2][2] and [3][2] (column-major 10 and 14)
uniform float projB;
out vec4 metres;
void main() {
  ivec2 texel = ivec2(gl_FragCoord.xy);
  vec4 t = texelFetch(depthTexture, ${array ? "ivec3(texel, layer)" : "texel"}, 0);
  float raw = packed16 == 1 ? floor(t.r * 255.0 + 0.5) + 256.0 * floor(t.a * 255.0 + 0.5) : t.r;
  float value = raw * rawValueToMeters;
  float m;
  if (windowDepth == 1) {
    float zNdc = 2.0 * value - 1.0;
    m = (value <= 0.0 || value >= 1.0) ? 0.0 : projB / (zNdc + projA);
  } else {
    m = value;
  }
  metres = vec4(m, 0.0, 0.0, 1.0);
}`;
}

function compile(gl, vertexSource, fragmentSource) {
  const program = gl.createProgram();
  for (const [type, source] of [
    [gl.VERTEX_SHADER, vertexSource],
    [gl.FRAGMENT_SHADER, fragmentSource],
  ]) {
    const shader = gl.createShader(type);
    gl.shaderSource(shader, source);
    gl.compileShader(shader);
    if (!gl.getShaderParameter(shader, gl.COMPILE_STATUS)) throw new Error(`depth shader: ${gl.getShaderInfoLog(shader)}`);
    gl.attachShader(program, shader);
  }
  gl.linkProgram(program);
  if (!gl.getProgramParameter(program, gl.LINK_STATUS)) throw new Error(`depth shader: ${gl.getProgramInfoLog(program)}`);
  return program;
}

/** The projection's depth terms: from the depth information's own projectionMatrix, else its
 * depthNear/depthFar (an OpenGL perspective; an infinite far plane allowed). */
export function depthTerms(info) {
  if (info.projectionMatrix) return { a: info.projectionMatrix[10], b: info.projectionMatrix[14] };
  const n = info.depthNear;
  const f = info.depthFar;
  if (!Number.isFinite(f)) return { a: -1, b: -2 * n };
  return { a: -(f + n) / (f - n), b: (-2 * f * n) / (f - n) };
}

/** Whether a GPU depth information's values are window depth rather than metric: Quest
 * Browser marks its depth with the range it was rendered with (depthNear/depthFar). */
export function isWindowDepth(info) {
  return info.depthNear !== undefined && info.depthNear !== null;
}

export class GpuDepthReader {
  constructor(gl, readback) {
    if (!gl.getExtension("EXT_color_buffer_float")) throw new Error("this browser cannot render float depth (EXT_color_buffer_float)");
    this.gl = gl;
    this.readback = readback;
    this.programs = { true: compile(gl, VERTEX, fragment(true)), false: compile(gl, VERTEX, fragment(false)) };
    this.target = null;
    this.size = [0, 0];
    this.framebuffer = gl.createFramebuffer();
    this.vao = gl.createVertexArray();
  }

  _ensureTarget(width, height) {
    const gl = this.gl;
    if (this.target && this.size[0] === width && this.size[1] === height) return;
    if (this.target) gl.deleteTexture(this.target);
    this.target = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, this.target);
    gl.texStorage2D(gl.TEXTURE_2D, 1, gl.R32F, width, height);
    gl.bindTexture(gl.TEXTURE_2D, null);
    this.size = [width, height];
  }

  /** Start reading `info` (an XRWebGLDepthInformation) as metres; `tag` comes back with a
   * Float32Array of RGBA texels, metres in red (row 0 = depth-buffer row 0), from
   * readback.collect(). */
  start(info, format, tag) {
    const gl = this.gl;
    if (format !== "float32" && format !== "luminance-alpha") throw new Error(`GPU depth in ${format} is not read by this page (float32 or luminance-alpha)`);
    const array = info.textureType === "texture-array";
    const { width, height } = info;
    this._ensureTarget(width, height);
    const saved = {
      framebuffer: gl.getParameter(gl.FRAMEBUFFER_BINDING),
      program: gl.getParameter(gl.CURRENT_PROGRAM),
      viewport: gl.getParameter(gl.VIEWPORT),
      vao: gl.getParameter(gl.VERTEX_ARRAY_BINDING),
      blend: gl.isEnabled(gl.BLEND),
      depthTest: gl.isEnabled(gl.DEPTH_TEST),
    };
    gl.bindFramebuffer(gl.FRAMEBUFFER, this.framebuffer);
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, this.target, 0);
    gl.viewport(0, 0, width, height);
    gl.disable(gl.BLEND);
    gl.disable(gl.DEPTH_TEST);
    const program = this.programs[array];
    gl.useProgram(program);
    gl.activeTexture(gl.TEXTURE0);
    gl.bindTexture(array ? gl.TEXTURE_2D_ARRAY : gl.TEXTURE_2D, info.texture);
    gl.uniform1i(gl.getUniformLocation(program, "depthTexture"), 0);
    gl.uniform1i(gl.getUniformLocation(program, "layer"), info.imageIndex || 0);
    const windowDepth = isWindowDepth(info);
    gl.uniform1i(gl.getUniformLocation(program, "windowDepth"), windowDepth ? 1 : 0);
    gl.uniform1i(gl.getUniformLocation(program, "packed16"), format === "luminance-alpha" ? 1 : 0);
    gl.uniform1f(gl.getUniformLocation(program, "rawValueToMeters"), info.rawValueToMeters || 1);
    const { a, b } = windowDepth ? depthTerms(info) : { a: 0, b: 0 };
    gl.uniform1f(gl.getUniformLocation(program, "projA"), a);
    gl.uniform1f(gl.getUniformLocation(program, "projB"), b);
    gl.bindVertexArray(this.vao);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
    gl.bindTexture(array ? gl.TEXTURE_2D_ARRAY : gl.TEXTURE_2D, null);
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, null, 0);
    gl.bindVertexArray(saved.vao);
    gl.useProgram(saved.program);
    gl.bindFramebuffer(gl.FRAMEBUFFER, saved.framebuffer);
    gl.viewport(...saved.viewport);
    if (saved.blend) gl.enable(gl.BLEND);
    if (saved.depthTest) gl.enable(gl.DEPTH_TEST);
    // RGBA/FLOAT is the read format every float colour target allows; metres are in red.
    this.readback.start(this.target, width, height, {
      format: gl.RGBA,
      type: gl.FLOAT,
      ArrayType: Float32Array,
      channels: 4,
      tag,
    });
  }
}
