"""Distilling the static tower (app/semantics/distil.py) and keeping it (TowerStore)."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from app.semantics import DEFAULT_MODEL_ID, get_text_encoder
from app.semantics.distil import (
    STATIC_DIM,
    TowerStore,
    corpus_texts,
    distil_static_tower,
    load_static_tower,
)
from app.semantics.static import StaticEncoder, StaticTower, TowerError


def _tiny(seed: int = 0) -> bytes:
    vocab = ["[PAD]", "[UNK]", "a", "chair", "table", "##s"]
    rows = np.random.default_rng(seed).standard_normal((len(vocab), 8))
    return StaticTower.build(vocab, rows, teacher=DEFAULT_MODEL_ID).to_bytes()


def test_a_teacher_is_distilled_once_per_directory(tmp_path):
    builds = []

    def build(teacher: str) -> bytes:
        builds.append(teacher)
        return _tiny()

    first = TowerStore(tmp_path).for_teacher(DEFAULT_MODEL_ID, build)
    again = TowerStore(tmp_path).for_teacher(DEFAULT_MODEL_ID, build)  # another process, say
    assert builds == [DEFAULT_MODEL_ID]
    assert again.to_bytes() == first.to_bytes()
    assert TowerStore(tmp_path).get(first.sha256) == first.to_bytes()


def test_concurrent_callers_wait_for_the_one_distillation(tmp_path):
    store, builds, towers = TowerStore(tmp_path), [], []
    started = threading.Event()

    def build(teacher: str) -> bytes:
        builds.append(teacher)
        started.set()
        return _tiny()

    threads = [
        threading.Thread(target=lambda: towers.append(store.for_teacher(DEFAULT_MODEL_ID, build)))
        for _ in range(4)
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(30)
    assert len(builds) == 1 and len({t.sha256 for t in towers}) == 1 and len(towers) == 4


def test_a_damaged_file_is_distilled_again(tmp_path):
    store = TowerStore(tmp_path)
    tower = store.for_teacher(DEFAULT_MODEL_ID, lambda teacher: _tiny())
    (tmp_path / f"{tower.sha256}.sxt").write_bytes(b"damaged")
    again = store.for_teacher(DEFAULT_MODEL_ID, lambda teacher: _tiny(1))
    assert again.sha256 != tower.sha256


def test_the_store_reads_only_tower_names_and_keeps_only_towers(tmp_path):
    store = TowerStore(tmp_path)
    assert store.get("../../etc/passwd") is None and store.get("0" * 64) is None
    with pytest.raises(TowerError):
        store.put(b"not a tower")
    tower = store.put(_tiny())
    assert store.get(tower.sha256) == _tiny()


def test_load_static_tower_reads_a_file(tmp_path):
    path = tmp_path / "t.sxt"
    path.write_bytes(_tiny())
    assert load_static_tower(path).to_bytes() == _tiny()


def test_the_corpus_is_everyday_text_and_the_same_every_time():
    texts = corpus_texts(500)
    assert len(texts) == 500 and len(set(texts)) == 500
    assert texts == corpus_texts(500)
    assert any(t.startswith(("where", "find", "is there", "show me")) for t in texts)


def test_another_teacher_is_refused_for_now():
    with pytest.raises(ValueError, match="only"):
        distil_static_tower("openai/clip-vit-base-patch32")


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_a_real_distillation_ranks_like_its_teacher():
    """model2vec on the packaged MiniLM, the map fitted on 300 texts: it encodes as a static
    tower does, and ranks plain names the way MiniLM does."""
    data = distil_static_tower(corpus=300, progress=lambda line: None)
    tower = StaticTower.from_bytes(data)
    assert tower.dim == STATIC_DIM and tower.teacher == DEFAULT_MODEL_ID
    assert len(tower.vocab) > 25_000
    static, minilm = StaticEncoder(tower), get_text_encoder()
    labels = ["chair", "refrigerator", "bed", "lamp", "television", "sink", "book", "plant"]
    asked = ["a chair", "the fridge", "a bed to sleep in", "the lamp", "a tv", "the sink"]
    for encoder in (static, minilm):
        best = np.argmax(encoder.encode(asked) @ encoder.encode(labels).T, axis=1)
        assert [labels[i] for i in best] == [
            "chair",
            "refrigerator",
            "bed",
            "lamp",
            "television",
            "sink",
        ], encoder.model_id
