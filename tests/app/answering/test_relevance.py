"""Calibrated relevance: real queries match, nonsense and absent objects do not (real MiniLM)."""

from __future__ import annotations

import numpy as np
import pytest

from app.answering.label_knowledge import SERVED_LABEL_TEXTS
from app.answering.relevance import CONFIDENT, QueryRater, is_match, rater_for
from app.cli.demo import DEFAULT_QUERIES
from app.semantics import TextEncoder

# An apartment without keys; a laptop and a keyboard are what "keys" used to find.
APARTMENT = [
    "sofa", "chair", "refrigerator", "sink", "coffee maker", "dishwasher", "bed",
    "dining table", "tv", "laptop", "keyboard", "bathtub", "toilet", "bookshelf",
]  # fmt: skip


def answer(encoder, text: str, labels: list[str], k: int = 5):
    """The top-k labels by similarity to `text` (the hits a map of `labels` gives), rated."""
    embedding = encoder.encode_query(text)
    top = [labels[i] for i in np.argsort(-(encoder.encode(labels) @ embedding))[:k]]
    return top, rater_for(encoder).rate(embedding, top)


@pytest.mark.parametrize(
    "text",
    [*DEFAULT_QUERIES, "where do I keep the milk cold", "a seat", "a chair", "the red chair"],
)
def test_the_demos_and_the_tests_real_queries_are_confident_matches(encoder, text):
    top, rating = answer(encoder, text, APARTMENT)
    assert rating.match, (top, rating)
    assert rating.relevance[0] == max(rating.relevance) >= CONFIDENT


@pytest.mark.parametrize("text", ["xyzzy plugh", "asdf qwer", "hello world", "keys"])
def test_nonsense_and_an_absent_object_are_no_confident_match(encoder, text):
    top, rating = answer(encoder, text, APARTMENT)
    assert len(rating.relevance) == len(top) == 5  # the hits are still rated and listed
    assert not rating.match, (top, rating)
    assert all(0.0 <= r < CONFIDENT for r in rating.relevance)


def test_keys_match_once_the_map_holds_keys(encoder):
    top, rating = answer(encoder, "keys", [*APARTMENT, "keys"])
    assert top[0] == "keys" and rating.match and rating.relevance[0] == 1.0


def test_a_label_outside_the_vocabulary_is_rated_against_it(encoder):
    rater = QueryRater(encoder, vocabulary=["chair", "table", "lamp", "sofa", "bed", "sink"])
    rating = rater.rate(encoder.encode_query("a zebra"), ["zebra", "chair"])
    assert rating.relevance[0] > rating.relevance[1]


class ConstantEncoder(TextEncoder):
    """Every text the same embedding: no label can stand out."""

    model_id, dim = "constant", 4

    def _encode_uncached(self, texts: list[str]) -> np.ndarray:
        return np.tile(np.array([1.0, 0.0, 0.0, 0.0], np.float32), (len(texts), 1))


def test_an_encoder_that_tells_nothing_apart_matches_nothing():
    encoder = ConstantEncoder()
    rating = QueryRater(encoder).rate(encoder.encode_query("chair"), ["chair", "sofa"])
    assert rating.relevance == [0.0, 0.0] and not rating.match


def test_no_hits_no_match(encoder):
    assert rater_for(encoder).rate(encoder.encode_query("chair"), []).match is False
    assert not is_match([]) and is_match([0.2, CONFIDENT])


@pytest.mark.parametrize(
    ("text", "label"),
    [("my rucksack", "backpack"), ("the knapsack", "backpack"), ("where is my couch", "sofa")],
)
def test_a_thing_named_by_another_word_matches_its_label(encoder, text, label):
    # rucksack -> backpack scores 0.08 by their names alone: the label's WordNet texts tie them
    rater = rater_for(encoder)
    embedding = encoder.encode_query(text)
    assert rater.rate(embedding, [label], SERVED_LABEL_TEXTS).match, text
    assert not rater.rate(embedding, ["dishwasher"], SERVED_LABEL_TEXTS).match, text


def test_a_label_outside_the_background_is_matched_by_the_texts_served_with_it(encoder):
    rater = rater_for(encoder)
    embedding = encoder.encode_query("the zebra")
    texts = {"zebra": SERVED_LABEL_TEXTS["zebra"]}
    assert rater.rate(embedding, ["zebra"], texts).match
    assert (
        rater.rate(embedding, ["zebra"], SERVED_LABEL_TEXTS).relevance
        == rater.rate(embedding, ["zebra"], texts).relevance
    )  # the server's texts and the served copy rate alike


def test_the_rival_is_the_background_label_the_gap_trails(encoder):
    rater = QueryRater(
        encoder,
        vocabulary=["keys", "keyboard", "sofa", "lamp", "sink"],
        vocabulary_texts={"sofa": ("couch", "an upholstered seat for more than one person")},
    )
    query = encoder.encode_query("where are my keys")
    # a map without keys answers with the keyboard; the query names the keys outright
    assert rater.rival(query, "keyboard") == ("keys", "keys")
    (keyboard,) = rater.standing(query, ["keyboard"])
    assert keyboard.gap > 0
    # the keys themselves trail nothing the query names better: their rival is behind them
    label, _ = rater.rival(query, "keys")
    assert label != "keys"
    assert rater.standing(query, ["keys"])[0].gap < 0
    # a rival is found by any of its texts
    assert rater.rival(encoder.encode_query("the couch"), "lamp") == ("sofa", "couch")
