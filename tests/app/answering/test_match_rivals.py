"""The match rule's rivals and its shipped background embeddings (real MiniLM): another kind
of the same head noun stays a rival, a label sharing a served name does not, and the shipped
embeddings are the tower's own."""

from __future__ import annotations

import numpy as np
import pytest

from app.answering.label_knowledge import SERVED_LABEL_TEXTS
from app.answering.relevance import (
    QueryRater,
    background_text_list,
    background_texts,
    names_of,
    other_kind,
    rater_for,
    shipped_embeddings,
)


@pytest.mark.parametrize(
    ("label", "other", "expected"),
    [
        ("floor lamp", "table lamp", True),
        ("lamp", "table lamp", True),  # the query names a kind the plain label may not be
        ("table lamp", "lamp", False),  # "the lamp" names a table lamp, less precisely
        ("table lamp", "table lamp", False),
        ("nightstand", "bedside table", False),  # another head noun
        ("Dining Table", "coffee table", True),
    ],
)
def test_another_kind_of_the_same_head_noun(label, other, expected):
    assert other_kind(label, other) is expected


def test_names_are_the_texts_before_the_first_description():
    texts = ["backpack", "knapsack", "rucksack", "a bag carried by a strap on your back", "bag"]
    assert names_of("backpack", texts) == {"backpack", "knapsack", "rucksack"}
    assert names_of("Nightstand", []) == {"nightstand"}


def test_a_label_sharing_a_served_name_with_the_asked_word_matches(encoder):
    # WordNet names a painting "picture" too; the background's "picture" is then no rival
    rater = rater_for(encoder)
    embedding = encoder.encode_query("the picture")
    assert "picture" in names_of("painting", background_texts()["painting"])
    assert rater.rate(embedding, ["painting"], SERVED_LABEL_TEXTS).match


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
