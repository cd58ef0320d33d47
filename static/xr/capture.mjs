// The capture stage: per keyframe, colour + depth + the camera they belong to, through the
// standard WebXR surface only, so that any runtime written to the specs drives it.
//
// Two paths, chosen by what the XR session enabled:
// - "camera-access" (Chrome on Android): colour from WebXR Raw Camera Access
//   (`view.camera`, XRWebGLBinding.getCameraImage), depth from the CPU depth information of
//   the same view (XRFrame.getDepthInformation); the pose and intrinsics are that view's.
// - "headset" (Quest Browser): no camera-access, so colour from getUserMedia (the headset
//   cameras), placed by a documented, approximate calibration relative to the viewer pose
//   (calibration.mjs) and paired with the viewer pose nearest in time (the skew goes with
//   the frame as `pose_skew_s`); depth from the GPU depth information (gpu-depth.mjs),
//   reprojected from the depth view into the colour camera in the encode Worker.
// Readbacks are asynchronous; a capture is complete a frame or two after it starts.

import { CALIBRATIONS, DEFAULT_CALIBRATION, intrinsicsAt } from "./calibration.mjs";
import { multiply, protocolCamera, protocolPose } from "./conventions.mjs";
import { GpuDepthReader } from "./gpu-depth.mjs";
import { Readback } from "./readback.mjs";

const POSE_HISTORY = 45; // viewer poses kept for pairing with video frames (~0.5-0.75 s)

export class Capture {
  /**
   * session: the XRSession; gl: its XR-compatible WebGL2 context; space: the reference space;
   * video: for the headset path, a playing <video> of the getUserMedia stream.
   */
  constructor({ session, gl, space, video = null, calibration = DEFAULT_CALIBRATION }) {
    this.session = session;
    this.gl = gl;
    this.space = space;
    this.binding = new XRWebGLBinding(session, gl);
    this.readback = new Readback(gl);
    this.path = (session.enabledFeatures || []).includes("camera-access") ? "camera-access" : "headset";
    this.depthUsage = session.depthUsage;
    this.depthFormat = session.depthDataFormat;
    this.inFlight = new Map(); // job id -> {parts left, frame data}
    this.nextJob = 1;
    this.poses = []; // [{timeMs, matrix}] recent viewer poses (headset path)
    this.calibration = CALIBRATIONS[calibration];
    this.video = video;
    this.videoTimeMs = null; // the newest video frame's time, on the performance clock
    this.gpuDepth = this.depthUsage === "gpu-optimized" ? new GpuDepthReader(gl, this.readback) : null;
    this.runtimeMs = 0; // time spent inside the XR runtime's own calls (its work, not ours)
    this.completed = [];
    this.failures = [];
    this.closed = false;
    if (video) this._followVideoFrames();
  }

  /** What the page says about where its colour and pose come from. */
  describe() {
    if (this.path === "camera-access") return "colour and pose from the camera's own view (camera-access), CPU depth";
    return `colour from the headset camera (getUserMedia), placed by the ${this.calibration.name} calibration and paired with the nearest pose; ${this.depthUsage} depth`;
  }

  _followVideoFrames() {
    const video = this.video;
    const onFrame = (now, meta) => {
      // captureTime where the platform gives it (the camera's own clock on the performance
      // timeline), else when the frame was presented.
      this.videoTimeMs = meta && Number.isFinite(meta.captureTime) ? meta.captureTime : meta && Number.isFinite(meta.expectedDisplayTime) ? meta.expectedDisplayTime : now;
      if (!this.closed) video.requestVideoFrameCallback(onFrame);
    };
    video.requestVideoFrameCallback(onFrame);
  }

  /** Every XR frame: remember the viewer pose (the headset path pairs video frames with it). */
  notePose(timeMs, viewerPose) {
    if (this.path !== "headset") return;
    this.poses.push({ timeMs, matrix: Float64Array.from(viewerPose.transform.matrix) });
    if (this.poses.length > POSE_HISTORY) this.poses.shift();
  }

  get busy() {
    return this.inFlight.size > 0;
  }

  /**
   * Start capturing a keyframe in this XR frame callback. Returns false (nothing started)
   * when the runtime has no image or depth for it yet.
   */
  begin(frame, viewerPose, timeMs) {
    return this.path === "camera-access" ? this._beginCameraAccess(frame, viewerPose, timeMs) : this._beginHeadset(viewerPose, timeMs);
  }

  _beginCameraAccess(frame, viewerPose, timeMs) {
    const gl = this.gl;
    const view = viewerPose.views.find((v) => v.camera);
    if (!view) return false;
    const asked = performance.now();
    const depthInfo = frame.getDepthInformation(view);
    const texture = depthInfo ? this.binding.getCameraImage(view.camera) : null;
    this.runtimeMs += performance.now() - asked;
    if (!depthInfo || !texture) return false;
    const { width, height } = view.camera;
    const id = this.nextJob++;
    const job = {
      parts: 1,
      t: epochSeconds(timeMs),
      camera: protocolCamera(view.transform.matrix, view.projectionMatrix, width, height),
      depth: {
        kind: "cpu",
        buffer: depthInfo.data.slice(0), // valid only during this callback
        format: this.depthFormat,
        depthWidth: depthInfo.width,
        depthHeight: depthInfo.height,
        rawValueToMeters: depthInfo.rawValueToMeters,
        normDepthFromNormView: Array.from(depthInfo.normDepthBufferFromNormView.matrix),
      },
      colour: null,
      poseSkewS: null,
    };
    this.inFlight.set(id, job);
    this.readback.start(texture, width, height, {
      format: gl.RGBA,
      type: gl.UNSIGNED_BYTE,
      ArrayType: Uint8Array,
      channels: 4,
      tag: { id, part: "colour", width, height },
    });
    return true;
  }

  _beginHeadset(viewerPose, timeMs) {
    if (!this.video || this.videoTimeMs === null || this.video.readyState < 2) return false;
    const view = viewerPose.views[0];
    const asked = performance.now();
    const depthInfo = this.binding.getDepthInformation(view);
    this.runtimeMs += performance.now() - asked;
    if (!depthInfo) return false;
    const nearest = this._poseNearest(this.videoTimeMs) || { timeMs, matrix: viewerPose.transform.matrix };
    const cameraMatrix = multiply(nearest.matrix, this.calibration.cameraFromViewer);
    const width = this.video.videoWidth;
    const height = this.video.videoHeight;
    const id = this.nextJob++;
    const job = {
      parts: 2,
      t: epochSeconds(nearest.timeMs),
      camera: { pose: protocolPose(cameraMatrix), intrinsics: intrinsicsAt(this.calibration, width, height) },
      depth: {
        kind: "metres",
        depthWidth: depthInfo.width,
        depthHeight: depthInfo.height,
        stride: 4,
        bottomUp: true, // a GL texture's rows (gpu-depth.mjs)
        normDepthFromNormView: Array.from(depthInfo.normDepthBufferFromNormView.matrix),
        depthProjection: Array.from(depthInfo.projectionMatrix || view.projectionMatrix),
        depthTransform: Array.from(depthInfo.transform ? depthInfo.transform.matrix : view.transform.matrix),
      },
      colour: null,
      poseSkewS: (this.videoTimeMs - nearest.timeMs) / 1000,
    };
    this.inFlight.set(id, job);
    this.gpuDepth.start(depthInfo, this.depthFormat, { id, part: "depth" });
    createImageBitmap(this.video).then(
      (bitmap) => this._part(id, "colour", { kind: "bitmap", bitmap }),
      (error) => this._fail(id, `the camera frame could not be read: ${error}`),
    );
    return true;
  }

  _poseNearest(timeMs) {
    let best = null;
    for (const p of this.poses) if (!best || Math.abs(p.timeMs - timeMs) < Math.abs(best.timeMs - timeMs)) best = p;
    return best;
  }

  _part(id, part, value) {
    const job = this.inFlight.get(id);
    if (!job) return;
    if (part === "colour") job.colour = value;
    else job.depth.depth = value;
    job.parts -= 1;
    if (job.parts === 0) {
      this.inFlight.delete(id);
      this.completed.push(job);
    }
  }

  _fail(id, reason) {
    this.inFlight.delete(id);
    this.failures.push(reason);
  }

  /** Each XR frame: finished captures, ready for the encoder ({t, camera, colour, depth,
   * poseSkewS}), and reasons for captures that failed. */
  collect() {
    for (const { tag, data } of this.readback.collect()) {
      if (tag.part === "colour") this._part(tag.id, "colour", { kind: "pixels", rgba: data.buffer, width: tag.width, height: tag.height, bottomUp: true });
      else this._part(tag.id, "depth", data.buffer);
    }
    const done = this.completed.splice(0);
    const failed = this.failures.splice(0);
    return { done, failed };
  }

  close() {
    this.closed = true;
  }
}

/** Epoch seconds of a time on the page's performance clock (the XR frame loop's clock). */
export function epochSeconds(timeMs) {
  return (performance.timeOrigin + timeMs) / 1000;
}
