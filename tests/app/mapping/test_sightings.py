"""Sightings: when the frames seen of a candidate confirm it (`Sightings.qualifies`)."""

from app.mapping.object import MapObject
from app.mapping.sightings import Sightings


def sightings_of(oid: int, seen: list[int], missed: list[int] = ()) -> Sightings:
    sightings = Sightings()
    for seq in seen:
        sightings.observed(oid, seq)
    sightings.glimpses[oid].missed |= set(missed)
    return sightings


def test_a_candidate_seen_on_enough_frames_spread_apart_qualifies():
    assert sightings_of(7, [10, 11, 12]).qualifies(7, min_observations=2)


def test_a_candidate_seen_only_on_neighbouring_frames_does_not_qualify():
    assert not sightings_of(7, [10, 11]).qualifies(7, min_observations=2)


def test_a_candidate_most_frames_in_view_missed_does_not_qualify():
    assert not sightings_of(7, [10, 14], missed=[11, 12, 13]).qualifies(7, min_observations=2)


def test_a_merged_candidate_keeps_what_was_seen_of_both():
    sightings = sightings_of(1, [10])
    sightings.observed(2, 13)
    sightings.merge(MapObject(id=1), MapObject(id=2))
    assert sightings.glimpses[1].seen == {10, 13} and 2 not in sightings.glimpses
    assert sightings.qualifies(1, min_observations=2)
