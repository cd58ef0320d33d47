"""Ask aloud through a real server on loopback: espeak-ng questions posted as a page posts
them get the typed question's answer; every bad input gets the 4xx that names it; a long
question never stalls another session; Whisper's plumbing runs on a tiny random model."""

from __future__ import annotations

import subprocess
import sys
import threading

import httpx
import numpy as np
import pytest
from audio_files import pyav_bytes, wav_bytes
from relation_scene import SCENE, map_export
from spoken import speak

from app.protocol.rest import QueryResult, SpokenQueryResult

API_KEY = "speech-test-key"
pytestmark = pytest.mark.slow


@pytest.fixture
def server(live_server):
    return live_server(api_key=API_KEY, asr_timeout_s=60)


def client(server) -> httpx.Client:
    return httpx.Client(
        base_url=server.url, headers={"Authorization": f"Bearer {API_KEY}"}, timeout=120
    )


def new_session(http: httpx.Client) -> str:
    """A session holding the relation scene (desk, shelf, table, sofa, mugs, chairs, bag)."""
    created = http.post("/v1/sessions/import", json=map_export(SCENE, "spoken"))
    assert created.status_code == 201, created.text
    return created.json()["session_id"]


def post_audio(http, sid, data: bytes, content_type="audio/wav", **params) -> httpx.Response:
    return http.post(
        f"/v1/sessions/{sid}/query/speech",
        params={"points": "false", **params},
        content=data,
        headers={"Content-Type": content_type},
    )


def typed(http, sid, text: str, **params) -> QueryResult:
    reply = http.get(
        f"/v1/sessions/{sid}/query", params={"text": text, "points": "false", **params}
    )
    assert reply.status_code == 200, reply.text
    return QueryResult.model_validate(reply.json())


def silence_wav(seconds: float) -> bytes:
    return wav_bytes(np.zeros(int(seconds * 16_000), np.float32), 16_000)


@pytest.mark.parametrize(
    ("question", "voice"),
    [
        ("where is the sofa", "en-us"),
        ("find the sofa", "en-us+f3"),
        ("the mug on the table", "en-gb"),
        ("the chair next to the sofa", "en-us+f3"),
    ],
)
def test_a_spoken_question_gets_the_typed_answer(server, tmp_path, question, voice):
    wav = speak(question, tmp_path / "q.wav", voice=voice).read_bytes()
    with client(server) as http:
        sid = new_session(http)
        reply = post_audio(http, sid, wav, "audio/wav", k=3)
        assert reply.status_code == 200, reply.text
        spoken = SpokenQueryResult.model_validate(reply.json())
        as_typed = typed(http, sid, question, k=3)
    assert spoken.transcript == question
    assert spoken.text == spoken.transcript
    assert [h.id for h in spoken.results] == [h.id for h in as_typed.results]
    assert [h.relation for h in spoken.results] == [h.relation for h in as_typed.results]
    assert spoken.asr_ms > 0 and spoken.confidence is not None and 0 <= spoken.confidence <= 1


def test_browser_audio_with_codecs_is_heard_as_its_wav(server, tmp_path):
    """The same question as a page records it (WebM/Opus, `;codecs=opus`) and as curl sends
    it (WAV) is heard alike."""
    from app.speech.audio import decode_audio

    wav = speak("where is the sofa", tmp_path / "q.wav").read_bytes()
    samples = decode_audio(wav, "audio/wav").samples
    webm = pyav_bytes(samples, 16_000, "webm", "libopus")
    with client(server) as http:
        sid = new_session(http)
        reply = post_audio(http, sid, webm, "audio/webm;codecs=opus")
    assert reply.status_code == 200, reply.text
    assert reply.json()["transcript"] == "where is the sofa"


def test_every_bad_input_gets_the_4xx_that_names_it(live_server):
    server = live_server(api_key=API_KEY, max_audio_bytes=100_000)
    with client(server) as http:
        sid = new_session(http)
        cases = [
            (post_audio(http, sid, b"fLaC....", "audio/flac"), 415, "audio/flac"),
            (post_audio(http, sid, b"", "audio/wav"), 400, "empty"),
            (post_audio(http, sid, b"RIFF and then nonsense", "audio/wav"), 400, "audio/wav"),
            (post_audio(http, sid, b"\x1a\x45\xdf\xa3 nonsense", "audio/webm"), 400, "audio/webm"),
            (post_audio(http, sid, b"x" * 100_001, "audio/wav"), 413, "--max-audio-bytes"),
            (post_audio(http, sid, silence_wav(3.2), "audio/wav"), 422, "30 s"),
        ]
        server_30s = live_server(api_key=API_KEY)
        with client(server_30s) as other:
            other_sid = new_session(other)
            cases += [
                (post_audio(other, other_sid, silence_wav(31), "audio/wav"), 422, "30 s"),
                (post_audio(other, other_sid, silence_wav(1.0), "audio/wav"), 422, "no speech"),
            ]
        unauthorised = httpx.post(
            f"{server.url}/v1/sessions/{sid}/query/speech",
            content=b"not audio",
            headers={"Content-Type": "audio/wav"},
        )
        cases.append((unauthorised, 401, "token"))
        assert http.get(f"/v1/sessions/{sid}").status_code == 200  # still answering
    for reply, status, words in cases[:5] + cases[6:]:
        assert reply.status_code == status, reply.text
        assert words in reply.json()["detail"], reply.text
    assert cases[5][0].status_code == 413  # 3.2 s of WAV is 102 kB: over this server's limit


def test_a_question_over_the_time_limit_is_503_with_retry_after_and_the_next_is_heard(
    live_server, tmp_path
):
    server = live_server(api_key=API_KEY, asr_timeout_s=0.2)
    long_question = " and ".join(["where is the sofa"] * 14)
    wav = speak(long_question, tmp_path / "long.wav", words_per_minute=120).read_bytes()
    with client(server) as http:
        sid = new_session(http)
        refused = post_audio(http, sid, wav)
        assert refused.status_code == 503, refused.text
        assert refused.headers["Retry-After"] == "1"
        assert "--asr-timeout-s" in refused.json()["detail"]


def test_a_long_question_does_not_stall_another_sessions_query(server, tmp_path):
    long_question = " and ".join(["where is the sofa next to the table"] * 8)
    wav = speak(long_question, tmp_path / "long.wav", words_per_minute=110).read_bytes()
    with client(server) as http:
        asker, other = new_session(http), new_session(http)
        post_audio(http, asker, speak("the sofa", tmp_path / "warm.wav").read_bytes())
        done = threading.Event()
        spoken: list[httpx.Response] = []

        def ask_aloud():
            with client(server) as own:
                spoken.append(post_audio(own, asker, wav))
            done.set()

        thread = threading.Thread(target=ask_aloud)
        thread.start()
        answered_while_heard = 0
        while not done.is_set() and answered_while_heard < 5:
            assert typed(http, other, "where is the desk").results[0].label == "desk"
            answered_while_heard += not done.is_set()
        thread.join(120)
    assert spoken and spoken[0].status_code == 200, spoken
    assert answered_while_heard >= 3


def test_the_endpoint_and_every_error_answer_are_in_openapi(server):
    with client(server) as http:
        operation = http.get("/openapi.json").json()["paths"]["/v1/sessions/{sid}/query/speech"]
    post = operation["post"]
    assert {"200", "400", "401", "403", "413", "415", "422", "503"} <= post["responses"].keys()
    assert "--max-audio-bytes" in post["responses"]["413"]["description"]
    assert set(post["requestBody"]["content"]) == {
        "audio/wav",
        "audio/webm",
        "audio/ogg",
        "audio/mp4",
    }
    assert {p["name"] for p in post["parameters"]} >= {"sid", "k", "points", "include", "from"}


def test_whisper_from_a_local_folder_answers_with_its_transcript(live_server, tmp_path):
    """The tiny random Whisper's transcripts are noise: this proves the plumbing (load from
    the folder, the labels as prompt, generation, the answer), not recognition."""
    from app.speech.whisper import write_tiny_whisper

    folder = write_tiny_whisper(tmp_path / "whisper")
    server = live_server(api_key=API_KEY, asr=f"whisper:{folder}", asr_timeout_s=120)
    wav = speak("where is the sofa", tmp_path / "q.wav").read_bytes()
    with client(server) as http:
        sid = new_session(http)
        reply = post_audio(http, sid, wav)
    assert reply.status_code in (200, 422), reply.text
    if reply.status_code == 200:
        body = SpokenQueryResult.model_validate(reply.json())
        assert body.text == body.transcript and body.confidence is None and body.asr_ms > 0
    else:
        assert "no speech" in reply.json()["detail"]


def test_serve_exits_2_naming_asr_when_whisper_is_missing(tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", "app.cli", "serve", "--asr", f"whisper:{tmp_path / 'none'}"]
        + ["--port", "0", "--data-dir", str(tmp_path / "data")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 2
    assert "--asr whisper:" in done.stderr and "config.json" in done.stderr
