"""Spoken questions for tests: speech synthesised offline by Debian's espeak-ng (a WAV file,
16-bit PCM mono at 22.05 kHz), and the Chromium flags that make it a page's microphone.

    wav = speak("where is the refrigerator", tmp_path / "question.wav")  # skips without espeak-ng
    browser = playwright.chromium.launch(args=[*CHROMIUM_ARGS, *fake_microphone_args(wav)])
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

ASR_TIMEOUT_S = 60
"""`asr_timeout_s` for a test server that recognises speech: generous, since its first
question starts the recogniser's process and loads it, on a busy machine."""


def speak(text: str, path: Path, *, voice: str = "en-us", words_per_minute: int = 150) -> Path:
    """`text` spoken by espeak-ng into the WAV file `path`; a pytest skip naming the package
    when espeak-ng is missing."""
    espeak = shutil.which("espeak-ng")
    if espeak is None:
        pytest.skip("no espeak-ng to synthesise speech (Debian: apt-get install espeak-ng)")
    command = [espeak, "-v", voice, "-s", str(words_per_minute), "-w", str(path), text]
    subprocess.run(command, check=True, capture_output=True, timeout=60)
    return path


def fake_microphone_args(wav: Path) -> list[str]:
    """Chromium's flags for a microphone that says `wav` once from the start of every
    getUserMedia stream, then silence (`%noloop`; without it the file loops), with the
    permission granted without a prompt."""
    return [
        "--use-fake-device-for-media-stream",
        "--use-fake-ui-for-media-stream",
        f"--use-file-for-fake-audio-capture={wav}%noloop",
    ]
