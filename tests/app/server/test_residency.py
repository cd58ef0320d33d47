"""Residency: which sessions are in memory. At most a budget, each loaded once, unloaded least
recently used first, never while busy; no room when every resident one is busy.

`Residency` is plain Python: these tests drive it with small sessions and a store that is a
dict, and real threads for the concurrency. Through the real server:
tests/app/server/test_resident_sessions.py.
"""

from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor

import pytest

from app.server.sessions import Residency, ResidentSessionsBusy


class Item:
    """A session as residency sees it: an id, uses, a last use, and a keyframe flag."""

    def __init__(self, sid: str):
        self.id = sid
        self.users = 0
        self.last_used = time.monotonic()
        self.mapping = False

    @property
    def busy(self) -> bool:
        return self.users > 0 or self.mapping

    def touch(self) -> None:
        self.last_used = time.monotonic()


class Shelf:
    """The store side: which ids exist, what was loaded and unloaded, and failures on demand."""

    def __init__(self, *ids: str):
        self.ids = set(ids)
        self.loads: list[str] = []
        self.unloads: list[tuple[str, str]] = []
        self.refuse_unload = False
        self.load_gate: threading.Event | None = None

    def load(self, sid: str) -> Item:
        if sid not in self.ids:
            raise KeyError(sid)
        self.loads.append(sid)
        if self.load_gate is not None:
            assert self.load_gate.wait(10)
        return Item(sid)

    def unload(self, item: Item, reason: str) -> None:
        if self.refuse_unload:
            raise OSError("the disk refused the write")
        self.unloads.append((item.id, reason))


def residency(shelf: Shelf, budget: int = 2) -> Residency[Item]:
    return Residency(budget, shelf.load, shelf.unload, retry_after_s=5)


def use(resident: Residency[Item], sid: str) -> Item:
    item = resident.acquire(sid)
    resident.release(item)
    return item


def test_a_session_is_loaded_on_first_use_and_kept_while_there_is_room():
    shelf = Shelf("a", "b")
    resident = residency(shelf)
    assert resident.get("a") is None
    first = use(resident, "a")
    assert use(resident, "a") is first
    use(resident, "b")
    assert shelf.loads == ["a", "b"] and shelf.unloads == []
    with pytest.raises(KeyError):
        resident.acquire("nope")


def test_many_threads_asking_for_one_unloaded_session_load_it_once():
    shelf = Shelf("a")
    shelf.load_gate = threading.Event()
    resident = residency(shelf)
    with ThreadPoolExecutor(8) as pool:
        futures = [pool.submit(resident.acquire, "a") for _ in range(8)]
        while not shelf.loads:  # the first caller is loading; the others queue behind it
            time.sleep(0.005)
        shelf.load_gate.set()
        items = [f.result(timeout=10) for f in futures]
    assert shelf.loads == ["a"]
    assert all(item is items[0] for item in items) and items[0].users == 8


def test_room_is_made_by_unloading_the_least_recently_used_session():
    shelf = Shelf("a", "b", "c")
    resident = residency(shelf)
    use(resident, "a")
    use(resident, "b")
    use(resident, "a")  # b is now the least recently used
    use(resident, "c")
    assert shelf.unloads == [("b", "budget")]
    assert set(resident.snapshot()) == {"a", "c"}


def test_a_session_in_use_or_mapping_is_never_unloaded_and_then_there_is_no_room():
    shelf = Shelf("a", "b", "c")
    resident = residency(shelf)
    held = resident.acquire("a")  # a socket stays open on a
    mapping = use(resident, "b")
    mapping.mapping = True  # b has a keyframe in flight
    with pytest.raises(ResidentSessionsBusy, match="retry in 5 s") as busy:
        resident.acquire("c")
    assert busy.value.retry_after_s == 5 and "--max-resident-sessions" in str(busy.value)
    with pytest.raises(ResidentSessionsBusy):
        resident.admit("new", lambda: Item("new"))
    assert shelf.unloads == [] and set(resident.snapshot()) == {"a", "b"}

    mapping.mapping = False  # its keyframe is done: b may go, a (still in use) stays
    use(resident, "c")
    assert shelf.unloads == [("b", "budget")]
    resident.release(held)
    assert set(resident.snapshot()) == {"a", "c"}


def test_a_session_that_cannot_be_saved_stays_resident_and_the_load_waiting_for_room_fails():
    shelf = Shelf("a", "b", "c")
    resident = residency(shelf)
    use(resident, "a")
    use(resident, "b")
    shelf.refuse_unload = True
    with pytest.raises(OSError, match="refused"):
        resident.acquire("c")
    assert set(resident.snapshot()) == {"a", "b"}
    shelf.refuse_unload = False
    use(resident, "c")  # the failed attempt held no slot of the budget
    assert len(resident) == 2


def test_sessions_unused_for_the_idle_time_are_unloaded_and_others_stay():
    shelf = Shelf("a", "b", "c")
    resident = residency(shelf, budget=3)
    old, in_use = use(resident, "a"), resident.acquire("b")
    old.last_used -= 100  # unused for 100 s
    in_use.last_used -= 100  # as old, but a socket is open on it
    use(resident, "c")
    assert resident.unload_idle(idle_s=50) == ["a"]
    assert shelf.unloads == [("a", "idle")] and set(resident.snapshot()) == {"b", "c"}
    assert use(resident, "a") is not old  # loaded again on its next use
    assert shelf.loads == ["a", "b", "c", "a"]


def test_a_removed_session_leaves_memory_even_in_use_and_cannot_load_meanwhile():
    shelf = Shelf("a")
    resident = residency(shelf)
    held = resident.acquire("a")
    loaded_during_delete = []

    def delete(item: Item | None) -> bool:
        # Deleting: another caller asking for "a" now waits, then finds it gone.
        asker = threading.Thread(target=lambda: loaded_during_delete.append(_try(resident)))
        asker.start()
        time.sleep(0.05)  # room for a wrong load to happen; passing never depends on it
        assert not loaded_during_delete
        shelf.ids.discard("a")
        return item is held

    assert resident.remove("a", delete)
    assert resident.get("a") is None
    deadline = time.monotonic() + 10
    while not loaded_during_delete and time.monotonic() < deadline:
        time.sleep(0.005)
    assert loaded_during_delete == ["gone"]


def _try(resident: Residency[Item]) -> str:
    try:
        resident.acquire("a")
    except KeyError:
        return "gone"
    return "loaded"


def test_removal_is_skipped_when_its_condition_no_longer_holds():
    shelf = Shelf("a")
    resident = residency(shelf)
    held = resident.acquire("a")
    assert not resident.remove("a", lambda item: True, only_if=lambda item: not item.busy)
    assert resident.get("a") is held
