"""The server's static towers (app/server/towers.py): the first static sessions created at
once wait for one distillation, a failed one is tried again by the next creator, a restart
reads the distilled tower from its directory instead of distilling again, and a session's
tower is found by hash (or refused, naming the hash, when the directory no longer holds it).

The distillation is a tiny random tower built in milliseconds (`StaticTower.build`), handed
to the service as its builder: the real one takes minutes and is measured by
`semanticxr towers distil`."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from app.semantics import DEFAULT_MODEL_ID
from app.semantics.static import StaticEncoder, StaticTower
from app.server.towers import MissingTowerError, TowerService

WORDS = ["[UNK]", "a", "the", "chair", "table", "##s"]


class Builder:
    """Builds a tiny tower when let through (`release`), counting its calls."""

    def __init__(self, fail_first: bool = False):
        self.calls, self.fail_first = 0, fail_first
        self.released = threading.Event()
        self.messages: list[str] = []

    def __call__(self, teacher: str, progress) -> bytes:
        self.calls += 1
        progress(f"building from {teacher}")
        self.released.wait(60)
        if self.fail_first and self.calls == 1:
            raise RuntimeError("the first distillation fails")
        rows = np.random.default_rng(0).normal(size=(len(WORDS), 16))
        return StaticTower.build(WORDS, rows, teacher=teacher).to_bytes()


def test_creators_asking_at_once_wait_for_one_distillation(tmp_path):
    build = Builder()
    service = TowerService(tmp_path / "towers", DEFAULT_MODEL_ID, build=build)
    got: list[StaticTower] = []
    threads = [
        threading.Thread(target=lambda: got.append(service.for_new_session())) for _ in range(6)
    ]
    for thread in threads:
        thread.start()
    build.released.set()
    for thread in threads:
        thread.join(60)
    assert build.calls == 1
    assert len(got) == 6 and len({tower.sha256 for tower in got}) == 1
    sha = got[0].sha256
    assert service.file_bytes(sha) == got[0].to_bytes()
    assert isinstance(service.encoder(sha), StaticEncoder)
    assert service.encoder(sha) is service.encoder(sha)  # one per tower, shared
    # a restart: the tower is read from the directory, not distilled again
    again = Builder()
    restarted = TowerService(tmp_path / "towers", DEFAULT_MODEL_ID, build=again)
    assert restarted.for_new_session().sha256 == sha and again.calls == 0


def test_a_failed_distillation_fails_its_creators_and_the_next_one_tries_again(tmp_path):
    build = Builder(fail_first=True)
    build.released.set()
    service = TowerService(tmp_path / "towers", DEFAULT_MODEL_ID, build=build)
    with pytest.raises(RuntimeError, match="the first distillation fails"):
        service.for_new_session()
    assert service.for_new_session().teacher == DEFAULT_MODEL_ID
    assert build.calls == 2


def test_a_tower_the_directory_does_not_hold_is_refused_naming_its_hash(tmp_path):
    service = TowerService(tmp_path / "towers", DEFAULT_MODEL_ID, build=Builder())
    missing = "ab" * 32
    assert service.tower(missing) is None and service.file_bytes(missing) is None
    with pytest.raises(MissingTowerError, match=f"{missing}.*--static-tower"):
        service.encoder(missing)
