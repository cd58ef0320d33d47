// Asking aloud on the real-device page: the push-to-talk button beside the question box
// (static/common/push-to-talk.mjs). By default the question is recorded
// (static/common/recorder.mjs) and the server recognises it, offline (answers.mjs askAloud).
// Where the browser can recognise speech on the device itself (local-speech.mjs), the page
// offers that as a choice, off by default. The page says which recognises the questions.

import { HINT, PushToTalk } from "../common/push-to-talk.mjs";
import { MAX_RECORDING_MS, microphoneProblem, recordedQuestion, recordingErrorWords, startRecording } from "../common/recorder.mjs";
import { RECOGNISED } from "../common/words.mjs";
import { onDeviceAvailable, startListening } from "./local-speech.mjs";

/**
 * Wire the page's voice. `button` becomes push-to-talk; `onDevice`, a checkbox inside a
 * hidden label, is shown where the browser recognises on the device; `note` says where the
 * questions are recognised. `onRecorded(blob)` gets a recording for the server,
 * `onRecognised({transcript, confidence})` a question recognised on the device (each
 * awaited, the button busy meanwhile); `onError(message)` what went wrong, in words.
 * Returns `{setSession(sid)}`: without a session the button is disabled.
 */
export function wireVoice({ button, onDevice, note, onRecorded, onRecognised, onError }) {
  const choice = onDevice.closest("label");
  const microphone = microphoneProblem();
  let sid = null;
  const local = () => onDevice.checked && !choice.hidden;
  const talk = new PushToTalk(button, {
    start: ({ onLimit }) => (local() ? startListening({ maxMs: MAX_RECORDING_MS, onLimit }) : startRecording({ onLimit })),
    onCaptured: (captured) => (captured.blob ? onRecorded(recordedQuestion(captured)) : onRecognised(captured)),
    onError: (error) => onError(recordingErrorWords(error)),
  });
  const update = () => {
    note.textContent = `${HINT}; ${local() ? RECOGNISED.device : RECOGNISED.server}`;
    talk.setUnavailable(sid ? (local() ? null : microphone) : "choose or create a session first");
  };
  choice.hidden = true;
  onDevice.checked = false; // the server's recognition unless the person picks the device's
  onDevice.addEventListener("change", update);
  onDeviceAvailable().then((available) => {
    choice.hidden = !available;
    update();
  });
  update();
  return {
    setSession(session) {
      sid = session || null;
      update();
    },
  };
}
