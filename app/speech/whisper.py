"""Whisper from a local folder (`--asr whisper:DIR`): `WhisperForConditionalGeneration` and
`WhisperProcessor` saved with `save_pretrained`, loaded from DIR only (never the hub).

The session's labels go in as Whisper's prompt (the "previous text" it conditions on), which
is how Whisper is told the words to expect. `write_tiny_whisper(DIR)` writes a small random
Whisper of the real architecture with a tokenizer trained here, offline: it runs the real
loading and generation code in seconds, and its transcripts are noise.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from app.speech.audio import SAMPLE_RATE_HZ
from app.speech.recognisers import Transcript
from app.speech.vocabulary import normalised_labels

MAX_NEW_TOKENS = 64
"""Longest transcript in tokens (a question is a sentence)."""
PROMPT_MAX_LABELS = 40
"""Labels named in the prompt (Whisper's prompt takes at most half its 448-token context)."""


class WhisperRecogniser:
    name = "whisper"

    def __init__(self, model_dir: str):
        import torch
        from transformers import WhisperForConditionalGeneration, WhisperProcessor

        torch.set_num_threads(1)  # one question at a time; the server's cores map keyframes
        self._torch = torch
        self.processor = WhisperProcessor.from_pretrained(model_dir, local_files_only=True)
        self.model = WhisperForConditionalGeneration.from_pretrained(
            model_dir, local_files_only=True
        ).eval()
        self._prompts: dict[tuple[str, ...], object] = {}

    def transcribe(self, samples: np.ndarray, labels: Sequence[str]) -> Transcript:
        features = self.processor(
            samples, sampling_rate=SAMPLE_RATE_HZ, return_tensors="pt"
        ).input_features
        with self._torch.no_grad():
            ids = self.model.generate(
                features,
                max_new_tokens=MAX_NEW_TOKENS,
                prompt_ids=self._prompt(labels),
                language="en",
                task="transcribe",
            )
        text = self.processor.batch_decode(ids, skip_special_tokens=True)[0]
        return Transcript(" ".join(text.lower().split()))

    def _prompt(self, labels: Sequence[str]):
        """The prompt ids of these labels, made once per label set."""
        key = tuple(normalised_labels(labels)[:PROMPT_MAX_LABELS])
        if not key:
            return None
        if key not in self._prompts:
            self._prompts[key] = self.processor.get_prompt_ids(
                ", ".join(key) + ".", return_tensors="pt"
            )
        return self._prompts[key]


WIDTH = 32
BPE_VOCAB_SIZE = 400
SPECIAL_TOKENS = (
    "<|endoftext|>",
    "<|startoftranscript|>",
    "<|en|>",
    "<|translate|>",
    "<|transcribe|>",
    "<|startoflm|>",
    "<|startofprev|>",
    "<|nospeech|>",
    "<|notimestamps|>",
)
"""Whisper's special tokens, in its order (the tiny one speaks English only)."""


def write_tiny_whisper(out: str | Path, seed: int = 0) -> Path:
    """A small random Whisper (1 layer each side, 32 wide, 80 mel bins) with its processor
    and a byte-level BPE tokenizer trained here on the question words, in `out`, as `--asr
    whisper:OUT` loads it. Returns out."""
    import torch
    from tokenizers import Tokenizer, models, pre_tokenizers, trainers
    from transformers import (
        GenerationConfig,
        WhisperConfig,
        WhisperFeatureExtractor,
        WhisperForConditionalGeneration,
        WhisperProcessor,
        WhisperTokenizer,
    )
    from transformers.utils import logging as hf_logging

    from app.speech.vocabulary import indoor_tags, session_corpus

    hf_logging.set_verbosity_error()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(seed)

    bpe = Tokenizer(models.BPE())
    bpe.pre_tokenizer = pre_tokenizers.ByteLevel(add_prefix_space=False)
    trainer = trainers.BpeTrainer(
        vocab_size=BPE_VOCAB_SIZE,
        initial_alphabet=pre_tokenizers.ByteLevel.alphabet(),
        show_progress=False,
    )
    bpe.train_from_iterator([" " + line for line in session_corpus(indoor_tags())], trainer)
    model = json.loads(bpe.to_str())["model"]
    (out / "vocab.json").write_text(json.dumps(model["vocab"]))
    merges = [m if isinstance(m, str) else " ".join(m) for m in model["merges"]]
    (out / "merges.txt").write_text("#version: 0.2\n" + "\n".join(merges) + "\n")
    tokenizer = WhisperTokenizer(
        str(out / "vocab.json"),
        str(out / "merges.txt"),
        unk_token="<|endoftext|>",
        bos_token="<|endoftext|>",
        eos_token="<|endoftext|>",
        pad_token="<|endoftext|>",
    )
    tokenizer.add_special_tokens({"additional_special_tokens": list(SPECIAL_TOKENS)})
    ids = {token: tokenizer.convert_tokens_to_ids(token) for token in SPECIAL_TOKENS}
    eot = ids["<|endoftext|>"]

    config = WhisperConfig(
        vocab_size=len(tokenizer),
        num_mel_bins=80,
        d_model=WIDTH,
        encoder_layers=1,
        decoder_layers=1,
        encoder_attention_heads=2,
        decoder_attention_heads=2,
        encoder_ffn_dim=2 * WIDTH,
        decoder_ffn_dim=2 * WIDTH,
        max_source_positions=1500,
        max_target_positions=448,
        decoder_start_token_id=ids["<|startoftranscript|>"],
        bos_token_id=eot,
        eos_token_id=eot,
        pad_token_id=eot,
        suppress_tokens=[],
        begin_suppress_tokens=[],
    )
    whisper = WhisperForConditionalGeneration(config).eval()
    whisper.generation_config = GenerationConfig(
        decoder_start_token_id=ids["<|startoftranscript|>"],
        bos_token_id=eot,
        eos_token_id=eot,
        pad_token_id=eot,
        max_length=448,
        is_multilingual=True,
        lang_to_id={"<|en|>": ids["<|en|>"]},
        task_to_id={"transcribe": ids["<|transcribe|>"], "translate": ids["<|translate|>"]},
        no_timestamps_token_id=ids["<|notimestamps|>"],
        prev_sot_token_id=ids["<|startofprev|>"],
        suppress_tokens=[],
        begin_suppress_tokens=[],
    )
    whisper.save_pretrained(out)
    WhisperProcessor(
        feature_extractor=WhisperFeatureExtractor(feature_size=80), tokenizer=tokenizer
    ).save_pretrained(out)
    return out
