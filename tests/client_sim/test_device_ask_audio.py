"""`semanticxr device --ask-audio FILE`: the command's code path against a real server on
loopback. A recorded question (speech synthesised by espeak-ng) is recognised by the server
and answered as the words it heard are answered typed; audio the server refuses is said, in
its words, and the exit status says a question went unanswered; a missing file or an
unknown extension is a set-up error before any session is made."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import httpx
import pytest
from analytic_world import KITCHEN, RectSource
from spoken import ASR_TIMEOUT_S, speak

from app.client.rest import AUDIO_FILE_TYPES
from app.speech import AUDIO_TYPES

pytestmark = [pytest.mark.slow, pytest.mark.timeout(240)]


def run_device(server_url: str, tmp_path: Path, monkeypatch, *flags: str) -> tuple[int, dict]:
    """The `device` command (its parser and run()) streaming the kitchen (a chair and a
    refrigerator), then asking `flags`' questions; its exit status and --json summary."""
    from app.cli import device

    monkeypatch.setattr(
        device, "make_device_source", lambda spec, frames, max_side_px=None: RectSource(KITCHEN, 6)
    )
    parser = argparse.ArgumentParser()
    device.add_parser(parser.add_subparsers(dest="command"))
    summary = tmp_path / "device.json"
    knobs = ["--keyframe-interval", "1", "--min-observations", "2"]
    command = ["device", "--server", server_url, "--create", "--fps", "0", *knobs]
    args = parser.parse_args([*command, "--json", str(summary), *flags])
    code = args.func(args)
    return code, json.loads(summary.read_text()) if summary.exists() else {}


def test_a_recorded_question_is_answered_as_the_words_the_server_heard(
    live_server, tmp_path, monkeypatch, capsys
):
    server = live_server(asr_timeout_s=ASR_TIMEOUT_S)
    question = speak("where is the refrigerator", tmp_path / "question.wav")
    code, summary = run_device(server.url, tmp_path, monkeypatch, "--ask-audio", str(question))
    assert code == 0
    (spoken,) = summary["queries"]
    assert spoken["mode"] == "SQ" and "refrigerator" in spoken["transcript"]
    assert spoken["asr_ms"] > 0 and spoken["results"][0]["label"] == "refrigerator"
    typed = httpx.get(
        f"{server.url}/v1/sessions/{summary['session_id']}/query",
        params={"text": spoken["transcript"], "k": 3, "points": "false"},
        timeout=30,
    ).json()
    assert spoken["text"] == typed["text"]
    assert [(h["id"], h["relevance"]) for h in spoken["results"]] == [
        (h["id"], h["relevance"]) for h in typed["results"]
    ]
    out = capsys.readouterr().out
    assert f"{question}: heard {spoken['transcript']!r} (recognised on the server in" in out
    assert f"{spoken['text']!r}: SQ in" in out and "refrigerator" in out


def test_audio_the_server_refuses_is_said_and_the_exit_status_says_so(
    live_server, tmp_path, monkeypatch, capsys
):
    server = live_server(asr_timeout_s=ASR_TIMEOUT_S)
    garbled = tmp_path / "garbled.wav"
    garbled.write_bytes(b"RIFF, but not a WAV file")
    code, summary = run_device(server.url, tmp_path, monkeypatch, "--ask-audio", str(garbled))
    assert code == 1
    (refused,) = summary["queries"]
    assert refused["mode"] == "none" and refused["results"] == []
    assert "HTTP 400" in refused["reason"]
    assert f"{garbled}: not answered: " in capsys.readouterr().out


@pytest.mark.parametrize(
    ("name", "said"),
    [
        ("missing.wav", "--ask-audio {path}: No such file or directory"),
        ("question.flac", "cannot tell the audio type of .flac: use .wav .webm .ogg .m4a .mp4"),
    ],
)
def test_a_missing_recording_or_an_unknown_type_stops_the_command_before_any_session(
    live_server, tmp_path, monkeypatch, capsys, name, said
):
    server = live_server()
    path = tmp_path / name
    if name.endswith(".flac"):
        path.write_bytes(b"fLaC")
    code, _ = run_device(server.url, tmp_path, monkeypatch, "--ask-audio", str(path))
    assert code == 2
    assert said.format(path=path) in capsys.readouterr().err
    assert httpx.get(f"{server.url}/v1/sessions", timeout=10).json() == []


def test_each_file_type_the_device_names_is_one_the_server_decodes():
    assert set(AUDIO_FILE_TYPES.values()) == set(AUDIO_TYPES)
