"""The two system organisations, each one small class chosen once per map."""

import numpy as np
import pytest

from app.config import MODES, Knobs
from app.mapping.organisation import (
    BASELINE_RESOLUTION_M,
    BaselineOrganisation,
    SemanticXROrganisation,
    organisation_for,
)


def test_each_mode_has_its_organisation():
    for mode in MODES:
        assert organisation_for(mode).mode == mode


def test_an_unknown_mode_is_refused_naming_the_modes():
    with pytest.raises(ValueError, match="semanticxr, baseline"):
        organisation_for("fast")


def test_semanticxr_spreads_denoising_over_the_interval_each_object_once():
    changed, interval = set(range(1, 13)), 4
    due = [SemanticXROrganisation().denoise_due(changed, k, interval) for k in range(1, 5)]
    assert sorted(oid for ids in due for oid in ids) == sorted(changed)
    assert all(len(ids) == 3 for ids in due)


def test_the_baseline_denoises_every_changed_object_on_the_interval_only():
    changed = {5, 1, 3}
    baseline = BaselineOrganisation()
    assert baseline.denoise_due(changed, 4, 4) == [1, 3, 5]
    assert baseline.denoise_due(changed, 5, 4) == []


def test_semanticxr_caps_geometry_and_the_baseline_keeps_sensor_resolution():
    knobs = Knobs(max_object_points_server=100, max_object_spacing_m=None)
    points = np.random.default_rng(0).uniform(0, 0.5, (5000, 3)).astype(np.float32)
    points[:, 2] = 0.0  # a surface
    capped, _ = SemanticXROrganisation().cap(points, knobs)
    kept, spacing_m = BaselineOrganisation().cap(points, knobs)
    assert len(capped) <= 100
    assert len(kept) > 100 and spacing_m == BASELINE_RESOLUTION_M
