"""Spoken questions as they arrive: audio bytes of a MIME type -> 16 kHz mono float32.

WAV is read by the standard library's `wave` (PCM); WebM, Ogg and MP4 (what Chrome's,
Firefox's and Safari's MediaRecorder write) by PyAV, whose wheel brings FFmpeg's codecs. The
length is measured by decoding, never read from a header (a browser's WebM carries none),
and decoding stops as soon as it passes the limit, so a long upload costs what the limit
allows and no more.
"""

from __future__ import annotations

import io
import wave
from dataclasses import dataclass

import numpy as np

SAMPLE_RATE_HZ = 16_000
"""What every recogniser hears: 16 kHz mono float32 in [-1, 1]."""
MAX_SPEECH_S = 30.0
"""Longest question, in seconds of decoded audio (Whisper hears 30 s windows)."""
AUDIO_TYPES: tuple[str, ...] = ("audio/wav", "audio/webm", "audio/ogg", "audio/mp4")
"""The MIME types a spoken question may have (parameters such as `;codecs=opus` ignored)."""
_ALIASES = {"audio/x-wav": "audio/wav", "audio/wave": "audio/wav", "audio/vnd.wave": "audio/wav"}
"""Other names of WAV that clients send (curl and older browsers)."""


class AudioError(ValueError):
    """Audio that cannot be a question: `status` is the HTTP answer it gets (415 an
    unsupported type, 400 empty or undecodable, 422 too long)."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status


@dataclass(frozen=True)
class Audio:
    samples: np.ndarray
    """float32 [n] at SAMPLE_RATE_HZ, mono, in [-1, 1]."""

    @property
    def duration_s(self) -> float:
        return len(self.samples) / SAMPLE_RATE_HZ


def audio_type(content_type: str | None) -> str:
    """The supported MIME type a Content-Type names, parameters dropped
    ("audio/webm;codecs=opus" -> "audio/webm"); AudioError 415 for any other."""
    mime = (content_type or "").split(";", 1)[0].strip().lower()
    mime = _ALIASES.get(mime, mime)
    if mime not in AUDIO_TYPES:
        raise AudioError(
            415,
            f"Content-Type {content_type or '(none)'!r} is not spoken audio this server takes: "
            f"send one of {', '.join(AUDIO_TYPES)} (parameters like ;codecs= are fine)",
        )
    return mime


def decode_audio(data: bytes, content_type: str | None, max_s: float = MAX_SPEECH_S) -> Audio:
    """`data` of `content_type` as 16 kHz mono float32. AudioError: 415 for a type not in
    AUDIO_TYPES, 400 for no bytes, bytes that do not decode as that type, or no samples, 422
    for over `max_s` seconds."""
    mime = audio_type(content_type)
    if not data:
        raise AudioError(400, "the body is empty: send the recorded audio as the request body")
    if mime == "audio/wav":
        try:
            samples = _wav(data, max_s)
        except (wave.Error, EOFError) as exc:
            if "unknown format" not in str(exc):  # PCM only; float WAV goes to PyAV
                raise AudioError(400, f"not a readable audio/wav file: {exc}") from None
            samples = _pyav(data, mime, max_s)
    else:
        samples = _pyav(data, mime, max_s)
    if samples.size == 0:
        raise AudioError(400, f"the {mime} body holds no audio samples")
    return Audio(samples)


def _too_long(mime: str, max_s: float) -> AudioError:
    return AudioError(
        422, f"the {mime} audio is over {max_s:g} s: ask a shorter question (at most {max_s:g} s)"
    )


def _wav(data: bytes, max_s: float) -> np.ndarray:
    """PCM WAV (8, 16, 24 or 32-bit integers, any channels and rate) by `wave`."""
    with wave.open(io.BytesIO(data)) as wav:
        channels, width, rate = wav.getnchannels(), wav.getsampwidth(), wav.getframerate()
        if rate <= 0:
            raise wave.Error(f"sample rate {rate}")
        if wav.getnframes() > max_s * rate:
            raise _too_long("audio/wav", max_s)
        raw = wav.readframes(wav.getnframes())
    if width == 1:
        pcm = (np.frombuffer(raw, np.uint8).astype(np.float32) - 128.0) / 128.0
    elif width == 3:  # little-endian 24-bit: widen to 32
        b = np.frombuffer(raw[: len(raw) // 3 * 3], np.uint8).reshape(-1, 3)
        wide = np.zeros((len(b), 4), np.uint8)
        wide[:, 1:] = b
        pcm = wide.view("<i4").ravel().astype(np.float32) / 2.0**31
    elif width in (2, 4):
        pcm = np.frombuffer(raw, f"<i{width}").astype(np.float32) / 2.0 ** (8 * width - 1)
    else:
        raise wave.Error(f"{8 * width}-bit samples")
    usable = len(pcm) // channels * channels
    mono = pcm[:usable].reshape(-1, channels).mean(axis=1)
    return resample(mono, rate)


def resample(samples: np.ndarray, rate_hz: int) -> np.ndarray:
    """float32 [n] at `rate_hz` -> float32 [m] at SAMPLE_RATE_HZ (polyphase, anti-aliased)."""
    if rate_hz == SAMPLE_RATE_HZ:
        return samples.astype(np.float32, copy=False)
    from math import gcd

    from scipy.signal import resample_poly

    g = gcd(SAMPLE_RATE_HZ, rate_hz)
    out = resample_poly(samples, SAMPLE_RATE_HZ // g, rate_hz // g)
    return np.clip(out, -1.0, 1.0).astype(np.float32)


def _pyav(data: bytes, mime: str, max_s: float) -> np.ndarray:
    """The first audio stream of a WebM, Ogg, MP4 (or non-PCM WAV) by PyAV, resampled by
    FFmpeg to 16 kHz mono float; decoding stops past `max_s`."""
    import av

    limit = int(max_s * SAMPLE_RATE_HZ)
    chunks: list[np.ndarray] = []
    n = 0
    try:
        with av.open(io.BytesIO(data), mode="r", format=_DEMUXERS.get(mime)) as container:
            if not container.streams.audio:
                raise AudioError(400, f"the {mime} body has no audio stream")
            stream = container.streams.audio[0]
            resampler = av.AudioResampler(format="flt", layout="mono", rate=SAMPLE_RATE_HZ)
            for frame in container.decode(stream):
                for out in resampler.resample(frame):
                    chunk = out.to_ndarray().reshape(-1)
                    chunks.append(chunk)
                    n += len(chunk)
                if n > limit:
                    raise _too_long(mime, max_s)
            for out in resampler.resample(None):  # what the resampler still holds
                chunks.append(out.to_ndarray().reshape(-1))
    except av.FFmpegError as exc:
        raise AudioError(400, f"not a readable {mime} file: {exc}") from None
    samples = np.concatenate(chunks) if chunks else np.zeros(0, np.float32)
    if len(samples) > limit:
        raise _too_long(mime, max_s)
    return np.clip(samples, -1.0, 1.0).astype(np.float32, copy=False)


_DEMUXERS = {"audio/webm": "matroska", "audio/ogg": "ogg", "audio/mp4": "mp4", "audio/wav": "wav"}
"""FFmpeg's demuxer for each type: the Content-Type says what the bytes are, and a body that
is not that type is undecodable rather than guessed at."""
