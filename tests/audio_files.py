"""Audio files for tests, written as browsers and curl send them: PCM WAV by the standard
library, WebM/Ogg (Opus) and MP4 (AAC) by PyAV, as a page's MediaRecorder makes them."""

from __future__ import annotations

import io
import wave

import numpy as np


def wav_bytes(samples: np.ndarray, rate_hz: int, channels: int = 1, width: int = 2) -> bytes:
    """PCM WAV of mono float samples, copied to `channels`, `width` bytes a sample."""
    scale = 2 ** (8 * width - 1) - 1
    pcm = np.repeat((samples * scale).astype("<i4")[:, None], channels, axis=1).ravel()
    raw = pcm.astype("<i2").tobytes() if width == 2 else pcm.view(np.uint8).reshape(-1, 4)[:, :3]
    out = io.BytesIO()
    with wave.open(out, "wb") as w:
        w.setnchannels(channels)
        w.setsampwidth(width)
        w.setframerate(rate_hz)
        w.writeframes(raw if isinstance(raw, bytes) else raw.tobytes())
    return out.getvalue()


def pyav_bytes(samples: np.ndarray, rate_hz: int, container: str, codec: str) -> bytes:
    """`samples` encoded by PyAV as a browser's MediaRecorder would send them."""
    import av

    out = io.BytesIO()
    with av.open(out, mode="w", format=container) as c:
        stream = c.add_stream(codec, rate=48_000 if codec == "libopus" else rate_hz)
        stream.layout = "mono"
        frame = av.AudioFrame.from_ndarray(samples[None, :], format="flt", layout="mono")
        frame.sample_rate = rate_hz
        resampler = av.AudioResampler(format=stream.format.name, layout="mono", rate=stream.rate)
        for resampled in [*resampler.resample(frame), *resampler.resample(None)]:
            for packet in stream.encode(resampled):
                c.mux(packet)
        for packet in stream.encode(None):
            c.mux(packet)
    return out.getvalue()
