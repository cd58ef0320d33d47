"""Recognisers: audio (16 kHz mono float32) + the session's labels -> a transcript.

`--asr` chooses one: `pocketsphinx` (embedded, the default: the PyPI wheel ships its
US-English model, nothing to download) or `whisper:DIR` (a Whisper checkpoint saved by
`transformers` in DIR, loaded from it only). `check_asr` runs at start-up without loading
anything heavy, so a missing model stops `serve` at once with the flag named; the model
itself loads in the recogniser worker on the first question (`pool.py`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

ASR_CHOICES = ("pocketsphinx", "whisper:DIR")
"""What `--asr` takes."""
WHISPER_FILES = (
    ("config.json",),
    ("tokenizer_config.json",),
    ("preprocessor_config.json", "processor_config.json"),
)
"""Files a Whisper folder must hold, one of each tuple (the model's and the processor's
`save_pretrained`; transformers 5 names the processor's file processor_config.json)."""


class AsrSettingError(ValueError):
    """An `--asr` value that cannot work: not a known recogniser, or its model is missing."""


@dataclass(frozen=True)
class Transcript:
    text: str
    """What was heard, lower case, as the query's text."""
    confidence: float | None = None
    """The recogniser's posterior for `text` in [0, 1], when it computes one."""


class Recogniser(Protocol):
    name: str

    def transcribe(self, samples: np.ndarray, labels: Sequence[str]) -> Transcript:
        """samples: float32 [n] at 16 kHz mono; labels: the session's, which may shape what
        the recogniser expects (rebuilt when they change, not per question)."""
        ...


@dataclass(frozen=True)
class AsrChoice:
    kind: str
    """"pocketsphinx" or "whisper"."""
    model_dir: str | None = None


def parse_asr(value: str) -> AsrChoice:
    """`--asr` as an AsrChoice; AsrSettingError naming the flag for anything else."""
    value = value.strip()
    if value == "pocketsphinx":
        return AsrChoice("pocketsphinx")
    if value.startswith("whisper:") and value[len("whisper:") :].strip():
        return AsrChoice("whisper", value[len("whisper:") :].strip())
    raise AsrSettingError(
        f"--asr {value!r}: give one of {', '.join(ASR_CHOICES)} (DIR: a Whisper model saved "
        "with transformers' save_pretrained, model and processor)"
    )


def check_asr(value: str) -> AsrChoice:
    """The choice, its model checked present (nothing loaded); AsrSettingError naming `--asr`
    and what is missing."""
    choice = parse_asr(value)
    if choice.kind == "pocketsphinx":
        try:
            import pocketsphinx  # noqa: F401  (its wheel carries the model)
        except ImportError:
            raise AsrSettingError(
                "--asr pocketsphinx: the pocketsphinx package is not installed "
                "(pip install pocketsphinx)"
            ) from None
        return choice
    folder = Path(choice.model_dir or "")
    missing = [
        " or ".join(names)
        for names in WHISPER_FILES
        if not any((folder / name).is_file() for name in names)
    ]
    if missing:
        raise AsrSettingError(
            f"--asr whisper:{folder}: {', '.join(missing)} missing in {folder} (a Whisper model "
            "saved with save_pretrained, model and processor: on a machine with hub access, "
            f"`hf download openai/whisper-base.en --local-dir {folder}`; for tests, "
            f"`semanticxr models tiny-whisper --out {folder}`)"
        )
    return choice
