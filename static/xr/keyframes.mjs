// Which frames the page sends, by the rules the Python device uses (app/keyframes.py and
// the device's --fps): frames are sampled from the XR frame loop at the stream rate, and
// among the sampled frames the first and every `keyframe_interval`-th one after it is a
// keyframe (the session's knob). With the sightings extension the page sends only its
// keyframes whole; a page has no detections, so it has no sighting to send between them.

/** Whether sampled frame `index` (0-based) is a keyframe: app.keyframes.is_keyframe. */
export function isKeyframe(index, interval) {
  return index % interval === 0;
}

/** Samples an XR frame loop (60-90 Hz) at `fps`: `take(timeMs)` says whether to use this one. */
export class FrameSampler {
  constructor(fps) {
    this.periodMs = 1000 / fps;
    this.nextMs = null;
    this.sampled = 0; // frames taken so far: the index the keyframe rule counts
  }

  take(timeMs) {
    if (this.nextMs !== null && timeMs < this.nextMs) return false;
    // Keep the schedule (no drift); after a stall, restart it from now rather than bursting.
    this.nextMs = this.nextMs === null || timeMs - this.nextMs > this.periodMs ? timeMs + this.periodMs : this.nextMs + this.periodMs;
    this.sampled += 1;
    return true;
  }
}
