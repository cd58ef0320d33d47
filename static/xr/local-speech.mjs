// The browser's own speech recognition, used only where it runs on the device: Web Speech's
// SpeechRecognition with `processLocally = true` ("speech recognition done via the
// SpeechRecognition object must be done locally"), offered only when
// `SpeechRecognition.available({langs, processLocally: true})` answers "available" (the
// language pack is on the device already; the page never installs one). A browser whose
// SpeechRecognition has no `processLocally` is never used: its recognition may send the audio
// to a cloud service (Chrome's does unless asked to process locally).

export const LANG = "en-US"; // the map's labels and the question forms are English

const Recognition = () => globalThis.SpeechRecognition || globalThis.webkitSpeechRecognition || null;

/** Whether this browser recognises `lang` on the device now (never a download). */
export async function onDeviceAvailable(lang = LANG) {
  const Api = Recognition();
  if (!Api || !("processLocally" in Api.prototype) || typeof Api.available !== "function") return false;
  try {
    return (await Api.available({ langs: [lang], processLocally: true })) === "available";
  } catch {
    return false; // blocked by a permissions policy, or not fully active
  }
}

/**
 * Listen on the device. Resolves, once listening, to `{stop()}`; `stop()` resolves to
 * `{transcript, confidence}` (the final results joined; confidence their mean, null when the
 * browser gives none) or rejects naming the recogniser's error ("no-speech",
 * "language-not-supported", ...). `onLimit` is called after `maxMs`.
 */
export function startListening({ lang = LANG, maxMs, onLimit = () => {} } = {}) {
  const Api = Recognition();
  const recognition = new Api();
  recognition.processLocally = true;
  if (recognition.processLocally !== true) throw new Error("this browser cannot promise to recognise on the device");
  recognition.lang = lang;
  recognition.continuous = true; // the button, not a pause, ends the question
  recognition.interimResults = false;
  recognition.maxAlternatives = 1;
  const finals = [];
  let failure = null;
  let limit = null;
  return new Promise((resolveStarted, rejectStarted) => {
    let resolveDone;
    let rejectDone;
    const done = new Promise((resolve, reject) => {
      resolveDone = resolve;
      rejectDone = reject;
    });
    done.catch(() => {}); // a failure before listening is told through the start's rejection
    recognition.onresult = (event) => {
      for (let i = event.resultIndex; i < event.results.length; i++) {
        if (event.results[i].isFinal) finals.push(event.results[i][0]);
      }
    };
    recognition.onerror = (event) => {
      failure = new Error(`on-device recognition: ${event.error}${event.message ? ` (${event.message})` : ""}`);
      rejectStarted(failure); // no effect once started
    };
    recognition.onend = () => {
      clearTimeout(limit);
      const transcript = finals.map((alternative) => alternative.transcript.trim()).filter(Boolean).join(" ");
      const known = finals.map((alternative) => alternative.confidence).filter((c) => typeof c === "number" && c > 0);
      if (failure) rejectDone(failure);
      else if (!transcript) rejectDone(new Error("on-device recognition heard no words"));
      else resolveDone({ transcript, confidence: known.length ? known.reduce((a, b) => a + b) / known.length : null });
    };
    recognition.onstart = () => {
      if (maxMs) limit = setTimeout(onLimit, maxMs);
      resolveStarted({
        stop() {
          recognition.stop();
          return done;
        },
      });
    };
    recognition.start();
  });
}
