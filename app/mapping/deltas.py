"""The delta log: "what changed since seq S", coalesced per object.

Every commit that changes the published (confirmed) map takes the next sequence number and
stamps the ids it touched. Because only an id's newest stamp is kept, a delta since S lists
each object once, at its newest version. Removals are kept as tombstones until trimmed;
a subscriber whose `since` is older than the oldest kept tombstone gets a full snapshot.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass


@dataclass
class Delta:
    """Ids to send to a subscriber whose last applied seq is `since`."""

    seq: int
    full: bool
    upserts: list[int]
    removed: list[int]


class DeltaLog:
    def __init__(self, seq: int = 0, max_tombstones: int = 100_000):
        self.seq = seq
        self._upserted_at: dict[int, int] = {}
        self._removed_at: dict[int, int] = {}
        self._floor = seq  # history after `_floor` is complete
        self._max_tombstones = max_tombstones

    @property
    def floor(self) -> int:
        """Oldest seq a subscriber may resume from without a full snapshot."""
        return self._floor

    def commit(self, upserted: Iterable[int] = (), removed: Iterable[int] = ()) -> int:
        """Record one atomic change; returns the seq (unchanged when nothing changed).

        An id both upserted and removed in one commit ends up removed.
        """
        upserted, removed = set(upserted), set(removed)
        if not upserted and not removed:
            return self.seq
        self.seq += 1
        for oid in upserted - removed:
            self._upserted_at[oid] = self.seq
            self._removed_at.pop(oid, None)
        for oid in removed:
            self._upserted_at.pop(oid, None)
            self._removed_at[oid] = self.seq
        if len(self._removed_at) > self._max_tombstones:
            self._trim_tombstones()
        return self.seq

    def _trim_tombstones(self) -> None:
        """Keep about half of max_tombstones, the newest: raise the floor past the others
        (every tombstone at or below the floor goes, as none can reach a subscriber)."""
        by_age = sorted(self._removed_at.values())
        self._floor = max(self._floor, by_age[len(by_age) - self._max_tombstones // 2 - 1])
        self._removed_at = {oid: s for oid, s in self._removed_at.items() if s > self._floor}

    def live_ids(self) -> list[int]:
        return sorted(self._upserted_at)

    def since(self, since: int | None) -> Delta:
        """Everything after `since`; a full snapshot when since is None, in the future, or
        older than the kept history."""
        if since is None or since < self._floor or since > self.seq:
            return Delta(self.seq, True, self.live_ids(), [])
        upserts = sorted(oid for oid, s in self._upserted_at.items() if s > since)
        removed = sorted(oid for oid, s in self._removed_at.items() if s > since)
        return Delta(self.seq, False, upserts, removed)

    def state(self) -> dict:
        """Serialisable state (for persistence)."""
        return {
            "seq": self.seq,
            "floor": self._floor,
            "upserted_at": dict(self._upserted_at),
            "removed_at": dict(self._removed_at),
        }

    @classmethod
    def from_state(cls, state: dict, max_tombstones: int = 100_000) -> DeltaLog:
        """The log of `state()`, trimmed at once if it holds more than max_tombstones."""
        log = cls(seq=int(state["seq"]), max_tombstones=max_tombstones)
        log._floor = int(state["floor"])
        log._upserted_at = {int(k): int(v) for k, v in state["upserted_at"].items()}
        log._removed_at = {int(k): int(v) for k, v in state["removed_at"].items()}
        if len(log._removed_at) > max_tombstones:
            log._trim_tombstones()
        return log
