"""The revisit source: walk 1 over the scene, then the same path again over the changed scene,
on one device clock (0.2 s per frame, the second walk `gap_s` after the first)."""

from __future__ import annotations

import numpy as np
import pytest

from client_sim.sources import SOURCE_KINDS, FrameSource, make_source
from client_sim.sources.revisit import RevisitSource
from client_sim.sources.synthetic import SyntheticFrame
from world import RevisitScenario, default_camera, make_revisit

WALK = 150
SMALL_CAMERA = default_camera(160, 120)


@pytest.fixture(scope="module")
def scenario() -> RevisitScenario:
    return make_revisit("kitchen", 0, walk_frames=WALK, gap_s=600.0)


@pytest.fixture(scope="module")
def source(scenario: RevisitScenario) -> RevisitSource:
    return RevisitSource(scenario, camera=SMALL_CAMERA)


def test_two_walks_of_the_same_path_make_one_stream(source: RevisitSource):
    assert isinstance(source, FrameSource)
    assert len(source) == 2 * WALK
    assert [source.walk_of(i) for i in (0, WALK - 1, WALK, 2 * WALK - 1)] == [1, 1, 2, 2]
    for i in (0, 17, WALK - 1):
        np.testing.assert_array_equal(source.frame(i).pose, source.frame(WALK + i).pose)
    with pytest.raises(IndexError):
        source.frame(2 * WALK)


def test_t_advances_a_fifth_of_a_second_per_frame_and_walk_two_starts_gap_s_later(
    source: RevisitSource,
):
    t = [source.scenario.t_of(i) for i in range(len(source))]
    steps = np.diff(t)
    np.testing.assert_allclose(steps[: WALK - 1], 0.2)
    np.testing.assert_allclose(steps[WALK:], 0.2)
    assert t[WALK] - t[WALK - 1] == pytest.approx(600.0)
    for i in (0, WALK - 1, WALK, WALK + 5):
        assert source.frame(i).t == pytest.approx(t[i])
    assert all(c.t_world == pytest.approx(t[WALK]) for c in source.scenario.changes)


def test_walk_two_frames_show_the_changed_scene_with_its_instance_ids(source: RevisitSource):
    scenario = source.scenario
    removed = {c.instance_id for c in scenario.changes if c.kind == "removed"}
    added = {c.instance_id for c in scenario.changes if c.kind == "added"}
    seen_first, seen_second = set(), set()
    for i in range(0, WALK, 5):
        first, second = source.frame(i), source.frame(WALK + i)
        assert isinstance(second, SyntheticFrame) and second.instances is not None
        seen_first |= set(np.unique(first.view.instance_ids).tolist())
        seen_second |= set(np.unique(second.view.instance_ids).tolist())
        # Detections of walk 2 come from the changed scene's objects.
        assert set(second.detections.sources.values()) - {0} <= {
            o.instance_id for o in scenario.after.objects
        }
    assert removed & seen_first and not removed & seen_second
    assert added & seen_second and not added & seen_first


def test_make_source_builds_a_revisit_from_its_spec():
    assert "revisit" in SOURCE_KINDS
    source = make_source("revisit:living_room", walk_frames=20, camera=SMALL_CAMERA, noise="none")
    assert isinstance(source, RevisitSource) and source.name == "revisit:living_room"
    assert len(source) == 40
    assert source.frame(20).t == pytest.approx(19 * 0.2 + 600.0)


def test_an_unknown_noise_profile_is_refused(scenario: RevisitScenario):
    with pytest.raises(ValueError, match="noise profile"):
        RevisitSource(scenario, noise="fuzzy")
