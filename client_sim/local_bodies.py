"""The relation bodies a local map keeps between questions: least recently used first,
within a byte bound, dropped for objects that change, go or are evicted (`LocalMap`
`relational_query`; counted in its `memory_bytes`)."""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Iterable

from app.relations.bodies import Body

BODY_OVERHEAD_BYTES = 2000
"""Bytes of a cached relation `Body` besides its points (float32 [3, N]): its box, centres,
footprint and the cache's entry. Checked against tracemalloc in the tests."""


def body_bytes(body: Body) -> int:
    """Bytes a cached relation body holds (its points exactly, the rest estimated)."""
    return body.local.nbytes + BODY_OVERHEAD_BYTES


class BodyCache:
    """id -> (key, Body), least recently used first; `key` says what the body was made from
    ((version, up axis)), so a changed object's body is never served."""

    def __init__(self, limit_bytes: int):
        self.limit_bytes = limit_bytes
        """The most bytes the cache holds, whatever room the map's budget leaves."""
        self._entries: OrderedDict[int, tuple[tuple, Body, int]] = OrderedDict()
        self.nbytes = 0
        """Bytes the cached bodies hold (`body_bytes` of each)."""

    def __len__(self) -> int:
        return len(self._entries)

    def __contains__(self, oid: object) -> bool:
        return oid in self._entries

    def ids(self) -> list[int]:
        return list(self._entries)

    def sizes(self) -> dict[int, int]:
        """id -> the bytes its cached body holds."""
        return {oid: entry[2] for oid, entry in self._entries.items()}

    def get(self, oid: int, key: tuple) -> Body | None:
        """The cached body of `oid` made from `key`, now the most recently used; else None."""
        cached = self._entries.get(oid)
        if cached is None or cached[0] != key:
            return None
        self._entries.move_to_end(oid)
        return cached[1]

    def keep(self, oid: int, key: tuple, body: Body, room_bytes: int) -> None:
        """Cache a body, least recently used ones out, within `limit_bytes` and `room_bytes`
        (what the map's budget leaves free); a body bigger than that is not kept."""
        self.forget([oid])
        nbytes = body_bytes(body)
        room = min(self.limit_bytes, room_bytes)
        if nbytes > room:
            return
        while self.nbytes + nbytes > room:
            _, (_, _, dropped) = self._entries.popitem(last=False)
            self.nbytes -= dropped
        self._entries[oid] = (key, body, nbytes)
        self.nbytes += nbytes

    def forget(self, ids: Iterable[int] | None = None) -> None:
        """Drop the bodies of these ids (every one when None)."""
        if ids is None:
            self._entries.clear()
            self.nbytes = 0
            return
        for oid in ids:
            entry = self._entries.pop(int(oid), None)
            if entry is not None:
                self.nbytes -= entry[2]
