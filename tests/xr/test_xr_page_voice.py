"""The real-device page's push-to-talk (static/xr/voice.mjs) in real Chromium against a real
server on loopback: a question held and spoken into a fake microphone (speech synthesised by
espeak-ng) is recognised by the server and answered exactly as the same words typed; the
page says where it was recognised and shows the server's words when it refuses the audio.
The browser's own recognition is used only on the device: a stand-in for Web Speech checks
that the page asks it to process locally, and never offers a recogniser that cannot."""

from __future__ import annotations

from urllib.parse import parse_qs, urlsplit

import httpx
import pytest
from browser_pages import checked_page
from fake_xr_browser import launch, open_with_fake_xr, wait_until
from relation_scene import scene_export
from scene_feed import SceneFeed
from spoken import ASR_TIMEOUT_S, fake_microphone_args, speak
from xr_device import Phone

from app.speech import AUDIO_TYPES

pytestmark = [pytest.mark.slow, pytest.mark.timeout(300)]

SPOKEN = "where is the sofa"
SPEAKING_MS = 2500
"""How long the person holds the button: the synthesised question lasts about 1.2 s."""

# A stand-in for Web Speech's SpeechRecognition (installed before the page's scripts) that
# "hears" window.__speech.says: it records the options of available() and each instance.
WEB_SPEECH_STAND_IN = """
window.__speech = { says: "the mug on the desk", available: [], started: [], local: %(local)s };
class StandInRecognition {
  static async available(options) {
    window.__speech.available.push(options);
    return "available";
  }
  start() {
    window.__speech.started.push({ processLocally: this.processLocally, lang: this.lang,
                                   continuous: this.continuous });
    setTimeout(() => this.onstart(), 0);
  }
  stop() {
    const alternative = { transcript: window.__speech.says, confidence: 0.9 };
    const result = Object.assign([alternative], { isFinal: true });
    setTimeout(() => {
      this.onresult({ resultIndex: 0, results: [result] });
      this.onend();
    }, 0);
  }
}
if (window.__speech.local) StandInRecognition.prototype.processLocally = false;
window.SpeechRecognition = StandInRecognition;
window.webkitSpeechRecognition = StandInRecognition;
"""


@pytest.fixture(scope="module")
def mic_browser(xr_playwright, tmp_path_factory):
    """A Chromium whose microphone says SPOKEN at the start of every recording."""
    wav = speak(SPOKEN, tmp_path_factory.mktemp("speech") / "question.wav")
    browser = launch(xr_playwright, fake_microphone_args(wav))
    yield browser
    browser.close()


# Each Blob the page gives fetch as a body: its type and size.
BLOBS_SENT = """
window.__blobsSent = [];
const pageFetch = window.fetch;
window.fetch = (resource, init) => {
  if (init && init.body instanceof Blob) window.__blobsSent.push({ type: init.body.type, size: init.body.size });
  return pageFetch(resource, init);
};
"""


@pytest.fixture
def mic_page(mic_browser):
    yield from checked_page(mic_browser, {"width": 960, "height": 720}, (BLOBS_SENT,))


def open_office(page, server) -> str:
    """tests/relation_scene.py's office imported as a session, the page opened on it; its id."""
    created = httpx.post(
        f"{server.url}/v1/sessions/import", json=scene_export("office"), timeout=30
    )
    assert created.status_code == 201, created.text
    sid, token = created.json()["session_id"], created.json()["token"]
    feed = SceneFeed(Phone(), n_frames=2)
    open_with_fake_xr(page, f"{server.url}/xr#session={sid}&token={token}", feed)
    wait_until(page, "() => !document.querySelector('#talk').disabled")
    return sid


def hold_to_talk(page) -> None:
    """Press the button, talk while holding it, let go."""
    box = page.locator("#talk").bounding_box()
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.mouse.down()
    wait_until(page, "() => document.querySelector('#talk').dataset.state === 'listening'")
    page.wait_for_timeout(SPEAKING_MS)  # the person talking: not a wait on the page
    page.mouse.up()


def answer_shown(page) -> dict:
    """The page's answer (window.semanticxr.answer, points left out) and its line."""
    return page.evaluate(
        """() => {
            const a = window.semanticxr.answer;
            return { text: a.text, match: a.match, source: a.source, transcript: a.transcript,
                     recognised: a.recognised, ids: a.results.map((hit) => hit.id),
                     words: document.querySelector('#answer').textContent };
        }"""
    )


def test_held_and_spoken_the_question_is_answered_as_the_same_words_typed(live_server, mic_page):
    server = live_server(asr_timeout_s=ASR_TIMEOUT_S)
    open_office(mic_page, server)
    assert "recognised on the server (offline)" in mic_page.inner_text("#voice-note")
    assert mic_page.locator("#on-device-choice").is_hidden()  # no on-device pack here
    sent: list = []
    mic_page.on("request", lambda r: sent.append(r) if "/query/speech" in r.url else None)

    hold_to_talk(mic_page)
    wait_until(mic_page, "() => (window.semanticxr.answer || {}).recognised === 'server'")
    spoken = answer_shown(mic_page)
    heard = mic_page.inner_text("#heard")
    assert heard.startswith(f"heard “{spoken['transcript']}”")
    assert "recognised on the server (offline)" in heard
    assert "sofa" in spoken["transcript"] and spoken["ids"][0] == 4  # the sofa
    (request,) = sent
    assert request.all_headers()["content-type"].startswith("audio/webm")  # Chromium's Opus
    # The body's size as the page handed it to fetch (a Blob body is not in Playwright's
    # request, and the feed's routing takes content-length off its headers).
    (blob,) = mic_page.evaluate("window.__blobsSent")
    assert blob["type"] == request.all_headers()["content-type"] and blob["size"] > 2000
    assert parse_qs(urlsplit(request.url).query) == {
        "k": ["5"],
        "points": ["true"],
        "rerank": ["true"],
    }

    # Typed, the same words get the same answer, said the same way; the heard line goes.
    mic_page.fill("#ask-text", spoken["transcript"])
    mic_page.click("#ask-form button[type=submit]")
    wait_until(mic_page, "() => !('transcript' in window.semanticxr.answer)")
    typed = answer_shown(mic_page)
    same = ("text", "match", "source", "ids", "words")
    assert {k: typed[k] for k in same} == {k: spoken[k] for k in same}
    assert mic_page.locator("#heard").is_hidden()


def test_audio_the_server_refuses_is_said_in_the_servers_words(live_server, mic_page):
    server = live_server(asr_timeout_s=ASR_TIMEOUT_S)
    open_office(mic_page, server)
    # The recording garbled on its way: the server cannot decode it.
    mic_page.route("**/query/speech?*", lambda route: route.continue_(post_data=b"not audio"))
    mic_page.click("#talk")  # a tap starts
    wait_until(mic_page, "() => document.querySelector('#talk').dataset.state === 'listening'")
    mic_page.wait_for_timeout(SPEAKING_MS)
    mic_page.click("#talk")  # a second tap stops and asks
    wait_until(mic_page, "() => document.querySelector('#heard').dataset.error === 'true'")
    assert mic_page.inner_text("#heard").startswith("not answered: ")
    assert "(400)" in mic_page.inner_text("#heard")
    assert mic_page.evaluate("window.semanticxr.answer") is None


def test_on_device_recognition_is_offered_only_where_it_stays_on_the_device(live_server, mic_page):
    server = live_server()
    mic_page.add_init_script(script=WEB_SPEECH_STAND_IN % {"local": "true"})
    sid = open_office(mic_page, server)
    wait_until(mic_page, "() => !document.querySelector('#on-device-choice').hidden")
    assert not mic_page.is_checked("#on-device")  # the server's recognition by default
    assert mic_page.evaluate("window.__speech.available") == [
        {"langs": ["en-US"], "processLocally": True}
    ]
    mic_page.check("#on-device")
    assert "recognised on this device" in mic_page.inner_text("#voice-note")
    asked: list[str] = []
    mic_page.on("request", lambda r: asked.append(r.url) if "/query" in r.url else None)

    mic_page.click("#talk")
    wait_until(mic_page, "() => document.querySelector('#talk').dataset.state === 'listening'")
    mic_page.click("#talk")
    wait_until(mic_page, "() => (window.semanticxr.answer || {}).recognised === 'device'")
    assert mic_page.evaluate("window.__speech.started") == [
        {"processLocally": True, "lang": "en-US", "continuous": True}
    ]
    heard = mic_page.inner_text("#heard")
    assert heard == "heard “the mug on the desk” (0.90) · recognised on this device"
    assert answer_shown(mic_page)["ids"][0] == 10  # the mug on the desk, asked as typed text
    (url,) = asked  # no audio left the device: the words went as a typed question
    assert urlsplit(url).path == f"/v1/sessions/{sid}/query"
    assert parse_qs(urlsplit(url).query)["text"] == ["the mug on the desk"]


def test_a_recogniser_that_cannot_promise_to_stay_on_the_device_is_never_offered(
    live_server, mic_page
):
    server = live_server()
    mic_page.add_init_script(script=WEB_SPEECH_STAND_IN % {"local": "false"})
    open_office(mic_page, server)  # the button is enabled after the check: it has answered
    assert mic_page.locator("#on-device-choice").is_hidden()
    assert mic_page.evaluate("window.__speech.available") == []  # not even asked
    assert "recognised on the server (offline)" in mic_page.inner_text("#voice-note")


def test_a_recording_takes_the_first_type_the_browser_records_of_those_the_server_takes(
    xr_browser, live_server
):
    server = live_server()
    page = xr_browser.new_page()
    page.goto(f"{server.url}/healthz")  # the server's origin: its modules import
    picked = page.evaluate(
        """async () => {
            const { recordingType, RECORDING_TYPES } = await import('/static/common/recorder.mjs');
            return {
                all: RECORDING_TYPES,
                safari: recordingType((t) => t === 'audio/mp4'),
                firefox: recordingType((t) => t.startsWith('audio/ogg') || t === 'audio/mp4'),
                none: recordingType(() => false),
                chromium: recordingType(),
            };
        }"""
    )
    page.close()
    assert picked == {
        "all": ["audio/webm;codecs=opus", "audio/ogg;codecs=opus", "audio/mp4"],
        "safari": "audio/mp4",
        "firefox": "audio/ogg;codecs=opus",
        "none": None,
        "chromium": "audio/webm;codecs=opus",
    }
    # Each is a type the server decodes (its parameters ignored).
    assert {t.split(";")[0] for t in picked["all"]} <= set(AUDIO_TYPES)
