"""The WordNet reader on Debian's real files (wordnet-base): a label's texts."""

from __future__ import annotations

import os

import pytest

from app.answering.label_knowledge import WordNet, served_texts, texts_of, wordnet_dir

pytestmark = pytest.mark.skipif(
    not os.path.isfile(os.path.join(wordnet_dir(), "index.noun")),
    reason=f"WordNet is not installed at {wordnet_dir()} (Debian package wordnet-base)",
)


@pytest.fixture(scope="module")
def wordnet():
    reader = WordNet(wordnet_dir())
    yield reader
    reader.close()


def test_a_label_with_synonyms_gets_them_its_definition_and_its_kind(wordnet):
    texts = texts_of(wordnet, "rucksack")
    assert texts[0] == "rucksack"
    assert {"backpack", "knapsack"} <= set(texts)
    assert any("bag carried by a strap" in t for t in texts)  # the definition
    assert "bag" in texts  # what kind of thing it is


def test_a_multiword_label_is_read_whole_or_by_its_head_noun(wordnet):
    assert wordnet.lemma("Coffee  Mug") == "coffee_mug"
    assert "coffee mug" in texts_of(wordnet, "coffee mug")
    texts = texts_of(wordnet, "wall cabinet")  # not in WordNet: its head noun "cabinet"
    assert texts[0] == "wall cabinet" and "cabinet" in texts


def test_a_plural_is_read_as_its_noun(wordnet):
    assert wordnet.lemma("mugs") == "mug"
    assert wordnet.lemma("shelves") == "shelf"  # noun.exc


def test_an_unknown_word_is_its_own_only_text(wordnet):
    assert texts_of(wordnet, "xyzzy plugh") == ("xyzzy plugh",)


def test_a_sense_that_is_no_thing_is_skipped(wordnet):
    texts = " ".join(texts_of(wordnet, "table"))
    assert "furniture" in texts and "rows and columns" not in texts


def test_the_server_sends_texts_only_for_labels_outside_the_shipped_background():
    assert served_texts("sofa") is None  # every end holds the background's texts
    zebra = served_texts("zebra")
    assert zebra is not None and zebra[0] == "zebra" and len(zebra) > 1


def test_a_directory_without_wordnet_is_a_clear_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="index.noun"):
        WordNet(tmp_path)


def test_a_rare_sense_is_left_out_by_its_tag_count(wordnet):
    box = wordnet.senses("box")
    assert wordnet.tag_count("box", box[0]) > 2 * wordnet.tag_count("box", box[1])
    texts = " ".join(texts_of(wordnet, "box"))
    assert "container" in texts and "theater" not in texts and "loge" not in texts


def test_a_second_sense_about_as_common_as_the_first_is_kept(wordnet):
    texts = " ".join(texts_of(wordnet, "plant"))
    assert "industrial labor" in texts and "living organism" in texts


def test_without_tag_counts_every_physical_sense_up_to_the_limit_is_read(tmp_path):
    for name in ("index.noun", "data.noun", "noun.exc"):
        (tmp_path / name).symlink_to(os.path.join(wordnet_dir(), name))
    reader = WordNet(tmp_path)
    try:
        assert reader.tag_count("box", reader.senses("box")[0]) is None
        assert "theater" in " ".join(texts_of(reader, "box"))
    finally:
        reader.close()
