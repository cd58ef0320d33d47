"""Spoken questions (docs/architecture.md): audio in, the question's text out.

    audio.py        bytes of a MIME type -> 16 kHz mono float32 (`decode_audio`, `AudioError`)
    recognisers.py  `--asr`: `parse_asr`, `check_asr`, the `Recogniser` interface, `Transcript`
    sphinx.py       the embedded recogniser (PocketSphinx, a language model per label set)
    vocabulary.py   what a session's recogniser expects to hear (labels, question forms)
    whisper.py      Whisper from a local folder; `write_tiny_whisper` for tests
    pool.py         `RecogniserPool`: worker processes, a hard time limit, busy refusals

Below the server (which answers the recognised text as a typed query) and above mapping
(whose question grammar shapes the vocabulary). Importing it loads no recogniser.
"""

from app.speech.audio import AUDIO_TYPES, MAX_SPEECH_S, Audio, AudioError, audio_type, decode_audio
from app.speech.pool import Heard, RecogniserPool, RecognisersBusy
from app.speech.recognisers import AsrChoice, AsrSettingError, Transcript, check_asr, parse_asr

__all__ = [
    "AUDIO_TYPES",
    "MAX_SPEECH_S",
    "AsrChoice",
    "AsrSettingError",
    "Audio",
    "AudioError",
    "Heard",
    "RecogniserPool",
    "RecognisersBusy",
    "Transcript",
    "audio_type",
    "check_asr",
    "decode_audio",
    "parse_asr",
]
