"""The text encoder's label cache: shared by every session of a server."""

import threading

import numpy as np

from app.semantics import TextEncoder


class GatedEncoder(TextEncoder):
    """Deterministic rows; encoding a text in `gated` waits until `gate` opens."""

    model_id, dim = "gated", 4

    def __init__(self, gated: set[str]):
        super().__init__(cache_size=8)
        self.gated, self.calls = gated, []
        self.entered, self.gate = threading.Event(), threading.Event()

    def _encode_uncached(self, texts):
        self.calls.append(list(texts))
        if self.gated & set(texts):
            self.entered.set()
            self.gate.wait(10)
        rows = np.array([[len(t), ord(t[0]), 1.0, 0.0] for t in texts], np.float32)
        return rows / np.linalg.norm(rows, axis=1, keepdims=True)


def test_cached_labels_answer_while_another_caller_encodes_new_ones():
    encoder = GatedEncoder(gated={"armchair"})
    cached = encoder.encode(["chair", "table"])
    slow = threading.Thread(target=encoder.encode, args=(["armchair", "chair"],))
    slow.start()
    try:
        assert encoder.entered.wait(10)  # the new label is being encoded now
        assert np.array_equal(encoder.encode(["table", "chair"]), cached[::-1])
        assert slow.is_alive()  # the new label is still being encoded meanwhile
    finally:
        encoder.gate.set()
        slow.join(10)
    assert encoder.calls == [["chair", "table"], ["armchair"]]


def test_repeated_texts_are_encoded_once_and_the_cache_stays_bounded():
    encoder = GatedEncoder(gated=set())
    rows = encoder.encode(["a", "b", "a"])
    assert np.array_equal(rows[0], rows[2]) and encoder.calls == [["a", "b"]]
    encoder.encode([f"label {i}" for i in range(20)])
    assert len(encoder._cache) == 8
