"""The embedded recogniser: PocketSphinx 5 with its packaged US-English acoustic model, and a
trigram language model per set of session labels (`vocabulary.session_corpus` over the
BACKGROUND_WORDS most likely words of the packaged general model), built when the labels
change and kept for the next questions (the last CACHED_VOCABULARIES sets).

Audio is conditioned first, as a microphone would deliver it: synthesised (and noise
suppressed) audio holds runs of exact zeros, on which PocketSphinx's front end drops words
(espeak-ng questions word for word: 41 % without, 90 % with), so each question gets
CONDITION_PAD_S of silence either side, a peak of CONDITION_PEAK and a noise floor of
CONDITION_NOISE (seeded: the same audio is always heard the same).
"""

from __future__ import annotations

import logging
import os
import re
import tempfile
import time
from collections import OrderedDict
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from app.speech.audio import SAMPLE_RATE_HZ
from app.speech.recognisers import Transcript
from app.speech.vocabulary import background_corpus, session_corpus, vocabulary_key, words_of

log = logging.getLogger("semanticxr.speech")
_NOT_WORDS = re.compile(r"<s>|</s>|<sil>|\[|\+")
"""Segments that are no word of the transcript: sentence marks, silence, fillers."""

BACKGROUND_WORDS = 5_000
"""Most likely words of the general model kept as the language model's background (5,000:
40 % paraphrase top-1 at 0.35 s; 20,000: 36 % at 0.7 s; the whole 27 MB model: 32 % at 1.1 s)."""
CORPUS_MIN_WORDS = 8_000
"""The session corpus is said over until it holds this many words, so that its weight
against the background is the one measured (the apartment's 52 labels: ~8,700 words)
however few labels a map has."""
CACHED_VOCABULARIES = 8
"""Session vocabularies (decoders) a worker keeps built."""
CONDITION_PAD_S = 0.3
CONDITION_PEAK = 0.5
CONDITION_NOISE = 1e-3
"""Noise floor, standard deviation at full scale 1 (-60 dBFS, a quiet room's microphone)."""
SPELLED_MAX_CHARS = 4
"""A label word missing from the pronunciation dictionary is said letter by letter ("tv")
when this short; longer ones are left out of the vocabulary."""


def condition(samples: np.ndarray) -> np.ndarray:
    """float32 [n] in [-1, 1] -> int16 [n + 2 pad] as the recogniser hears it."""
    peak = float(np.abs(samples).max()) if samples.size else 0.0
    scaled = samples * (CONDITION_PEAK / peak) if peak > 0 else samples
    pad = np.zeros(int(CONDITION_PAD_S * SAMPLE_RATE_HZ), np.float32)
    padded = np.concatenate([pad, scaled.astype(np.float32), pad])
    noise = np.random.default_rng(len(padded)).normal(0.0, CONDITION_NOISE, padded.shape)
    return (np.clip(padded + noise, -1.0, 1.0) * 32767).astype(np.int16)


class SphinxRecogniser:
    name = "pocketsphinx"

    def __init__(self):
        import pocketsphinx

        self._ps = pocketsphinx
        model = Path(pocketsphinx.get_model_path()) / "en-us"
        self._pronunciations = _read_dictionary(model / "cmudict-en-us.dict")
        general = pocketsphinx.NGramModel.readfile(str(model / "en-us.lm.bin"))
        speakable = [w for w in self._pronunciations if w.replace("'", "").isalpha()]
        speakable.sort(key=lambda w: -general.prob([w]))
        self._background = speakable[:BACKGROUND_WORDS]
        self._decoders: OrderedDict[str, object] = OrderedDict()
        self._dir = tempfile.TemporaryDirectory(prefix="semanticxr-asr-")

    def transcribe(self, samples: np.ndarray, labels: Sequence[str]) -> Transcript:
        decoder = self._decoder_for(labels)
        decoder.start_utt()
        decoder.process_raw(condition(samples).tobytes(), full_utt=True)
        decoder.end_utt()
        hyp = decoder.hyp()
        text = hyp.hypstr.strip() if hyp is not None else ""
        posteriors = [seg.prob for seg in decoder.seg() if not _NOT_WORDS.match(seg.word)]
        confidence = float(np.mean(posteriors)) if posteriors else None
        return Transcript(text, confidence)

    def _decoder_for(self, labels: Sequence[str]):
        """The decoder of these labels' vocabulary, built now if it is not among the cached."""
        key = vocabulary_key(labels)
        if key in self._decoders:
            self._decoders.move_to_end(key)
            return self._decoders[key]
        t0 = time.perf_counter()
        lm_path, dict_path = self._write_model(key, labels)
        decoder = self._ps.Decoder(
            samprate=SAMPLE_RATE_HZ, lm=str(lm_path), dict=str(dict_path), loglevel="FATAL"
        )
        os.unlink(lm_path)
        os.unlink(dict_path)
        self._decoders[key] = decoder
        while len(self._decoders) > CACHED_VOCABULARIES:
            self._decoders.popitem(last=False)
        log.info(
            "speech vocabulary of %d labels built in %.0f ms",
            len(labels),
            (time.perf_counter() - t0) * 1e3,
        )
        return decoder

    def _write_model(self, key: str, labels: Sequence[str]) -> tuple[Path, Path]:
        """The ARPA language model and pronunciation dictionary of these labels."""
        from pocketsphinx.lm import ArpaBoLM

        lines = session_corpus(labels)
        repeat = -(-CORPUS_MIN_WORDS // max(sum(len(line.split()) for line in lines), 1))
        corpus = "\n".join(lines * repeat + background_corpus())
        words_path = Path(self._dir.name) / f"{key}.words"
        words_path.write_text("\n".join(self._background) + "\n")
        model = ArpaBoLM(text=corpus, add_start=True, word_file=str(words_path))
        model.compute()
        lm_path = Path(self._dir.name) / f"{key}.arpa"
        model.write_file(str(lm_path))
        os.unlink(words_path)
        vocabulary = dict.fromkeys([*words_of(corpus), *self._background])
        lines = []
        for word in vocabulary:
            for i, phones in enumerate(self._pronounce(word)):
                lines.append(f"{word if i == 0 else f'{word}({i + 1})'} {phones}")
        dict_path = Path(self._dir.name) / f"{key}.dict"
        dict_path.write_text("\n".join(lines) + "\n")
        return lm_path, dict_path

    def _pronounce(self, word: str) -> list[str]:
        if word in self._pronunciations:
            return self._pronunciations[word]
        letters = [self._pronunciations.get(c, [None])[0] for c in word]
        if len(word) <= SPELLED_MAX_CHARS and all(letters):
            return [" ".join(letters)]  # type: ignore[arg-type]
        log.info("speech vocabulary: no pronunciation of %r, left out", word)
        return []


def _read_dictionary(path: Path) -> dict[str, list[str]]:
    """CMUdict as PocketSphinx ships it: word -> its pronunciations, "word(2)" folded in."""
    pronunciations: dict[str, list[str]] = {}
    with open(path, encoding="utf-8") as f:
        for line in f:
            word, _, phones = line.strip().partition(" ")
            if phones:
                pronunciations.setdefault(word.split("(", 1)[0], []).append(phones.strip())
    return pronunciations
