/* A fake WebXR device for tests: replaces navigator.xr and the XR interfaces on window with an
 * emulated phone (Chrome on Android: camera-access, CPU depth) or Quest 3 (stereo views, GPU
 * depth per eye, colour from getUserMedia), walking through frames a Python feed renders
 * (tests/xr/scene_feed.py). Written from the specs, not from any implementation; the spec
 * sentence behind each convention is quoted where the convention is applied.
 *
 * Install: a classic script run before any page script (Playwright page.add_init_script), after
 * a first init script that sets window.__fakeXRConfig (tests/xr/fake_xr_browser.py does both).
 *
 * window.__fakeXRConfig (built by scene_feed.SceneFeed.js_config from xr_device.py):
 *   profile              "android" | "quest"
 *   features             feature descriptors the device supports ("viewer", "local",
 *                        "local-floor", "camera-access", "depth-sensing", "dom-overlay")
 *   views                [{eye, pinhole: {width, height, fx, fy, cx, cy}, viewport: [x, y, w, h]}]
 *                        pinholes in OpenCV's convention (pixel centres at integers, row 0 at
 *                        the top); viewports in GL's (origin bottom-left) within the layer
 *   framebuffer          [width, height] of an XRWebGLLayer at framebufferScaleFactor 1
 *   cameraAccess         {width, height} of the camera image (android) or null
 *   depth                usages, formats, preferredFormat, width, height (the buffer),
 *                        normDepthBufferFromNormView {position, orientation}, rawValueToMeters16
 *                        (16-bit formats), encoding "metres" | "window", alignedWithView;
 *                        window encoding also: pinholes (one per view), near, far (null:
 *                        infinite), bottomRowFirst, textureType; staleSceneFrames: how old
 *                        the depth is when the page sets matchDepthView false
 *   userMedia            {width, height} of the getUserMedia camera (quest) or null
 *   interactionMode      XRSession.interactionMode
 *   frameCount           scene frames in the walk; sceneFps: the walk's own clock
 *   localOrigin          {position, orientation}: 'local' space's origin in the tracking frame
 *                        (the 'local-floor' origin until a reset)
 *   xrFramesPerSceneFrame  XR animation frames each scene frame is held for
 *   onWalkEnd            "hold" (keep showing the last frame) | "end" (end the session)
 *   display, displayEvery, displayScale  composite passthrough + the app's layer onto a
 *                        visible canvas (#fakexr-display) every n-th XR frame, at this fraction
 *                        of the layer's resolution
 *   prefetch             scene frames fetched ahead
 *   requireUserActivation  requestSession needs transient activation (as Chrome does)
 *   videoFps, videoDelaySceneFrames  getUserMedia pushes frames at this rate, showing the scene
 *                        frame this many frames behind the XR frame's pose
 *   routePrefix          same-origin path of the feed: GET <routePrefix>frame/<i>
 *
 * Test API, window.fakeXR:
 *   config               the config in use
 *   session              the live XRSession, or null
 *   xrFrames             XR animation frames delivered this session
 *   sceneFrame           the scene frame of the latest XR frame
 *   done                 the walk has ended (the last scene frame was held its full time)
 *   stalls               window frames that waited for a scene frame still on its way
 *   frameLog             [{xrFrame, time, sceneFrame, sceneTime}] (sceneTime: the walk's clock)
 *   videoLog             [{time, sceneFrame}]: when the getUserMedia video turned to a frame
 *   errors               [string]: feed fetches that failed, deleteTexture on an opaque texture
 *   pause(), resume()    no XR frames while paused (the video keeps its frame)
 *   resetReferenceSpace(transform?)  a tracking discontinuity: 'reset' fires on every reference
 *                        space before the next XR frame, whose poses use the new origin;
 *                        transform {position, orientation}: the new origin in the old one
 *                        (default: a 25 degree turn and a step)
 *   resets               [{xrFrame, transform}]
 *   whenSceneFrame(i), whenDone()  promises
 *
 * Timing: one XR animation frame per window animation frame while the page has an XR frame
 * callback pending; XR frame k shows scene frame floor(k / xrFramesPerSceneFrame), so the walk
 * advances only as the page takes frames (deterministic, whatever the machine's speed). The
 * time passed to callbacks is the window frame's timestamp (monotonic, performance.now()'s clock).
 */
(() => {
  "use strict";
  const CONFIG = window.__fakeXRConfig;
  if (!CONFIG) {
    console.warn("fake_webxr.js: window.__fakeXRConfig is not set; navigator.xr left alone");
    return;
  }
  const INTERNAL = Symbol("fakeXR internal");
  const state = new WeakMap(); // every object's internal slots
  const slots = (object) => state.get(object);
  const domError = (name, message) => new DOMException(message, name);
  const illegal = () => new TypeError("Illegal constructor");

  // --- rigid transforms as {p: [x, y, z], q: [x, y, z, w]} ---------------------------------
  const IDENTITY = Object.freeze({ p: [0, 0, 0], q: [0, 0, 0, 1] });
  const qmul = (a, b) => [
    a[3] * b[0] + a[0] * b[3] + a[1] * b[2] - a[2] * b[1],
    a[3] * b[1] - a[0] * b[2] + a[1] * b[3] + a[2] * b[0],
    a[3] * b[2] + a[0] * b[1] - a[1] * b[0] + a[2] * b[3],
    a[3] * b[3] - a[0] * b[0] - a[1] * b[1] - a[2] * b[2],
  ];
  const qconj = (q) => [-q[0], -q[1], -q[2], q[3]];
  const qnormalize = (q) => {
    const n = Math.hypot(q[0], q[1], q[2], q[3]);
    return [q[0] / n, q[1] / n, q[2] / n, q[3] / n];
  };
  const qrot = (q, v) => qmul(qmul(q, [v[0], v[1], v[2], 0]), qconj(q)).slice(0, 3);
  const compose = (a, b) => {
    const r = qrot(a.q, b.p);
    return { p: [a.p[0] + r[0], a.p[1] + r[1], a.p[2] + r[2]], q: qnormalize(qmul(a.q, b.q)) };
  };
  const invert = (a) => {
    const q = qconj(a.q);
    const p = qrot(q, a.p);
    return { p: [-p[0], -p[1], -p[2]], q };
  };
  const poseOf = (js) => ({ p: [...js.position], q: qnormalize([...js.orientation]) });

  /** Column-major Float32Array(16) of a pose. WebXR Device API, Matrices: "4x4 matrices are
   * given as 16 element Float32Arrays with column major storage, and are applied to column
   * vectors by premultiplying the matrix from the left"; XRRigidTransform.matrix "will rotate
   * the vector by the 3D rotation described by orientation, and then translate it by
   * position ... M = T * R". */
  function matrixOf(pose) {
    const [x, y, z, w] = pose.q;
    const m = new Float32Array(16);
    m[0] = 1 - 2 * (y * y + z * z);
    m[1] = 2 * (x * y + z * w);
    m[2] = 2 * (x * z - y * w);
    m[4] = 2 * (x * y - z * w);
    m[5] = 1 - 2 * (x * x + z * z);
    m[6] = 2 * (y * z + x * w);
    m[8] = 2 * (x * z + y * w);
    m[9] = 2 * (y * z - x * w);
    m[10] = 1 - 2 * (x * x + y * y);
    m[12] = pose.p[0];
    m[13] = pose.p[1];
    m[14] = pose.p[2];
    m[15] = 1;
    return m;
  }

  /** OpenGL projection of a pinhole view (far null: infinite). The view looks down -Z with +Y
   * up (WebXR: "+X is considered Right, +Y is considered Up, and -Z is considered Forward");
   * NDC x = -1 is the image's left edge and NDC y = +1 its top edge, so normalized view
   * coordinates (x, y) -- depth sensing: "an origin in the top left corner of the view, with
   * X axis growing to the right, and Y axis growing downward" -- are ((ndc.x + 1) / 2,
   * (1 - ndc.y) / 2), and pixel (u, v) of an OpenCV pinhole sits at ((u + 0.5) / width,
   * (v + 0.5) / height). */
  function projectionOf(pinhole, near, far) {
    const { width, height, fx, fy, cx, cy } = pinhole;
    const m = new Float32Array(16);
    m[0] = (2 * fx) / width;
    m[5] = (2 * fy) / height;
    m[8] = 1 - (2 * (cx + 0.5)) / width;
    m[9] = (2 * (cy + 0.5)) / height - 1;
    m[11] = -1;
    if (far === null || far === undefined || !Number.isFinite(far)) {
      m[10] = -1;
      m[14] = -2 * near;
    } else {
      m[10] = -(far + near) / (far - near);
      m[14] = (-2 * far * near) / (far - near);
    }
    return m;
  }

  /** Window-space depth in [0, 1] of a z-depth in metres under a projection with these
   * planes (glDepthRange 0..1): what a Quest's depth texel holds (see the depth section). */
  function windowDepth(z, near, far) {
    if (!(z > 0)) return 0; // depth sensing: invalid depth data "MUST return a depth value of 0"
    if (far === null || far === undefined || !Number.isFinite(far)) return 1 - near / z;
    return (far * (z - near)) / (z * (far - near));
  }

  // --- event plumbing ----------------------------------------------------------------------
  function defineEventHandlers(cls, names) {
    for (const name of names) {
      const key = Symbol(`on${name}`);
      Object.defineProperty(cls.prototype, `on${name}`, {
        configurable: true,
        enumerable: true,
        get() {
          return this[key] ?? null;
        },
        set(handler) {
          if (this[key]) this.removeEventListener(name, this[key]);
          this[key] = typeof handler === "function" ? handler : null;
          if (this[key]) this.addEventListener(name, this[key]);
        },
      });
    }
  }
  const report = (error) => (typeof reportError === "function" ? reportError(error) : setTimeout(() => { throw error; }));

  // --- interfaces ---------------------------------------------------------------------------

  class XRRigidTransform {
    /** WebXR: the constructor throws a TypeError when position.w is not 1 or any value is not
     * finite, and normalizes the orientation. */
    constructor(position = {}, orientation = {}) {
      const p = [position.x ?? 0, position.y ?? 0, position.z ?? 0];
      const pw = position.w ?? 1;
      const q = [orientation.x ?? 0, orientation.y ?? 0, orientation.z ?? 0, orientation.w ?? 1];
      if (pw !== 1) throw new TypeError("XRRigidTransform: position.w must be 1");
      if (![...p, ...q].every(Number.isFinite)) throw new TypeError("XRRigidTransform: values must be finite");
      if (Math.hypot(...q) === 0) throw domError("InvalidStateError", "XRRigidTransform: zero orientation");
      state.set(this, { pose: { p, q: qnormalize(q) } });
    }
    get position() {
      const s = slots(this);
      return (s.position ??= new DOMPointReadOnly(s.pose.p[0], s.pose.p[1], s.pose.p[2], 1));
    }
    get orientation() {
      const s = slots(this);
      return (s.orientation ??= new DOMPointReadOnly(...s.pose.q));
    }
    get matrix() {
      const s = slots(this);
      return (s.matrix ??= matrixOf(s.pose));
    }
    get inverse() {
      // WebXR: "The XRRigidTransform returned by inverse MUST return transform as its inverse."
      const s = slots(this);
      if (!s.inverse) {
        s.inverse = rigid(invert(s.pose));
        slots(s.inverse).inverse = this;
      }
      return s.inverse;
    }
  }
  function rigid(pose) {
    const t = Object.create(XRRigidTransform.prototype);
    state.set(t, { pose: { p: [...pose.p], q: [...pose.q] } });
    return t;
  }

  class XRSpace extends EventTarget {
    constructor(token) {
      if (token !== INTERNAL) throw illegal();
      super();
    }
  }

  class XRReferenceSpace extends XRSpace {
    /** WebXR: getOffsetReferenceSpace's result has origin offset "the result of multiplying
     * base's origin offset by originOffset". */
    getOffsetReferenceSpace(originOffset) {
      const s = slots(this);
      return newReferenceSpace(s.session, s.type, compose(s.offset, slots(originOffset).pose));
    }
  }
  defineEventHandlers(XRReferenceSpace, ["reset"]);

  function newReferenceSpace(session, type, offset = IDENTITY) {
    const space = new XRReferenceSpace(INTERNAL);
    state.set(space, { session, type, offset });
    slots(session).spaces.add(space);
    return space;
  }

  /** The native origin of a space in the tracking frame. WebXR 'local-floor': "a native origin
   * at the floor ... The Y axis equals 0 at floor level"; the tracking frame's floor is y = 0.
   * 'local': "a native origin near the viewer's position at the time of creation". */
  function nativeOrigin(space, frameState) {
    const s = slots(space);
    if (s.type === "viewer") return frameState.viewer;
    const shift = slots(s.session).trackingShift;
    return s.type === "local" ? compose(shift, LOCAL_ORIGIN) : shift;
  }
  // WebXR: "the effective origin can be obtained by multiplying origin offset and the native
  // origin".
  const effectiveOrigin = (space, frameState) => compose(nativeOrigin(space, frameState), slots(space).offset);
  const poseIn = (space, frameState, trackingPose) => compose(invert(effectiveOrigin(space, frameState)), trackingPose);

  class XRPose {
    constructor(token) {
      if (token !== INTERNAL) throw illegal();
    }
    get transform() {
      return slots(this).transform;
    }
    get emulatedPosition() {
      return false;
    }
  }
  class XRViewerPose extends XRPose {
    get views() {
      return slots(this).views;
    }
  }

  class XRView {
    constructor(token) {
      if (token !== INTERNAL) throw illegal();
    }
    get eye() {
      return slots(this).eye;
    }
    get index() {
      return slots(this).index;
    }
    /** WebXR: "the transform attribute ... represents the position and orientation of the
     * object in the XRReferenceSpace used to obtain the object". */
    get transform() {
      return slots(this).transform;
    }
    get projectionMatrix() {
      const s = slots(this);
      return (s.projection ??= projectionOf(s.pinhole, s.near, s.far));
    }
    get recommendedViewportScale() {
      return null;
    }
    requestViewportScale() {}
    get isFirstPersonObserver() {
      return false;
    }
    /** Raw camera access: "When camera attribute is accessed for the first time ... the user
     * agent MUST run the obtain camera algorithm. Subsequent accesses ... MUST result [in] the
     * same XRCamera instance"; it is null unless camera-access was granted. */
    get camera() {
      const s = slots(this);
      if (!("camera" in s)) {
        const frame = slots(s.frame);
        if (!enabled(frame.session, "camera-access") || !CONFIG.cameraAccess) s.camera = null;
        else {
          if (!frame.active || !frame.animationFrame) throw domError("InvalidStateError", "XRView.camera: the frame is not active");
          s.camera = new XRCamera(INTERNAL);
          state.set(s.camera, { view: this, ...CONFIG.cameraAccess });
        }
      }
      return s.camera;
    }
  }

  class XRCamera {
    constructor(token) {
      if (token !== INTERNAL) throw illegal();
    }
    get width() {
      return slots(this).width;
    }
    get height() {
      return slots(this).height;
    }
  }

  class XRViewport {
    constructor(token) {
      if (token !== INTERNAL) throw illegal();
    }
    get x() {
      return slots(this)[0];
    }
    get y() {
      return slots(this)[1];
    }
    get width() {
      return slots(this)[2];
    }
    get height() {
      return slots(this)[3];
    }
  }

  class XRRenderState {
    constructor(token) {
      if (token !== INTERNAL) throw illegal();
    }
    get depthNear() {
      return slots(this).depthNear;
    }
    get depthFar() {
      return slots(this).depthFar;
    }
    get inlineVerticalFieldOfView() {
      return null;
    }
    get baseLayer() {
      return slots(this).baseLayer;
    }
    get layers() {
      return [];
    }
  }
  function renderState(values) {
    const rs = new XRRenderState(INTERNAL);
    state.set(rs, values);
    return rs;
  }

  class XRSessionEvent extends Event {
    constructor(type, init = {}) {
      super(type, init);
      this.session = init.session;
    }
  }
  class XRReferenceSpaceEvent extends Event {
    constructor(type, init = {}) {
      super(type, init);
      this.referenceSpace = init.referenceSpace;
      this.transform = init.transform ?? null;
    }
  }

  // --- the frame: poses and CPU depth -------------------------------------------------------

  class XRFrame {
    constructor(token) {
      if (token !== INTERNAL) throw illegal();
    }
    get session() {
      return slots(this).session;
    }
    get predictedDisplayTime() {
      return slots(this).time;
    }
    getViewerPose(referenceSpace) {
      const s = checkFrame(this, "getViewerPose");
      const pose = new XRViewerPose(INTERNAL);
      const { depthNear, depthFar } = slots(slots(s.session).renderState);
      const views = CONFIG.views.map((spec, index) => {
        const view = new XRView(INTERNAL);
        state.set(view, {
          frame: this,
          session: s.session,
          eye: spec.eye,
          index,
          referenceSpace,
          transform: rigid(poseIn(referenceSpace, s, s.data.views[index])),
          pinhole: spec.pinhole,
          near: depthNear,
          far: depthFar,
        });
        return view;
      });
      state.set(pose, { transform: rigid(poseIn(referenceSpace, s, s.viewer)), views: Object.freeze(views) });
      return pose;
    }
    getPose(space, baseSpace) {
      const s = checkFrame(this, "getPose");
      const pose = new XRPose(INTERNAL);
      const relative = compose(invert(effectiveOrigin(baseSpace, s)), effectiveOrigin(space, s));
      state.set(pose, { transform: rigid(relative) });
      return pose;
    }
    /** Depth sensing, "obtain CPU depth information": the checks in the spec's order. */
    getDepthInformation(view) {
      const s = slots(this);
      if (!enabled(s.session, "depth-sensing")) throw domError("NotSupportedError", "depth-sensing is not enabled");
      if (!s.active || !s.animationFrame) throw domError("InvalidStateError", "getDepthInformation: the frame is not active");
      if (slots(view).frame !== this) throw domError("InvalidStateError", "getDepthInformation: the view is not from this frame");
      const session = slots(s.session);
      if (session.depth.usage !== "cpu-optimized") throw domError("InvalidStateError", "getDepthInformation needs cpu-optimized depth");
      if (!session.depthActive) return null;
      return cpuDepthInformation(this, view);
    }
  }

  function checkFrame(frame, what) {
    const s = slots(frame);
    // WebXR getViewerPose / getPose: "If frame's active boolean is false, throw an
    // InvalidStateError"; likewise when it is not an animationFrame.
    if (!s.active || !s.animationFrame) throw domError("InvalidStateError", `XRFrame.${what}: the frame is not active`);
    return s;
  }

  class XRDepthInformation {
    constructor(token) {
      if (token !== INTERNAL) throw illegal();
    }
    get width() {
      return slots(this).width;
    }
    get height() {
      return slots(this).height;
    }
    get normDepthBufferFromNormView() {
      return slots(this).normDepthBufferFromNormView;
    }
    get rawValueToMeters() {
      return slots(this).rawValueToMeters;
    }
    /** Depth sensing: "XRDepthInformation includes XRViewGeometry"; "the transform [is set] to
     * the sensor's pose at time in view's reference space", and "If the sensor is aligned with
     * the associated view, then all values included from XRViewGeometry MUST return the same
     * values as the associated view does." */
    get transform() {
      return slots(this).transform;
    }
    get projectionMatrix() {
      return slots(this).projectionMatrix;
    }
  }

  /** Depth sensing, "attempt to access the depth buffer": the frame must be active and an
   * animation frame. */
  function accessDepthBuffer(info) {
    const s = slots(info);
    const frame = slots(s.frame);
    if (!frame.active || !frame.animationFrame) throw domError("InvalidStateError", "the depth buffer is only valid during its XR frame's callback");
    return s;
  }

  class XRCPUDepthInformation extends XRDepthInformation {
    /** Depth sensing: "The data is stored in row-major format, without padding, with each entry
     * corresponding to distance from the sensor's near plane to the users' environment, in
     * unspecified units ... converted ... to meters by multiplying them by rawValueToMeters".
     * The phone's units: millimetres for 16-bit formats (rawValueToMeters 0.001), metres for
     * float32; the distance is the z-depth ("the depth value does NOT represent the length of
     * aA vector"). */
    get data() {
      return accessDepthBuffer(this).data;
    }
    /** Depth sensing, "obtain depth at coordinates", step by step. */
    getDepthInMeters(x, y) {
      const s = accessDepthBuffer(this);
      if (!(x >= 0 && x <= 1)) throw new RangeError("getDepthInMeters: x must be in [0, 1]");
      if (!(y >= 0 && y <= 1)) throw new RangeError("getDepthInMeters: y must be in [0, 1]");
      const m = s.normDepthBufferFromNormView.matrix;
      const nx = m[0] * x + m[4] * y + m[12];
      const ny = m[1] * x + m[5] * y + m[13];
      const column = Math.min(Math.max(Math.trunc(nx * s.width), 0), s.width - 1);
      const row = Math.min(Math.max(Math.trunc(ny * s.height), 0), s.height - 1);
      const index = row * s.width + column;
      const raw = s.format === "float32" ? new Float32Array(s.data)[index] : new Uint16Array(s.data)[index];
      return raw * s.rawValueToMeters;
    }
  }

  class XRWebGLDepthInformation extends XRDepthInformation {
    get texture() {
      return accessDepthBuffer(this).texture;
    }
    get textureType() {
      return slots(this).textureType;
    }
    get imageIndex() {
      return slots(this).imageIndex;
    }
    /** Not in the spec: Quest Browser's planes of the depth data (immersive-web/depth-sensing#43,
     * "we need to communicate the near and far clip plane"; three.js and IWER read them).
     * Infinity for an infinite far plane. */
    get depthNear() {
      return slots(this).depthNear;
    }
    get depthFar() {
      return slots(this).depthFar;
    }
  }

  const BYTES_PER_ENTRY = { "luminance-alpha": 2, "unsigned-short": 2, float32: 4 };

  /** The phone: 16-bit formats in millimetres (ARCore's unit), float32 in metres. The Quest: the
   * values are window-space depth (see windowDepthLayer); float32 reports 1 as IWER does, and
   * the 16-bit formats scale back to [0, 1] -- not metres either way. */
  const rawValueToMeters = (format) => (format === "float32" ? 1 : CONFIG.depth.rawValueToMeters16);

  /** The scene frame whose depth a frame gets. Depth sensing: with matchDepthView true "the
   * XRSystem SHOULD return depth information that reflects the current frame. If this is
   * false, the XRSystem MAY return depth information that was captured at an earlier point in
   * time" -- here depth.staleSceneFrames earlier, with that moment's sensor pose as its
   * transform ("the sensor's pose at time"). */
  function depthSource(frame) {
    const f = slots(frame);
    const stale = CONFIG.depth.staleSceneFrames ?? 0;
    if (slots(f.session).depth.matchDepthView !== false || !stale) return f.data;
    return loader.ready(Math.max(0, f.data.index - stale)) ?? f.data;
  }

  /** The phone's depth, aligned with its one view: the same transform and projection (unless
   * it is an earlier frame's, see depthSource). */
  function cpuDepthInformation(frame, view) {
    const f = slots(frame);
    const v = slots(view);
    const session = slots(f.session);
    const format = session.depth.format;
    const source = depthSource(frame);
    const info = new XRCPUDepthInformation(INTERNAL);
    state.set(info, {
      frame,
      view,
      format,
      width: CONFIG.depth.width,
      height: CONFIG.depth.height,
      normDepthBufferFromNormView: rigid(poseOf(CONFIG.depth.normDepthBufferFromNormView)),
      rawValueToMeters: rawValueToMeters(format),
      data: cpuDepthBuffer(source, v.index, format).slice(0), // [SameObject], the page's own copy
      transform: source === f.data ? view.transform : rigid(poseIn(v.referenceSpace, f, source.depthSensors[v.index])),
      projectionMatrix: view.projectionMatrix,
    });
    return info;
  }

  function cpuDepthBuffer(data, index, format) {
    const key = `cpu:${format}:${index}`;
    if (!data.encoded[key]) {
      const metres = data.depth[index];
      let out;
      if (format === "float32") out = Float32Array.from(metres);
      else {
        const scale = 1 / CONFIG.depth.rawValueToMeters16;
        out = new Uint16Array(metres.length);
        for (let i = 0; i < metres.length; i++) out[i] = Math.min(65535, Math.round(metres[i] * scale));
      }
      data.encoded[key] = out.buffer;
    }
    return data.encoded[key];
  }

  /** Quest depth for one view, as a layer of a texture array. What the texels hold: OpenXR
   * XR_META_environment_depth (the runtime under Quest Browser) says "Depth is provided as
   * textures in the same format as described in the XR_KHR_composition_layer_depth extension.
   * The frustum's Z-planes are placed at nearZ and farZ meters. When farZ is less than nearZ,
   * an infinite projection matrix is used" -- window-space depth in [0, 1], not metres, whatever
   * the depth-sensing spec says about rawValueToMeters; IWER (Meta's emulator) fills its texture
   * with 1 - depthNear / z (the infinite case) and three.js writes the texel straight into
   * gl_FragDepth. Rows: OpenXR's depth view "is never flipped horizontally nor vertically" and
   * GL textures start at the bottom row; IWER flips its rows so, and three.js samples the
   * texture at gl_FragCoord / size (bottom-left origin) while Quest Browser's
   * normDepthBufferFromNormView is the identity ("Quest browser always returns the identity
   * matrix", immersive-web/depth-sensing#37). So texel row 0 is the bottom of the depth view when
   * depth.bottomRowFirst (the default), although the identity transform read literally would
   * put the view's top there. To metres: z = near / (1 - d) (infinite far) or
   * z = far * near / (far - d * (far - near)), or un-project (2x - 1, 1 - 2y, 2d - 1) with the
   * inverse of the depth information's own projectionMatrix. */
  function windowDepthLayer(data, index) {
    const key = `gpu:${index}`;
    if (!data.encoded[key]) {
      const { width, height, near, far, bottomRowFirst } = CONFIG.depth;
      const metres = data.depth[index];
      const out = new Float32Array(width * height);
      for (let row = 0; row < height; row++) {
        const from = bottomRowFirst ? height - 1 - row : row;
        for (let col = 0; col < width; col++) out[row * width + col] = windowDepth(metres[from * width + col], near, far);
      }
      data.encoded[key] = out;
    }
    return data.encoded[key];
  }

  function gpuDepthInformation(binding, frame, view) {
    const f = slots(frame);
    const v = slots(view);
    const session = slots(f.session);
    const format = session.depth.format;
    const { near, far, width, height } = CONFIG.depth;
    const source = depthSource(frame);
    const aligned = CONFIG.depth.alignedWithView && source === f.data;
    const info = new XRWebGLDepthInformation(INTERNAL);
    const sensor = poseIn(v.referenceSpace, f, source.depthSensors[v.index]);
    state.set(info, {
      frame,
      view,
      format,
      width,
      height,
      normDepthBufferFromNormView: rigid(poseOf(CONFIG.depth.normDepthBufferFromNormView)),
      rawValueToMeters: rawValueToMeters(format),
      texture: depthTexture(binding, frame, source, format),
      textureType: CONFIG.depth.textureType ?? "texture",
      // Depth sensing: imageIndex is 1 for the right eye's view and 0 otherwise.
      imageIndex: (CONFIG.depth.textureType ?? "texture") === "texture-array" ? (v.eye === "right" ? 1 : 0) : null,
      depthNear: near,
      depthFar: far === null || far === undefined ? Infinity : far,
      transform: aligned ? view.transform : rigid(sensor),
      projectionMatrix: aligned ? view.projectionMatrix : projectionOf(CONFIG.depth.pinholes[v.index], near, far),
    });
    return info;
  }

  // --- WebGL: layers, bindings, opaque textures ----------------------------------------------

  const xrCompatible = new WeakSet();
  const opaqueTextures = new WeakSet();
  const isGL2 = (gl) => typeof WebGL2RenderingContext !== "undefined" && gl instanceof WebGL2RenderingContext;
  const isGL = (gl) => isGL2(gl) || (typeof WebGLRenderingContext !== "undefined" && gl instanceof WebGLRenderingContext);

  /** Run fn with GL state it changes saved and restored, so the page's state is untouched. */
  function preserving(gl, fn) {
    const gl2 = isGL2(gl);
    const get = (p) => gl.getParameter(p);
    const saved = {
      tex2d: get(gl.TEXTURE_BINDING_2D),
      tex2dArray: gl2 ? get(gl.TEXTURE_BINDING_2D_ARRAY) : null,
      drawFb: get(gl2 ? gl.DRAW_FRAMEBUFFER_BINDING : gl.FRAMEBUFFER_BINDING),
      readFb: gl2 ? get(gl.READ_FRAMEBUFFER_BINDING) : null,
      renderbuffer: get(gl.RENDERBUFFER_BINDING),
      unpackBuffer: gl2 ? get(gl.PIXEL_UNPACK_BUFFER_BINDING) : null,
      packBuffer: gl2 ? get(gl.PIXEL_PACK_BUFFER_BINDING) : null,
      pixelStore: [
        gl.UNPACK_ALIGNMENT,
        gl.PACK_ALIGNMENT,
        gl.UNPACK_FLIP_Y_WEBGL,
        gl.UNPACK_PREMULTIPLY_ALPHA_WEBGL,
        gl.UNPACK_COLORSPACE_CONVERSION_WEBGL,
        ...(gl2
          ? [gl.UNPACK_ROW_LENGTH, gl.UNPACK_IMAGE_HEIGHT, gl.UNPACK_SKIP_PIXELS, gl.UNPACK_SKIP_ROWS, gl.UNPACK_SKIP_IMAGES, gl.PACK_ROW_LENGTH, gl.PACK_SKIP_PIXELS, gl.PACK_SKIP_ROWS]
          : []),
      ].map((p) => [p, get(p)]),
      clearColor: get(gl.COLOR_CLEAR_VALUE),
      clearDepth: get(gl.DEPTH_CLEAR_VALUE),
      clearStencil: get(gl.STENCIL_CLEAR_VALUE),
      colorMask: get(gl.COLOR_WRITEMASK),
      depthMask: get(gl.DEPTH_WRITEMASK),
      stencilMask: get(gl.STENCIL_WRITEMASK),
      scissor: gl.isEnabled(gl.SCISSOR_TEST),
    };
    // Neutral state for our own uploads and reads.
    if (gl2) {
      gl.bindBuffer(gl.PIXEL_UNPACK_BUFFER, null);
      gl.bindBuffer(gl.PIXEL_PACK_BUFFER, null);
      for (const p of [gl.UNPACK_ROW_LENGTH, gl.UNPACK_IMAGE_HEIGHT, gl.UNPACK_SKIP_PIXELS, gl.UNPACK_SKIP_ROWS, gl.UNPACK_SKIP_IMAGES, gl.PACK_ROW_LENGTH, gl.PACK_SKIP_PIXELS, gl.PACK_SKIP_ROWS]) gl.pixelStorei(p, 0);
    }
    gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
    gl.pixelStorei(gl.PACK_ALIGNMENT, 1);
    gl.pixelStorei(gl.UNPACK_FLIP_Y_WEBGL, false);
    gl.pixelStorei(gl.UNPACK_PREMULTIPLY_ALPHA_WEBGL, false);
    gl.pixelStorei(gl.UNPACK_COLORSPACE_CONVERSION_WEBGL, gl.NONE);
    try {
      return fn();
    } finally {
      gl.bindTexture(gl.TEXTURE_2D, saved.tex2d);
      if (gl2) gl.bindTexture(gl.TEXTURE_2D_ARRAY, saved.tex2dArray);
      if (gl2) {
        gl.bindFramebuffer(gl.DRAW_FRAMEBUFFER, saved.drawFb);
        gl.bindFramebuffer(gl.READ_FRAMEBUFFER, saved.readFb);
        gl.bindBuffer(gl.PIXEL_UNPACK_BUFFER, saved.unpackBuffer);
        gl.bindBuffer(gl.PIXEL_PACK_BUFFER, saved.packBuffer);
      } else gl.bindFramebuffer(gl.FRAMEBUFFER, saved.drawFb);
      gl.bindRenderbuffer(gl.RENDERBUFFER, saved.renderbuffer);
      for (const [p, value] of saved.pixelStore) gl.pixelStorei(p, value);
      gl.clearColor(...saved.clearColor);
      gl.clearDepth(saved.clearDepth);
      gl.clearStencil(saved.clearStencil);
      gl.colorMask(...saved.colorMask);
      gl.depthMask(saved.depthMask);
      gl.stencilMask(saved.stencilMask);
      if (saved.scissor) gl.enable(gl.SCISSOR_TEST);
      else gl.disable(gl.SCISSOR_TEST);
    }
  }

  class XRWebGLLayer {
    /** WebXR: an XRWebGLLayer gets "an opaque framebuffer with the dimensions framebufferSize";
     * ours is a plain framebuffer (colour texture + depth/stencil renderbuffer) the runtime
     * clears before each XR frame and composites after it. */
    constructor(session, context, init = {}) {
      const ss = slots(session);
      if (!ss || ss.ended) throw domError("InvalidStateError", "XRWebGLLayer: the session has ended");
      if (!isGL(context)) throw new TypeError("XRWebGLLayer: context must be a WebGL(2)RenderingContext");
      if (context.isContextLost()) throw domError("InvalidStateError", "XRWebGLLayer: the context is lost");
      // WebXR: "If context's XR compatible boolean is false, throw an InvalidStateError".
      if (!xrCompatible.has(context) && !context.getContextAttributes()?.xrCompatible)
        throw domError("InvalidStateError", "XRWebGLLayer: the context is not XR compatible (makeXRCompatible() or getContext(..., {xrCompatible: true}))");
      const options = { antialias: true, depth: true, stencil: false, alpha: true, ignoreDepthValues: false, framebufferScaleFactor: 1, ...init };
      const scale = Math.min(Math.max(options.framebufferScaleFactor, 0.2), 1);
      const width = Math.round(CONFIG.framebuffer[0] * scale);
      const height = Math.round(CONFIG.framebuffer[1] * scale);
      const gl = context;
      const made = preserving(gl, () => {
        const framebuffer = gl.createFramebuffer();
        const color = gl.createTexture();
        gl.bindTexture(gl.TEXTURE_2D, color);
        gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA, width, height, 0, gl.RGBA, gl.UNSIGNED_BYTE, null);
        gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.LINEAR);
        gl.bindFramebuffer(gl.FRAMEBUFFER, framebuffer);
        gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, color, 0);
        let depth = null;
        if (options.depth || options.stencil) {
          depth = gl.createRenderbuffer();
          gl.bindRenderbuffer(gl.RENDERBUFFER, depth);
          const both = options.depth && options.stencil;
          const format = isGL2(gl) ? (options.stencil ? gl.DEPTH24_STENCIL8 : gl.DEPTH_COMPONENT24) : options.stencil ? gl.DEPTH_STENCIL : gl.DEPTH_COMPONENT16;
          const attachment = options.stencil ? (both || isGL2(gl) ? gl.DEPTH_STENCIL_ATTACHMENT : gl.STENCIL_ATTACHMENT) : gl.DEPTH_ATTACHMENT;
          gl.renderbufferStorage(gl.RENDERBUFFER, format, width, height);
          gl.framebufferRenderbuffer(gl.FRAMEBUFFER, attachment, gl.RENDERBUFFER, depth);
        }
        return { framebuffer, color, depth };
      });
      state.set(this, { session, gl, options, width, height, scale, ...made, pixels: null });
    }
    get antialias() {
      return slots(this).options.antialias;
    }
    get ignoreDepthValues() {
      return slots(this).options.ignoreDepthValues;
    }
    get fixedFoveation() {
      return null;
    }
    set fixedFoveation(_) {}
    get framebuffer() {
      return slots(this).framebuffer;
    }
    get framebufferWidth() {
      return slots(this).width;
    }
    get framebufferHeight() {
      return slots(this).height;
    }
    getViewport(view) {
      const s = slots(this);
      const v = slots(view);
      if (v.session !== s.session) throw domError("InvalidStateError", "getViewport: the view is from another session");
      if (!slots(v.frame).active) throw domError("InvalidStateError", "getViewport: the view's frame is not active");
      const viewport = new XRViewport(INTERNAL);
      state.set(viewport, CONFIG.views[v.index].viewport.map((n) => Math.round(n * s.scale)));
      return viewport;
    }
    static getNativeFramebufferScaleFactor() {
      return 1;
    }
  }

  class XRWebGLBinding {
    constructor(session, context) {
      const ss = slots(session);
      if (!ss || ss.ended) throw domError("InvalidStateError", "XRWebGLBinding: the session has ended");
      if (!isGL(context)) throw new TypeError("XRWebGLBinding: context must be a WebGL(2)RenderingContext");
      if (!xrCompatible.has(context) && !context.getContextAttributes()?.xrCompatible)
        throw domError("InvalidStateError", "XRWebGLBinding: the context is not XR compatible");
      state.set(this, { session, gl: context, frameTextures: null });
    }
    get nativeProjectionScaleFactor() {
      return 1;
    }
    get usesDepthValues() {
      return false;
    }
    createProjectionLayer() {
      throw domError("NotSupportedError", "the fake XR device has no layers module");
    }
    /** Raw camera access, "obtain camera image", with its checks; the texture is an opaque
     * texture (WebXR Layers: "considered invalid outside of a requestAnimationFrame() callback
     * for its session"): deleted when the frame ends. Orientation: the spec leaves the texture's layout open ("Should we specify more
     * information about the returned WebGLTexture?"), but requires it "aligned" with the view
     * ("the camera pose is the same as the XRView's pose, and the camera's viewing frustum has
     * the same shape"); Chromium's camera-access-barebones sample derives intrinsics from the
     * projection matrix and the viewport in GL's bottom-left window convention, and clients
     * built on it that read the texture back note "Image is vertically flipped". So texel row 0
     * is the bottom row of the view, like a framebuffer rendered with the view's projection:
     * sample it at (x, 1 - y) for normalized view coordinates (x, y); readPixels gives the
     * bottom row first. RGBA8, opaque. */
    getCameraImage(camera) {
      const s = slots(this);
      const c = slots(camera);
      if (!c) throw new TypeError("getCameraImage: not an XRCamera");
      const view = slots(c.view);
      if (view.session !== s.session) throw domError("InvalidStateError", "getCameraImage: the camera is from another session");
      const frame = slots(view.frame);
      if (!frame.active || !frame.animationFrame) throw domError("InvalidStateError", "getCameraImage: the frame is not active");
      // "The user agent MAY cache the results ... keyed by the binding and the camera instance."
      const textures = frameTextures(this, view.frame);
      if (!textures.camera) {
        const gl = s.gl;
        textures.camera = preserving(gl, () => {
          const texture = gl.createTexture();
          gl.bindTexture(gl.TEXTURE_2D, texture);
          gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA, gl.RGBA, gl.UNSIGNED_BYTE, frame.data.images.camera);
          gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.LINEAR);
          gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
          gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
          gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
          return texture;
        });
        opaqueTextures.add(textures.camera);
      }
      return textures.camera;
    }
    /** Depth sensing, "obtain WebGL depth information": the checks in the spec's order. */
    getDepthInformation(view) {
      const s = slots(this);
      const v = slots(view);
      const frame = slots(v.frame);
      if (s.session !== frame.session) throw domError("InvalidStateError", "getDepthInformation: the view is from another session");
      if (!enabled(s.session, "depth-sensing")) throw domError("NotSupportedError", "depth-sensing is not enabled");
      const session = slots(s.session);
      if (session.depth.usage !== "gpu-optimized") throw domError("InvalidStateError", "XRWebGLBinding.getDepthInformation needs gpu-optimized depth");
      if (!frame.active || !frame.animationFrame) throw domError("InvalidStateError", "getDepthInformation: the frame is not active");
      if (!session.depthActive) return null;
      return gpuDepthInformation(this, v.frame, view);
    }
  }

  function frameTextures(binding, frame) {
    const s = slots(binding);
    const f = slots(frame);
    if (!s.frameTextures || s.frameTextures.frame !== frame) {
      s.frameTextures = { frame, camera: null, depth: null, gl: s.gl };
      f.textures.push(s.frameTextures);
    }
    return s.frameTextures;
  }

  const GPU_FORMATS = {
    float32: (gl) => [gl.R32F, gl.RED, gl.FLOAT],
    "unsigned-short": (gl) => [gl.R16UI, gl.RED_INTEGER, gl.UNSIGNED_SHORT],
    "luminance-alpha": (gl) => [gl.LUMINANCE_ALPHA, gl.LUMINANCE_ALPHA, gl.UNSIGNED_BYTE],
  };

  function depthTexture(binding, frame, source, format) {
    const textures = frameTextures(binding, frame);
    if (textures.depth) return textures.depth;
    const gl = slots(binding).gl;
    if (!isGL2(gl)) throw domError("InvalidStateError", "texture-array depth needs a WebGL2 context");
    const { width, height } = CONFIG.depth;
    const layers = CONFIG.views.map((_, index) => {
      const d = windowDepthLayer(source, index);
      if (format === "float32") return d;
      const u16 = new Uint16Array(d.length);
      for (let i = 0; i < d.length; i++) u16[i] = Math.round(d[i] / CONFIG.depth.rawValueToMeters16);
      return format === "luminance-alpha" ? new Uint8Array(u16.buffer) : u16;
    });
    textures.depth = preserving(gl, () => {
      const texture = gl.createTexture();
      const [internal, fmt, type] = GPU_FORMATS[format](gl);
      gl.bindTexture(gl.TEXTURE_2D_ARRAY, texture);
      gl.texImage3D(gl.TEXTURE_2D_ARRAY, 0, internal, width, height, layers.length, 0, fmt, type, null);
      layers.forEach((layer, i) => gl.texSubImage3D(gl.TEXTURE_2D_ARRAY, 0, 0, 0, i, width, height, 1, fmt, type, layer));
      gl.texParameteri(gl.TEXTURE_2D_ARRAY, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
      gl.texParameteri(gl.TEXTURE_2D_ARRAY, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
      gl.texParameteri(gl.TEXTURE_2D_ARRAY, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
      gl.texParameteri(gl.TEXTURE_2D_ARRAY, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
      return texture;
    });
    opaqueTextures.add(textures.depth);
    return textures.depth;
  }

  // --- sessions ------------------------------------------------------------------------------

  const enabled = (session, feature) => slots(session).features.includes(feature);
  const LOCAL_ORIGIN = poseOf(CONFIG.localOrigin);
  const DEFAULT_RESET = { position: [0.4, 0, -0.25], orientation: [0, Math.sin(Math.PI / 14.4), 0, Math.cos(Math.PI / 14.4)] };

  class XRSession extends EventTarget {
    constructor(token) {
      if (token !== INTERNAL) throw illegal();
      super();
    }
    get visibilityState() {
      return "visible";
    }
    get frameRate() {
      return 60;
    }
    get supportedFrameRates() {
      return new Float32Array([60]);
    }
    get renderState() {
      return slots(this).renderState;
    }
    get inputSources() {
      return slots(this).inputSources;
    }
    get enabledFeatures() {
      return slots(this).features;
    }
    get isSystemKeyboardSupported() {
      return false;
    }
    get environmentBlendMode() {
      return "alpha-blend";
    }
    get interactionMode() {
      return CONFIG.interactionMode;
    }
    get domOverlayState() {
      return slots(this).overlay ? { type: CONFIG.profile === "android" ? "screen" : "floating" } : null;
    }
    /** Depth sensing: these "MUST throw an InvalidStateError" without depth sensing enabled. */
    get depthUsage() {
      return depthState(this).usage;
    }
    get depthDataFormat() {
      return depthState(this).format;
    }
    get depthType() {
      return depthState(this).type;
    }
    get depthActive() {
      depthState(this);
      return slots(this).depthActive;
    }
    pauseDepthSensing() {
      depthState(this);
      slots(this).depthActive = false;
    }
    resumeDepthSensing() {
      depthState(this);
      slots(this).depthActive = true;
    }
    updateRenderState(init = {}) {
      const s = slots(this);
      if (s.ended) throw domError("InvalidStateError", "updateRenderState: the session has ended");
      if (init.baseLayer && slots(init.baseLayer).session !== this) throw domError("InvalidStateError", "updateRenderState: the layer belongs to another session");
      if (init.inlineVerticalFieldOfView !== undefined && init.inlineVerticalFieldOfView !== null) throw domError("InvalidStateError", "inlineVerticalFieldOfView is for inline sessions");
      // WebXR, "update the pending layers state": layers not null -> NotSupportedError.
      if (init.layers !== undefined && init.layers !== null) throw domError("NotSupportedError", "the fake XR device has no layers module");
      const base = s.pending ?? { ...slots(s.renderState) };
      for (const key of ["depthNear", "depthFar", "baseLayer"]) if (init[key] !== undefined) base[key] = init[key];
      s.pending = base;
    }
    updateTargetFrameRate() {
      return Promise.resolve();
    }
    requestReferenceSpace(type) {
      const s = slots(this);
      return new Promise((resolve, reject) =>
        setTimeout(() => {
          if (s.ended) reject(domError("InvalidStateError", "requestReferenceSpace: the session has ended"));
          // WebXR, "reference space is supported": the type must be a granted feature.
          else if (!["viewer", "local", "local-floor"].includes(type) || !s.features.includes(type))
            reject(domError("NotSupportedError", `reference space '${type}' is not supported (granted: ${s.features.join(", ")})`));
          else resolve(newReferenceSpace(this, type));
        }),
      );
    }
    requestAnimationFrame(callback) {
      const s = slots(this);
      if (s.ended) return 0;
      const id = ++s.nextCallbackId;
      s.callbacks.push({ id, callback });
      return id;
    }
    cancelAnimationFrame(id) {
      const s = slots(this);
      s.callbacks = s.callbacks.filter((c) => c.id !== id);
      if (s.running) s.running.forEach((c) => c.id === id && (c.cancelled = true));
    }
    requestHitTestSource() {
      return Promise.reject(domError("NotSupportedError", "hit-test is not supported by the fake XR device"));
    }
    end() {
      const s = slots(this);
      if (s.ended) return Promise.reject(domError("InvalidStateError", "end: the session has already ended"));
      shutDown(this);
      return new Promise((resolve) => setTimeout(resolve));
    }
  }
  defineEventHandlers(XRSession, ["end", "select", "selectstart", "selectend", "squeeze", "squeezestart", "squeezeend", "inputsourceschange", "visibilitychange", "frameratechange"]);

  function depthState(session) {
    const s = slots(session);
    if (!s.features.includes("depth-sensing")) throw domError("InvalidStateError", "depth sensing is not enabled on this session");
    return s.depth;
  }

  /** WebXR, "shut down the session": ended, no more frames, an 'end' XRSessionEvent. */
  function shutDown(session) {
    const s = slots(session);
    s.ended = true;
    s.callbacks = [];
    runtime.session = null;
    display.hide();
    if (s.overlay) s.overlay.root.style.cssText = s.overlay.css;
    setTimeout(() => session.dispatchEvent(new XRSessionEvent("end", { session })));
  }

  /** Depth sensing, "find supported configuration combination", step by step. */
  function findDepthConfiguration(init) {
    const device = CONFIG.depth;
    const supported = [["raw", "smooth"], device.usages, device.formats];
    const preferred = ["raw", device.usages[0], device.preferredFormat];
    let requests = [init.depthTypeRequest ?? [], init.usagePreference ?? [], init.dataFormatPreference ?? []];
    for (;;) {
      const selection = [null, null, null];
      requests.forEach((list, i) => list.length === 1 && (selection[i] = list[0]));
      requests.forEach((list, i) => {
        if (selection[i] === null) selection[i] = list.find((v) => supported[i].includes(v)) ?? null;
      });
      selection.forEach((v, i) => v === null && (selection[i] = preferred[i]));
      if (selection.every((v, i) => supported[i].includes(v))) return { type: selection[0], usage: selection[1], format: selection[2] };
      if (!requests[0].length) return null;
      requests = [[], requests[1], requests[2]];
    }
  }

  class XRSystem extends EventTarget {
    constructor(token) {
      if (token !== INTERNAL) throw illegal();
      super();
    }
    isSessionSupported(mode) {
      return Promise.resolve(mode === "immersive-ar");
    }
    requestSession(mode, init = {}) {
      const activated = navigator.userActivation ? navigator.userActivation.isActive : true;
      return new Promise((resolve, reject) => {
        if (mode !== "immersive-ar") return reject(domError("NotSupportedError", `the fake XR device (${CONFIG.profile}) supports immersive-ar only, not '${mode}'`));
        // WebXR, "immersive session request is allowed": false "If the request was not made
        // while the global object has transient activation" (a SecurityError); a request while
        // another immersive session is pending or active is an InvalidStateError.
        if (CONFIG.requireUserActivation && !activated) return reject(domError("SecurityError", "requestSession('immersive-ar') needs user activation"));
        if (runtime.session || runtime.pending) return reject(domError("InvalidStateError", "an immersive session is already active"));
        const required = [...new Set(["viewer", "local", ...(init.requiredFeatures ?? [])])];
        const optional = [...new Set(init.optionalFeatures ?? [])];
        let depth = null;
        const grant = (feature) => {
          if (!CONFIG.features.includes(feature)) return false;
          if (feature === "depth-sensing") {
            // Depth sensing: without a depthSensing key, or with no supported configuration, a
            // required feature is unresolved and an optional one is ignored.
            depth = init.depthSensing ? findDepthConfiguration(init.depthSensing) : null;
            if (depth) depth.matchDepthView = init.depthSensing.matchDepthView !== false;
            return depth !== null;
          }
          if (feature === "dom-overlay") return !!(init.domOverlay && init.domOverlay.root);
          return true;
        };
        const granted = [];
        for (const feature of required) {
          // WebXR: "If any feature listed in the requiredFeatures array is not supported by the
          // XR device ... the XRSession will not be created" (NotSupportedError); unknown or
          // unsupported optional features are ignored.
          if (!grant(feature)) return reject(domError("NotSupportedError", `required feature '${feature}' is not supported by the fake ${CONFIG.profile} device`));
          granted.push(feature);
        }
        for (const feature of optional) if (!granted.includes(feature) && grant(feature)) granted.push(feature);
        runtime.pending = true;
        setTimeout(() => {
          runtime.pending = false;
          resolve(startSession(granted, depth, init));
        });
      });
    }
  }
  defineEventHandlers(XRSystem, ["devicechange"]);

  function startSession(features, depth, init) {
    const session = new XRSession(INTERNAL);
    const inputSources = Object.freeze([]);
    let overlay = null;
    if (features.includes("dom-overlay")) {
      const root = init.domOverlay.root;
      overlay = { root, css: root.style.cssText };
      // DOM overlay: the root is shown over the immersive content (the UA's :xr-overlay style).
      root.style.cssText += ";position:fixed;inset:0;z-index:2147483001;background:transparent";
    }
    state.set(session, {
      features: Object.freeze(features),
      depth: depth ?? {},
      depthActive: true,
      renderState: renderState({ depthNear: 0.1, depthFar: 1000, baseLayer: null }),
      pending: null,
      callbacks: [],
      running: null,
      nextCallbackId: 0,
      ended: false,
      spaces: new Set(),
      trackingShift: IDENTITY,
      inputSources,
      overlay,
    });
    runtime.begin(session);
    return session;
  }

  // --- scene frames from the feed ---------------------------------------------------------

  class FrameLoader {
    constructor() {
      this.entries = new Map();
      this.inflight = 0;
    }
    request(index) {
      if (index < 0 || index >= CONFIG.frameCount || this.entries.has(index)) return;
      const entry = { ready: false, data: null };
      this.entries.set(index, entry);
      this.load(index).then(
        (data) => Object.assign(entry, { ready: true, data }),
        (error) => {
          const message = `fakeXR: scene frame ${index}: ${error && error.message ? error.message : error}`;
          api.errors.push(message);
          console.error(message);
        },
      );
    }
    prefetch(from) {
      for (let i = from; i < from + CONFIG.prefetch; i++) this.request(i);
      for (const [index, entry] of this.entries)
        if (index < from - 2 - CONFIG.videoDelaySceneFrames && entry.ready) {
          Object.values(entry.data.images).forEach((bitmap) => bitmap.close());
          this.entries.delete(index);
        }
    }
    ready(index) {
      const entry = this.entries.get(index);
      return entry && entry.ready ? entry.data : null;
    }
    async load(index) {
      const response = await fetch(`${CONFIG.routePrefix}frame/${index}`, { cache: "no-store" });
      if (!response.ok) throw new Error(`HTTP ${response.status}`);
      const bytes = new Uint8Array(await response.arrayBuffer());
      if (String.fromCharCode(...bytes.subarray(0, 4)) !== "FXR1") throw new Error("not a fake XR frame");
      const headerLength = new DataView(bytes.buffer).getUint32(4, true);
      const header = JSON.parse(new TextDecoder().decode(bytes.subarray(8, 8 + headerLength)));
      const base = 8 + headerLength;
      const blob = (name) => bytes.subarray(base + header.blobs[name].offset, base + header.blobs[name].offset + header.blobs[name].length);
      const images = {};
      const decodes = Object.keys(header.blobs)
        .filter((name) => !name.startsWith("depth"))
        .map(async (name) => {
          // The phone's camera image is kept bottom row first, as getCameraImage's texture
          // holds it (see getCameraImage); everything else top row first.
          const flip = name === "camera" && CONFIG.profile === "android";
          images[name] = await createImageBitmap(new Blob([blob(name)], { type: "image/png" }), {
            imageOrientation: flip ? "flipY" : "from-image",
            premultiplyAlpha: "none",
            colorSpaceConversion: "none",
          });
        });
      const depth = await Promise.all(
        Object.keys(header.blobs)
          .filter((name) => name.startsWith("depth"))
          .sort()
          .map(async (name) => {
            const stream = new Blob([blob(name)]).stream().pipeThrough(new DecompressionStream("deflate"));
            const units = new Uint16Array(await new Response(stream).arrayBuffer());
            const metres = new Float32Array(units.length);
            const unit = header.blobs[name].unit_m;
            for (let i = 0; i < units.length; i++) metres[i] = units[i] * unit;
            return metres;
          }),
      );
      await Promise.all(decodes);
      return {
        index,
        t_s: header.t_s,
        viewer: poseOf(header.viewer),
        views: header.views.map(poseOf),
        camera: poseOf(header.camera),
        depthSensors: header.depthSensors.map(poseOf),
        images,
        depth,
        encoded: {},
      };
    }
  }

  // --- what the user sees: passthrough + the app's layer ---------------------------------------

  const display = {
    canvas: null,
    image: null,
    show() {
      if (!CONFIG.display || this.canvas) return;
      const [w, h] = CONFIG.framebuffer;
      this.canvas = Object.assign(document.createElement("canvas"), { width: w, height: h, id: "fakexr-display" });
      this.canvas.style.cssText = "position:fixed;inset:0;width:100vw;height:100vh;object-fit:contain;background:#000;z-index:2147483000;pointer-events:none";
      (document.body || document.documentElement).appendChild(this.canvas);
    },
    hide() {
      if (this.canvas) this.canvas.remove();
      this.canvas = null;
    },
    /** RGBA, top row first, of what the device's cameras show in each view's viewport (cached
     * per scene frame). A software canvas: SwiftShader's 2D canvas takes ~30 ms a draw. */
    passthrough(data, width, height) {
      const key = `${width}x${height}`;
      if (data.passthrough && data.passthrough.key === key) return data.passthrough.pixels;
      const canvas = new OffscreenCanvas(width, height);
      const ctx = canvas.getContext("2d", { willReadFrequently: true });
      const [W, H] = CONFIG.framebuffer;
      ctx.scale(width / W, height / H);
      CONFIG.views.forEach((view, k) => {
        const [x, y, w, h] = view.viewport;
        const top = H - (y + h); // viewports are in GL window coordinates
        if (CONFIG.profile === "android") {
          ctx.save();
          ctx.translate(0, 2 * top + h);
          ctx.scale(1, -1); // the camera bitmap is stored bottom row first
          ctx.drawImage(data.images.camera, x, top, w, h);
          ctx.restore();
        } else if (data.images[`eye${k}`]) ctx.drawImage(data.images[`eye${k}`], x, top, w, h);
      });
      data.passthrough = { key, pixels: ctx.getImageData(0, 0, width, height).data };
      return data.passthrough.pixels;
    },
    /** The layer over the passthrough. WebXR: "The XR Compositor will assume the opaque
     * framebuffer contains colors with premultiplied alpha": out = layer + (1 - a) * camera. */
    composite(data, layer) {
      if (!this.canvas) return;
      const s = layer ? slots(layer) : null;
      const [layerWidth, layerHeight] = s ? [s.width, s.height] : CONFIG.framebuffer;
      const scale = CONFIG.displayScale ?? 1;
      const width = Math.max(1, Math.round(layerWidth * scale));
      const height = Math.max(1, Math.round(layerHeight * scale));
      if (this.canvas.width !== width || this.canvas.height !== height) Object.assign(this.canvas, { width, height });
      const background = this.passthrough(data, width, height);
      if (!this.image || this.image.width !== width || this.image.height !== height) this.image = new ImageData(width, height);
      const out = this.image.data;
      if (!s) out.set(background);
      else {
        const gl = s.gl;
        s.pixels ??= new Uint8Array(layerWidth * layerHeight * 4);
        preserving(gl, () => {
          gl.bindFramebuffer(gl.FRAMEBUFFER, s.framebuffer);
          gl.readPixels(0, 0, layerWidth, layerHeight, gl.RGBA, gl.UNSIGNED_BYTE, s.pixels);
        });
        const px = s.pixels;
        const opaque = !s.options.alpha;
        const sourceColumn = Array.from({ length: width }, (_, col) => Math.min(layerWidth - 1, Math.floor(col / scale)) * 4);
        for (let row = 0; row < height; row++) {
          let i = row * width * 4;
          // readPixels gives the bottom row first
          const sourceRow = (layerHeight - 1 - Math.min(layerHeight - 1, Math.floor(row / scale))) * layerWidth * 4;
          for (let col = 0; col < width; col++, i += 4) {
            const j = sourceRow + sourceColumn[col];
            const a = opaque ? 255 : px[j + 3];
            if (a === 0) {
              out[i] = background[i];
              out[i + 1] = background[i + 1];
              out[i + 2] = background[i + 2];
            } else if (a === 255) {
              out[i] = px[j];
              out[i + 1] = px[j + 1];
              out[i + 2] = px[j + 2];
            } else {
              const rest = (255 - a) / 255;
              out[i] = px[j] + background[i] * rest;
              out[i + 1] = px[j + 1] + background[i + 1] * rest;
              out[i + 2] = px[j + 2] + background[i + 2] * rest;
            }
            out[i + 3] = 255;
          }
        }
      }
      this.canvas.getContext("2d").putImageData(this.image, 0, 0);
    },
  };

  /** The Quest's passthrough camera as getUserMedia gives it: a canvas stream showing the
   * colour camera's image of the scene frame the headset is at (minus videoDelaySceneFrames). */
  const video = {
    canvas: null,
    track: null,
    lastPush: -Infinity,
    shownFrame: -1,
    stream() {
      if (!this.canvas) {
        const { width, height } = CONFIG.userMedia;
        this.canvas = Object.assign(document.createElement("canvas"), { width, height });
        this.track = this.canvas.captureStream(0).getVideoTracks()[0];
        loader.prefetch(0);
        runtime.startLoop();
      }
      return new MediaStream([this.track.clone()]);
    },
    tick(time) {
      if (!this.canvas) return;
      const wanted = Math.max(0, runtime.sceneFrame - CONFIG.videoDelaySceneFrames);
      const data = loader.ready(wanted);
      const changed = data && wanted !== this.shownFrame;
      if (!changed && time - this.lastPush < 1000 / CONFIG.videoFps) return;
      if (changed) this.shownFrame = wanted;
      const shown = loader.ready(this.shownFrame);
      if (!shown) return;
      // A camera delivers frames at its rate whether or not the scene changed; a canvas track
      // only captures a canvas drawn since its last frame, so draw it again each time.
      this.canvas.getContext("2d").drawImage(shown.images.camera, 0, 0, this.canvas.width, this.canvas.height);
      this.track.requestFrame();
      this.lastPush = time;
      if (changed) api.videoLog.push({ time, sceneFrame: this.shownFrame });
    },
  };

  // --- the frame loop ------------------------------------------------------------------------

  const loader = new FrameLoader();
  const runtime = {
    session: null,
    pending: false,
    looping: false,
    xrFrame: 0,
    sceneFrame: 0,
    done: false,
    paused: false,
    stalls: 0,
    resets: [],
    waiters: [],
    begin(session) {
      this.session = session;
      this.xrFrame = 0;
      this.sceneFrame = 0;
      this.done = false;
      loader.prefetch(0);
      display.show();
      this.startLoop();
    },
    startLoop() {
      if (this.looping) return;
      this.looping = true;
      const tick = (time) => {
        requestAnimationFrame(tick);
        if (this.session && !this.paused) this.xrTick(time);
        video.tick(time);
      };
      requestAnimationFrame(tick);
    },
    xrTick(time) {
      const session = this.session;
      const s = slots(session);
      if (!s.callbacks.length) return; // no frame asked for: the walk waits
      const hold = CONFIG.xrFramesPerSceneFrame;
      let scene = Math.floor(this.xrFrame / hold);
      if (scene >= CONFIG.frameCount) {
        if (!this.done) {
          this.done = true;
          this.waiters.filter((w) => w.done).forEach((w) => w.resolve());
        }
        if (CONFIG.onWalkEnd === "end") return void session.end();
        scene = CONFIG.frameCount - 1;
      }
      loader.prefetch(scene);
      const data = loader.ready(scene);
      if (!data) {
        this.stalls++;
        return;
      }
      this.sceneFrame = scene;
      video.tick(time); // the camera stream turns to the new scene frame before the page's callbacks
      // WebXR: the pending render state is applied when the next animation frame starts.
      if (s.pending) {
        s.renderState = renderState(s.pending);
        s.pending = null;
      }
      this.applyReset(session);
      const layer = slots(s.renderState).baseLayer;
      if (layer) this.clearLayer(layer);
      const frame = new XRFrame(INTERNAL);
      state.set(frame, { session, time, data, viewer: data.viewer, active: true, animationFrame: true, textures: [] });
      const callbacks = s.callbacks;
      s.callbacks = [];
      s.running = callbacks;
      for (const entry of callbacks) {
        if (entry.cancelled) continue;
        try {
          entry.callback(time, frame);
        } catch (error) {
          report(error);
        }
      }
      s.running = null;
      const f = slots(frame);
      f.active = false;
      for (const t of f.textures) {
        // Opaque textures live only for their frame's callbacks.
        for (const texture of [t.camera, t.depth].filter(Boolean)) {
          opaqueTextures.delete(texture);
          t.gl.deleteTexture(texture);
        }
      }
      if (CONFIG.display && this.xrFrame % CONFIG.displayEvery === 0) display.composite(data, slots(s.renderState).baseLayer);
      api.frameLog.push({ xrFrame: this.xrFrame, time, sceneFrame: scene, sceneTime: data.t_s });
      this.xrFrame++;
      this.waiters = this.waiters.filter((w) => {
        if (w.scene === undefined || w.scene > scene) return true;
        w.resolve();
        return false;
      });
    },
    /** WebXR, opaque framebuffers: "The buffers attached to an opaque framebuffer MUST be
     * cleared to the values in the table below ... prior to the processing of each XR
     * animation frame" (colour 0, depth 1, stencil 0). */
    clearLayer(layer) {
      const s = slots(layer);
      const gl = s.gl;
      preserving(gl, () => {
        gl.bindFramebuffer(gl.FRAMEBUFFER, s.framebuffer);
        gl.disable(gl.SCISSOR_TEST);
        gl.colorMask(true, true, true, true);
        gl.depthMask(true);
        gl.stencilMask(0xffffffff);
        gl.clearColor(0, 0, 0, 0);
        gl.clearDepth(1);
        gl.clearStencil(0);
        gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT | gl.STENCIL_BUFFER_BIT);
      });
    },
    /** WebXR: a reset "MUST be dispatched prior to the execution of any XR animation frames
     * that make use of the new origin"; its transform is "the post-event position and
     * orientation of the referenceSpace's native origin in the pre-event coordinate system". */
    applyReset(session) {
      const s = slots(session);
      const pending = this.pendingResets ?? [];
      this.pendingResets = [];
      for (const shift of pending) {
        const before = new Map([...s.spaces].filter((sp) => slots(sp).type !== "viewer").map((sp) => [sp, effectiveOrigin(sp, null)]));
        s.trackingShift = compose(s.trackingShift, shift);
        this.resets.push({ xrFrame: this.xrFrame, transform: { position: shift.p, orientation: shift.q } });
        for (const [space, old] of before) {
          const moved = compose(invert(old), effectiveOrigin(space, null));
          space.dispatchEvent(new XRReferenceSpaceEvent("reset", { referenceSpace: space, transform: rigid(moved) }));
        }
      }
    },
  };

  const api = {
    config: CONFIG,
    frameLog: [],
    videoLog: [],
    errors: [],
    get session() {
      return runtime.session;
    },
    get xrFrames() {
      return runtime.xrFrame;
    },
    get sceneFrame() {
      return runtime.sceneFrame;
    },
    get done() {
      return runtime.done;
    },
    get stalls() {
      return runtime.stalls;
    },
    get paused() {
      return runtime.paused;
    },
    get resets() {
      return runtime.resets;
    },
    pause() {
      runtime.paused = true;
    },
    resume() {
      runtime.paused = false;
    },
    resetReferenceSpace(transform = DEFAULT_RESET) {
      (runtime.pendingResets ??= []).push(poseOf(transform));
    },
    whenSceneFrame(index) {
      if (runtime.xrFrame > 0 && runtime.sceneFrame >= index) return Promise.resolve();
      return new Promise((resolve) => runtime.waiters.push({ scene: index, resolve }));
    },
    whenDone() {
      if (runtime.done) return Promise.resolve();
      return new Promise((resolve) => runtime.waiters.push({ done: true, resolve }));
    },
  };

  // --- installation ----------------------------------------------------------------------------

  const xr = new XRSystem(INTERNAL);
  Object.defineProperty(navigator, "xr", { value: xr, configurable: true, enumerable: true });
  const classes = {
    XRSystem,
    XRSession,
    XRSessionEvent,
    XRFrame,
    XRSpace,
    XRReferenceSpace,
    XRReferenceSpaceEvent,
    XRRigidTransform,
    XRPose,
    XRViewerPose,
    XRView,
    XRViewport,
    XRRenderState,
    XRCamera,
    XRWebGLLayer,
    XRWebGLBinding,
    XRDepthInformation,
    XRCPUDepthInformation,
    XRWebGLDepthInformation,
  };
  for (const [name, cls] of Object.entries(classes)) Object.defineProperty(window, name, { value: cls, writable: true, configurable: true });

  // WebXR: makeXRCompatible() sets the context's XR compatible boolean; so does creating it
  // with {xrCompatible: true}.
  for (const proto of [window.WebGLRenderingContext, window.WebGL2RenderingContext].filter(Boolean).map((c) => c.prototype)) {
    Object.defineProperty(proto, "makeXRCompatible", {
      configurable: true,
      writable: true,
      value() {
        xrCompatible.add(this);
        return Promise.resolve();
      },
    });
  }
  // WebXR Layers: "A call to deleteTexture with an opaque texture MUST generate an
  // INVALID_OPERATION error" -- a script cannot raise a GL error, so it is reported instead.
  for (const proto of [window.WebGLRenderingContext, window.WebGL2RenderingContext].filter(Boolean).map((c) => c.prototype)) {
    const deleteTexture = proto.deleteTexture;
    proto.deleteTexture = function (texture) {
      if (texture && opaqueTextures.has(texture)) {
        const message = "fakeXR: deleteTexture on an XR opaque texture (INVALID_OPERATION on a device)";
        api.errors.push(message);
        console.error(message);
        return;
      }
      return deleteTexture.call(this, texture);
    };
  }
  for (const proto of [window.HTMLCanvasElement, window.OffscreenCanvas].filter(Boolean).map((c) => c.prototype)) {
    const getContext = proto.getContext;
    proto.getContext = function (type, attributes) {
      const context = getContext.call(this, type, attributes);
      if (context && attributes && attributes.xrCompatible && isGL(context)) xrCompatible.add(context);
      return context;
    };
  }

  if (CONFIG.userMedia && navigator.mediaDevices) {
    const devices = navigator.mediaDevices;
    devices.getUserMedia = (constraints = {}) => {
      if (!constraints.video && !constraints.audio) return Promise.reject(new TypeError("getUserMedia: ask for video"));
      if (constraints.audio) return Promise.reject(domError("NotFoundError", "the fake Quest has no microphone"));
      return Promise.resolve(video.stream());
    };
    devices.enumerateDevices = () =>
      Promise.resolve([{ deviceId: "fakexr-passthrough", groupId: "fakexr", kind: "videoinput", label: "Passthrough camera (fake XR)", toJSON() { return { ...this }; } }]);
  }

  Object.defineProperty(window, "fakeXR", { value: api, configurable: true });
})();
