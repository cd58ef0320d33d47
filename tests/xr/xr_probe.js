// The script of a test-only page (tests/xr/test_fake_webxr.py): WebXR used as a page would use
// it, through the spec surface only (window.fakeXR serves just to name the scene frame a result
// belongs to, and to pause or reset the device). Each function returns plain data the test
// checks against the scene's truth. Independent of static/xr on purpose.
"use strict";

window.probe = (() => {
  let session = null;
  let gl = null;
  let binding = null;
  let space = null;

  const mul = (m, v) => [0, 1, 2, 3].map((r) => m[r] * v[0] + m[4 + r] * v[1] + m[8 + r] * v[2] + m[12 + r] * v[3]);

  /** Inverse of a column-major 4x4 (cofactors). */
  function invert(m) {
    const a = Array.from(m);
    const inv = new Array(16);
    inv[0] = a[5] * a[10] * a[15] - a[5] * a[11] * a[14] - a[9] * a[6] * a[15] + a[9] * a[7] * a[14] + a[13] * a[6] * a[11] - a[13] * a[7] * a[10];
    inv[4] = -a[4] * a[10] * a[15] + a[4] * a[11] * a[14] + a[8] * a[6] * a[15] - a[8] * a[7] * a[14] - a[12] * a[6] * a[11] + a[12] * a[7] * a[10];
    inv[8] = a[4] * a[9] * a[15] - a[4] * a[11] * a[13] - a[8] * a[5] * a[15] + a[8] * a[7] * a[13] + a[12] * a[5] * a[11] - a[12] * a[7] * a[9];
    inv[12] = -a[4] * a[9] * a[14] + a[4] * a[10] * a[13] + a[8] * a[5] * a[14] - a[8] * a[6] * a[13] - a[12] * a[5] * a[10] + a[12] * a[6] * a[9];
    inv[1] = -a[1] * a[10] * a[15] + a[1] * a[11] * a[14] + a[9] * a[2] * a[15] - a[9] * a[3] * a[14] - a[13] * a[2] * a[11] + a[13] * a[3] * a[10];
    inv[5] = a[0] * a[10] * a[15] - a[0] * a[11] * a[14] - a[8] * a[2] * a[15] + a[8] * a[3] * a[14] + a[12] * a[2] * a[11] - a[12] * a[3] * a[10];
    inv[9] = -a[0] * a[9] * a[15] + a[0] * a[11] * a[13] + a[8] * a[1] * a[15] - a[8] * a[3] * a[13] - a[12] * a[1] * a[11] + a[12] * a[3] * a[9];
    inv[13] = a[0] * a[9] * a[14] - a[0] * a[10] * a[13] - a[8] * a[1] * a[14] + a[8] * a[2] * a[13] + a[12] * a[1] * a[10] - a[12] * a[2] * a[9];
    inv[2] = a[1] * a[6] * a[15] - a[1] * a[7] * a[14] - a[5] * a[2] * a[15] + a[5] * a[3] * a[14] + a[13] * a[2] * a[7] - a[13] * a[3] * a[6];
    inv[6] = -a[0] * a[6] * a[15] + a[0] * a[7] * a[14] + a[4] * a[2] * a[15] - a[4] * a[3] * a[14] - a[12] * a[2] * a[7] + a[12] * a[3] * a[6];
    inv[10] = a[0] * a[5] * a[15] - a[0] * a[7] * a[13] - a[4] * a[1] * a[15] + a[4] * a[3] * a[13] + a[12] * a[1] * a[7] - a[12] * a[3] * a[5];
    inv[14] = -a[0] * a[5] * a[14] + a[0] * a[6] * a[13] + a[4] * a[1] * a[14] - a[4] * a[2] * a[13] - a[12] * a[1] * a[6] + a[12] * a[2] * a[5];
    inv[3] = -a[1] * a[6] * a[11] + a[1] * a[7] * a[10] + a[5] * a[2] * a[11] - a[5] * a[3] * a[10] - a[9] * a[2] * a[7] + a[9] * a[3] * a[6];
    inv[7] = a[0] * a[6] * a[11] - a[0] * a[7] * a[10] - a[4] * a[2] * a[11] + a[4] * a[3] * a[10] + a[8] * a[2] * a[7] - a[8] * a[3] * a[6];
    inv[11] = -a[0] * a[5] * a[11] + a[0] * a[7] * a[9] + a[4] * a[1] * a[11] - a[4] * a[3] * a[9] - a[8] * a[1] * a[7] + a[8] * a[3] * a[5];
    inv[15] = a[0] * a[5] * a[10] - a[0] * a[6] * a[9] - a[4] * a[1] * a[10] + a[4] * a[2] * a[9] + a[8] * a[1] * a[6] - a[8] * a[2] * a[5];
    const det = a[0] * inv[0] + a[1] * inv[4] + a[2] * inv[8] + a[3] * inv[12];
    return inv.map((v) => v / det);
  }

  function base64(bytes) {
    let s = "";
    for (let i = 0; i < bytes.length; i += 0x8000) s += String.fromCharCode(...bytes.subarray(i, i + 0x8000));
    return btoa(s);
  }

  const viewInfo = (view) => ({
    eye: view.eye,
    transform: Array.from(view.transform.matrix),
    position: [view.transform.position.x, view.transform.position.y, view.transform.position.z, view.transform.position.w],
    orientation: [view.transform.orientation.x, view.transform.orientation.y, view.transform.orientation.z, view.transform.orientation.w],
    projection: Array.from(view.projectionMatrix),
  });

  async function start(init = {}, spaceType = "local-floor") {
    session = await navigator.xr.requestSession("immersive-ar", init);
    const canvas = document.createElement("canvas");
    gl = canvas.getContext("webgl2", { xrCompatible: true });
    const layer = new XRWebGLLayer(session, gl);
    session.updateRenderState({ baseLayer: layer, depthNear: 0.05, depthFar: 100 });
    binding = new XRWebGLBinding(session, gl);
    space = await session.requestReferenceSpace(spaceType);
    const info = { features: [...session.enabledFeatures], framebuffer: [layer.framebufferWidth, layer.framebufferHeight] };
    try {
      info.depthUsage = session.depthUsage;
      info.depthDataFormat = session.depthDataFormat;
    } catch (error) {
      info.depthError = error.name;
    }
    return info;
  }

  async function refusal(init) {
    try {
      const s = await navigator.xr.requestSession("immersive-ar", init);
      await s.end();
      return null;
    } catch (error) {
      return error.name;
    }
  }

  /** fn(time, frame, pose) inside an XR frame with a pose, after `skip` such frames. */
  function inFrame(fn, skip = 0) {
    return new Promise((resolve, reject) => {
      let seen = 0;
      const onFrame = (time, frame) => {
        const pose = frame.getViewerPose(space);
        if (!pose || seen++ < skip) return void session.requestAnimationFrame(onFrame);
        try {
          resolve(fn(time, frame, pose));
        } catch (error) {
          reject(error);
        }
      };
      session.requestAnimationFrame(onFrame);
    });
  }

  /** CPU depth at normalized view coordinates, read as the spec says: through
   * normDepthBufferFromNormView, scaled by width/height, times rawValueToMeters; and through
   * getDepthInMeters; and (a wrong page's way) ignoring the transform. */
  function cpuDepth(points, skip = 0) {
    return inFrame((time, frame, pose) => {
      const view = pose.views[0];
      const depth = frame.getDepthInformation(view);
      const m = depth.normDepthBufferFromNormView.matrix;
      const raw = session.depthDataFormat === "float32" ? new Float32Array(depth.data) : new Uint16Array(depth.data);
      const at = (col, row) => raw[row * depth.width + col] * depth.rawValueToMeters;
      const read = ([x, y]) => at(Math.floor((m[0] * x + m[4] * y + m[12]) * depth.width), Math.floor((m[1] * x + m[5] * y + m[13]) * depth.height));
      const naive = ([x, y]) => at(Math.min(Math.floor(x * depth.width), depth.width - 1), Math.min(Math.floor(y * depth.height), depth.height - 1));
      return {
        scene: fakeXR.sceneFrame,
        format: session.depthDataFormat,
        width: depth.width,
        height: depth.height,
        rawValueToMeters: depth.rawValueToMeters,
        bytes: depth.data.byteLength,
        matrix: Array.from(m),
        manual: points.map(read),
        api: points.map(([x, y]) => depth.getDepthInMeters(x, y)),
        naive: points.map(naive),
        depthTransform: Array.from(depth.transform.matrix),
        depthProjection: Array.from(depth.projectionMatrix),
        view: viewInfo(view),
      };
    }, skip);
  }

  /** The camera texture read back with readPixels (bottom row first), as base64 RGBA. */
  function cameraImage(skip = 0) {
    let texture = null;
    const result = inFrame((time, frame, pose) => {
      const view = pose.views[0];
      const camera = view.camera;
      texture = binding.getCameraImage(camera);
      const fb = gl.createFramebuffer();
      gl.bindFramebuffer(gl.FRAMEBUFFER, fb);
      gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, texture, 0);
      const px = new Uint8Array(camera.width * camera.height * 4);
      gl.readPixels(0, 0, camera.width, camera.height, gl.RGBA, gl.UNSIGNED_BYTE, px);
      gl.bindFramebuffer(gl.FRAMEBUFFER, null);
      gl.deleteFramebuffer(fb);
      return {
        scene: fakeXR.sceneFrame,
        width: camera.width,
        height: camera.height,
        sameCamera: view.camera === camera,
        sameTexture: binding.getCameraImage(camera) === texture,
        rgba: base64(px),
        view: viewInfo(view),
      };
    }, skip);
    return result.then(async (out) => ({ ...out, textureAfterFrame: await inFrame(() => gl.isTexture(texture)) }));
  }

  /** What a page that deletes the camera texture gets told. */
  function deleteCameraTexture() {
    return inFrame((time, frame, pose) => {
      const texture = binding.getCameraImage(pose.views[0].camera);
      gl.deleteTexture(texture);
      return { stillATexture: gl.isTexture(texture), errors: [...fakeXR.errors] };
    });
  }

  /** Pixel coordinates (OpenCV: centres at integers, row 0 at the top) of points in the
   * reference space, through each view's transform, projectionMatrix and viewport. */
  function project(points, skip = 0) {
    return inFrame((time, frame, pose) => {
      const layer = session.renderState.baseLayer;
      return {
        scene: fakeXR.sceneFrame,
        viewer: Array.from(pose.transform.matrix),
        views: pose.views.map((view) => {
          const vp = layer.getViewport(view);
          const viewFromSpace = view.transform.inverse.matrix;
          return {
            ...viewInfo(view),
            viewport: [vp.x, vp.y, vp.width, vp.height],
            pixels: points.map((p) => {
              const clip = mul(view.projectionMatrix, mul(viewFromSpace, [...p, 1]));
              const x = (clip[0] / clip[3] + 1) / 2; // normalized view coordinates
              const y = (1 - clip[1] / clip[3]) / 2;
              return [x * vp.width - 0.5, y * vp.height - 0.5];
            }),
          };
        }),
      };
    }, skip);
  }

  /** GPU depth per view: each layer of the texture array read back as floats, converted to
   * metres the documented way (window depth under the depth view's planes) and lifted into the
   * reference space with the depth view's own projectionMatrix and transform; plus the
   * same texels lifted the wrong ways a page might (the render view's geometry, rows read top
   * first, the values taken as metres). Every `step`-th texel. */
  function gpuDepth(step = 8, skip = 0) {
    return inFrame((time, frame, pose) => {
      if (!gl.getExtension("EXT_color_buffer_float")) throw new Error("no EXT_color_buffer_float");
      return {
        scene: fakeXR.sceneFrame,
        views: pose.views.map((view) => {
          const d = binding.getDepthInformation(view);
          const fb = gl.createFramebuffer();
          gl.bindFramebuffer(gl.FRAMEBUFFER, fb);
          gl.framebufferTextureLayer(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, d.texture, 0, d.imageIndex);
          const w = d.width;
          const h = d.height;
          const px = new Float32Array(w * h * 4);
          gl.readPixels(0, 0, w, h, gl.RGBA, gl.FLOAT, px);
          gl.bindFramebuffer(gl.FRAMEBUFFER, null);
          gl.deleteFramebuffer(fb);
          const spaceFromDepth = d.transform.matrix;
          const depthFromNdc = invert(d.projectionMatrix);
          const lift = (toView, toSpace, ndcX, ndcY, ndcZ) => {
            const v = mul(toView, [ndcX, ndcY, ndcZ, 1]);
            return mul(toSpace, [v[0] / v[3], v[1] / v[3], v[2] / v[3], 1]).slice(0, 3);
          };
          const near = d.depthNear;
          const far = d.depthFar;
          const metres = (value) => (Number.isFinite(far) ? (far * near) / (far - value * (far - near)) : near / (1 - value));
          const ndcZ = (projection, z) => {
            const c = mul(projection, [0, 0, -z, 1]);
            return c[2] / c[3];
          };
          const renderFromNdc = invert(view.projectionMatrix);
          const out = { points: [], renderView: [], topRowFirst: [], asMetres: [] };
          for (let row = step >> 1; row < h; row += step) {
            for (let col = step >> 1; col < w; col += step) {
              const value = px[4 * (row * w + col)];
              if (!(value > 0)) continue;
              const x = (2 * col + 1) / w - 1; // texel row 0 is the bottom of the depth view
              const y = (2 * row + 1) / h - 1;
              out.points.push(lift(depthFromNdc, spaceFromDepth, x, y, 2 * value - 1));
              // The render view's geometry, with the right metric depth.
              out.renderView.push(lift(renderFromNdc, view.transform.matrix, x, y, ndcZ(view.projectionMatrix, metres(value))));
              out.topRowFirst.push(lift(depthFromNdc, spaceFromDepth, x, -y, 2 * value - 1));
              out.asMetres.push(lift(depthFromNdc, spaceFromDepth, x, y, ndcZ(d.projectionMatrix, value * d.rawValueToMeters)));
            }
          }
          return {
            ...out,
            eye: view.eye,
            textureType: d.textureType,
            imageIndex: d.imageIndex,
            width: w,
            height: h,
            depthNear: d.depthNear,
            depthFar: Number.isFinite(d.depthFar) ? d.depthFar : null,
            rawValueToMeters: d.rawValueToMeters,
            normDepthBufferFromNormView: Array.from(d.normDepthBufferFromNormView.matrix),
            transform: Array.from(d.transform.matrix),
            projection: Array.from(d.projectionMatrix),
            view: viewInfo(view),
          };
        }),
      };
    }, skip);
  }

  /** Viewer poses over `count` frames in the probe's space and in 'local'; asks the device for
   * a reset inside frame `resetAt`. */
  async function poses(count, resetAt = -1, transform = undefined) {
    const local = await session.requestReferenceSpace("local");
    const viewer = await session.requestReferenceSpace("viewer");
    const events = [];
    for (const s of [space, local])
      s.addEventListener("reset", (e) =>
        events.push({ space: s === space ? "probe" : "local", xrFrame: fakeXR.xrFrames, same: e.referenceSpace === s, transform: e.transform ? Array.from(e.transform.matrix) : null }),
      );
    const frames = [];
    return new Promise((resolve) => {
      const onFrame = (time, frame) => {
        const pose = frame.getViewerPose(space);
        frames.push({
          time,
          xrFrame: fakeXR.xrFrames,
          scene: fakeXR.sceneFrame,
          events: events.length,
          viewer: Array.from(pose.transform.matrix),
          local: Array.from(frame.getViewerPose(local).transform.matrix),
          viewerSpace: Array.from(frame.getPose(viewer, space).transform.matrix),
        });
        if (frames.length - 1 === resetAt) fakeXR.resetReferenceSpace(transform);
        if (frames.length < count) session.requestAnimationFrame(onFrame);
        else resolve({ frames, events });
      };
      session.requestAnimationFrame(onFrame);
    });
  }

  /** Paint a red rectangle (GL window coordinates) into the layer; the display as it shows
   * that frame, as base64 RGBA. */
  async function paint(rect) {
    const painted = await inFrame(() => {
      const layer = session.renderState.baseLayer;
      gl.bindFramebuffer(gl.FRAMEBUFFER, layer.framebuffer);
      gl.enable(gl.SCISSOR_TEST);
      gl.scissor(...rect);
      gl.clearColor(1, 0, 0, 1);
      gl.clear(gl.COLOR_BUFFER_BIT);
      gl.disable(gl.SCISSOR_TEST);
      gl.bindFramebuffer(gl.FRAMEBUFFER, null);
      return { scene: fakeXR.sceneFrame };
    });
    const canvas = document.getElementById("fakexr-display");
    const image = canvas.getContext("2d").getImageData(0, 0, canvas.width, canvas.height);
    return { ...painted, width: canvas.width, height: canvas.height, rgba: base64(new Uint8Array(image.data.buffer)) };
  }

  /** getUserMedia's video, once two frames have arrived, drawn into a canvas. */
  async function video() {
    const stream = await navigator.mediaDevices.getUserMedia({ video: { facingMode: "environment" } });
    const element = document.createElement("video");
    element.muted = true;
    element.playsInline = true;
    element.srcObject = stream;
    element.play();
    for (let i = 0; i < 3; i++) await new Promise((resolve) => element.requestVideoFrameCallback(resolve));
    const canvas = Object.assign(document.createElement("canvas"), { width: element.videoWidth, height: element.videoHeight });
    const ctx = canvas.getContext("2d");
    ctx.drawImage(element, 0, 0);
    const image = ctx.getImageData(0, 0, canvas.width, canvas.height);
    stream.getTracks().forEach((track) => track.stop());
    return {
      width: canvas.width,
      height: canvas.height,
      scene: fakeXR.videoLog.length ? fakeXR.videoLog[fakeXR.videoLog.length - 1].sceneFrame : null,
      rgba: base64(new Uint8Array(image.data.buffer)),
    };
  }

  async function end() {
    const ended = new Promise((resolve) => session.addEventListener("end", resolve, { once: true }));
    await session.end();
    await ended;
    return { liveSession: fakeXR.session !== null };
  }

  return { start, refusal, inFrame, cpuDepth, cameraImage, deleteCameraTexture, project, gpuDepth, poses, paint, video, end, get session() { return session; } };
})();
