// Push-to-talk on a button, shared by the dashboard (static/app.js) and the real-device page
// (static/xr/voice.mjs): hold the button while speaking and let go, or tap it to start and
// tap it again to stop; Enter or Space on the focused button start and stop too. What is
// captured is the caller's: a MediaRecorder recording for the server (static/common/
// recorder.mjs) or, on the real-device page, the browser's on-device recognition.

export const HOLD_MS = 400; // a press held this long is hold-to-talk; a shorter one is a tap
export const HINT = "hold to talk and let go, or tap to start and tap again to stop";

const LABELS = { idle: "Ask aloud", starting: "Opening the mic…", listening: "● Stop", working: "Asking…" };

/**
 * A push-to-talk button. `start({onLimit})` opens a capture and resolves to `{stop()}`, whose
 * promise is what was captured (the capture calls `onLimit` when it must end: the button then
 * stops it); `onCaptured(result)` is awaited with it (the button is busy meanwhile);
 * `onError(error)` gets a capture that could not start or failed. The button's `data-state`
 * says where it is: idle, starting, listening, working.
 */
export class PushToTalk {
  constructor(button, { start, onCaptured, onError }) {
    this.button = button;
    this.start = start;
    this.onCaptured = onCaptured;
    this.onError = onError;
    this.capture = null;
    this.pressedAt = null; // performance.now() of the press a release will end, if held
    this.stopWhenStarted = false; // released after a hold before the capture opened
    this.unavailable = null; // why the button cannot be used, or null
    button.type = "button";
    button.addEventListener("pointerdown", (event) => {
      if (event.button !== 0) return;
      event.preventDefault(); // no focus ring, no text selection on a long press
      if (button.setPointerCapture) button.setPointerCapture(event.pointerId); // its release
      this.press();
    });
    button.addEventListener("pointerup", () => this.release());
    button.addEventListener("pointercancel", () => this.release());
    button.addEventListener("contextmenu", (event) => event.preventDefault()); // a phone's long press
    button.addEventListener("click", (event) => {
      if (event.detail === 0) this.toggle(); // the keyboard or assistive technology: no pointer
    });
    this.set("idle");
  }

  /** Say why the button cannot be used (it is disabled), or null to enable it. */
  setUnavailable(reason) {
    this.unavailable = reason || null;
    this.set(this.state);
  }

  press() {
    if (this.state === "listening") {
      this.finish(); // the second tap
      return;
    }
    if (this.state !== "idle" || this.unavailable) return;
    this.pressedAt = performance.now();
    this.begin();
  }

  release() {
    const pressedAt = this.pressedAt;
    this.pressedAt = null;
    if (pressedAt === null || performance.now() - pressedAt < HOLD_MS) return; // a tap: go on
    if (this.state === "listening") this.finish();
    else if (this.state === "starting") this.stopWhenStarted = true;
  }

  toggle() {
    if (this.state === "listening") this.finish();
    else if (this.state === "idle" && !this.unavailable) this.begin();
  }

  async begin() {
    this.set("starting");
    this.stopWhenStarted = false;
    try {
      this.capture = await this.start({ onLimit: () => this.finish() });
    } catch (error) {
      this.set("idle");
      this.onError(error);
      return;
    }
    this.set("listening");
    if (this.stopWhenStarted) this.finish();
  }

  async finish() {
    if (this.state !== "listening") return;
    const capture = this.capture;
    this.capture = null;
    this.set("working");
    try {
      await this.onCaptured(await capture.stop());
    } catch (error) {
      this.onError(error);
    } finally {
      this.set("idle");
    }
  }

  set(state) {
    this.state = state;
    const button = this.button;
    button.dataset.state = state;
    button.setAttribute("aria-pressed", String(state === "listening"));
    button.textContent = LABELS[state];
    button.title = this.unavailable || (state === "listening" ? "listening: let go, or tap again, to ask" : HINT);
    button.disabled = Boolean(this.unavailable) || state === "working";
  }
}
