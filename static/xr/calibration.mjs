// Where a headset's colour camera is, when the runtime does not say (no `camera-access`):
// Quest Browser gives the passthrough camera through getUserMedia, with no intrinsics and no
// pose. These are documented, APPROXIMATE figures per device; a frame mapped with them is as
// good as they are. Each gives the camera's intrinsics for the image size it names (scaled to
// the size the stream delivers) and its pose relative to the XR viewer pose, in WebXR's
// camera convention (column-major, -z forward, +y up).
//
// Quest 3: the left RGB passthrough camera, 1280 x 960 at about 73 degrees horizontal field
// of view, about 3.2 cm left of, 2 cm below and 6 cm ahead of the point between the eyes,
// looking straight ahead. Published figures vary by unit; a real headset should be calibrated.

export const CALIBRATIONS = {
  "quest-3": {
    name: "Meta Quest 3 (approximate)",
    approximate: true,
    width: 1280,
    height: 960,
    intrinsics: [866, 866, 639.5, 479.5], // fx, fy, cx, cy at width x height
    cameraFromViewer: [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, -0.032, -0.02, -0.06, 1],
  },
};

export const DEFAULT_CALIBRATION = "quest-3";

/** The calibration's intrinsics for an image of width x height (same aspect, scaled). */
export function intrinsicsAt(calibration, width, height) {
  const sx = width / calibration.width;
  const sy = height / calibration.height;
  const [fx, fy, cx, cy] = calibration.intrinsics;
  return [fx * sx, fy * sy, (cx + 0.5) * sx - 0.5, (cy + 0.5) * sy - 0.5];
}
