"""Spoken-question audio: every container a browser or curl sends decodes to 16 kHz mono
float32 of the right length and pitch; bad audio is refused with the status it answers."""

from __future__ import annotations

import numpy as np
import pytest
from audio_files import pyav_bytes, wav_bytes

from app.speech.audio import SAMPLE_RATE_HZ, AudioError, audio_type, decode_audio

TONE_HZ = 440.0


def tone(seconds: float, rate_hz: int) -> np.ndarray:
    t = np.arange(int(seconds * rate_hz)) / rate_hz
    return (0.5 * np.sin(2 * np.pi * TONE_HZ * t)).astype(np.float32)


def pitch_hz(samples: np.ndarray) -> float:
    spectrum = np.abs(np.fft.rfft(samples))
    return float(np.fft.rfftfreq(len(samples), 1 / SAMPLE_RATE_HZ)[spectrum.argmax()])


CONTAINERS = {
    "audio/webm;codecs=opus": ("webm", "libopus"),
    "audio/ogg;codecs=opus": ("ogg", "libopus"),
    "audio/mp4": ("mp4", "aac"),
}


@pytest.mark.parametrize("content_type", sorted(CONTAINERS))
def test_each_browser_container_decodes_to_16k_mono_of_its_length_and_pitch(content_type):
    container, codec = CONTAINERS[content_type]
    data = pyav_bytes(tone(1.5, 48_000), 48_000, container, codec)
    audio = decode_audio(data, content_type)
    assert audio.samples.dtype == np.float32
    assert abs(audio.duration_s - 1.5) < 0.1
    assert abs(pitch_hz(audio.samples) - TONE_HZ) < 5


@pytest.mark.parametrize(
    ("rate_hz", "channels", "width"), [(22_050, 1, 2), (44_100, 2, 2), (16_000, 1, 3)]
)
def test_wav_of_any_rate_channels_and_width_decodes_by_the_standard_library(
    rate_hz, channels, width
):
    audio = decode_audio(wav_bytes(tone(1.0, rate_hz), rate_hz, channels, width), "audio/wav")
    assert abs(audio.duration_s - 1.0) < 0.01
    assert abs(pitch_hz(audio.samples) - TONE_HZ) < 5
    assert 0.45 < np.abs(audio.samples).max() <= 0.51


def test_parameters_and_wav_aliases_are_ignored_in_the_type():
    assert audio_type("audio/webm;codecs=opus") == "audio/webm"
    assert audio_type("Audio/MP4; codecs=mp4a.40.2") == "audio/mp4"
    assert audio_type("audio/x-wav") == "audio/wav"


@pytest.mark.parametrize(
    ("data", "content_type", "status", "words"),
    [
        (b"RIFF", "audio/flac", 415, "audio/flac"),
        (b"RIFF", None, 415, "(none)"),
        (b"", "audio/wav", 400, "empty"),
        (b"not audio at all", "audio/wav", 400, "audio/wav"),
        (b"not audio at all", "audio/webm", 400, "audio/webm"),
    ],
)
def test_bad_audio_is_refused_with_its_status_and_reason(data, content_type, status, words):
    with pytest.raises(AudioError) as refused:
        decode_audio(data, content_type)
    assert refused.value.status == status
    assert words in str(refused.value)


def test_webm_sent_as_ogg_is_undecodable_not_guessed():
    data = pyav_bytes(tone(0.5, 48_000), 48_000, "webm", "libopus")
    with pytest.raises(AudioError) as refused:
        decode_audio(data, "audio/ogg")
    assert refused.value.status == 400


@pytest.mark.parametrize("content_type", ["audio/wav", "audio/webm"])
def test_over_30_s_is_422_measured_by_decoding(content_type):
    quiet = np.zeros(31 * 16_000, np.float32)
    data = (
        wav_bytes(quiet, 16_000)
        if content_type == "audio/wav"
        else pyav_bytes(quiet, 16_000, "webm", "libopus")
    )
    with pytest.raises(AudioError) as refused:
        decode_audio(data, content_type)
    assert refused.value.status == 422
    assert "30 s" in str(refused.value)
