"""The match rule's shipped background embeddings (real MiniLM): they are the tower's own,
a stale file is not read, and a rater reading them rates as one that embeds the texts."""

from __future__ import annotations

import numpy as np

from app.answering.label_knowledge import SERVED_LABEL_TEXTS
from app.answering.relevance import (
    QueryRater,
    background_text_list,
    background_texts,
    rater_for,
    shipped_embeddings,
)


def test_the_shipped_background_embeddings_are_the_towers_own(encoder):
    texts = background_text_list()
    shipped = shipped_embeddings(encoder.model_id, texts, encoder.dim)
    assert shipped is not None, "python -m bench.relevance --calibrate ships them"
    sample = texts[:: max(len(texts) // 50, 1)]
    own = encoder.encode(sample)
    assert np.abs(np.stack([shipped[t] for t in sample]) - own).max() < 2e-3  # float16


def test_stale_or_unknown_embeddings_are_not_used(encoder):
    texts = background_text_list()
    assert shipped_embeddings(encoder.model_id, [*texts, "a text added since"], encoder.dim) is None
    assert shipped_embeddings("no-such-tower", texts, encoder.dim) is None


def test_the_rater_reads_the_shipped_rows_and_rates_as_if_it_embedded_them(encoder):
    shipped = rater_for(encoder)
    embedded = QueryRater(encoder, vocabulary_texts=dict(background_texts()))  # embeds itself
    labels = ["sofa", "refrigerator", "zebra"]
    for text in ("where can I sit", "the fridge", "the zebra", "xyzzy plugh"):
        embedding = encoder.encode_query(text)
        a = shipped.rate(embedding, labels, SERVED_LABEL_TEXTS)
        b = embedded.rate(embedding, labels, SERVED_LABEL_TEXTS)
        assert a.match == b.match
        assert np.allclose(a.relevance, b.relevance, atol=0.02)
