"""Outlier removal keeps a thing's smaller part that many views saw and drops a cluster only a
view or two left, however dense."""

from __future__ import annotations

import numpy as np
import pytest
from clouds import disc

from app.mapping import geometry as geo
from app.mapping.engine import OUTLIER_EPS_M, _denoise
from app.mapping.object import MapObject

RNG = np.random.default_rng(7)


def _lamp_with_stray():
    """A shade of 400 points seen by 20 views; a base apart from it (no pole between: 60
    points, 15 % of the shade's) that views keep showing, most of its points in one or two
    of them and some in up to 5 (as on a walk, where each clean-up that drops it restarts
    its count); and a stray clump of 60 points beside the base that 1 or 2 views left."""
    shade = disc(RNG, (0.0, 0.0, 1.2), 0.2, 400)
    base = disc(RNG, (0.0, 0.0, 0.0), 0.08, 60)
    stray = disc(RNG, (0.5, 0.0, 0.3), 0.08, 60)
    points = np.concatenate([shade, base, stray]).astype(np.float32)
    support = np.concatenate(
        [np.full(400, 20.0), RNG.choice([1.0, 1.0, 2.0, 3.0, 5.0], 60), RNG.choice([1.0, 2.0], 60)]
    ).astype(np.float32)
    part = np.repeat(np.array(["shade", "base", "stray"]), [400, 60, 60])
    return points, support, part


def test_a_base_many_views_saw_is_kept_and_a_stray_one_or_two_left_is_dropped():
    points, support, part = _lamp_with_stray()
    keep = geo.outlier_free(points, OUTLIER_EPS_M, support=support)
    assert keep[part == "shade"].all()
    assert keep[part == "base"].all()
    assert not keep[part == "stray"].any()


def test_without_support_a_part_under_a_quarter_of_the_largest_is_dropped():
    """The share rule alone (support unknown: a stored or imported object) cannot tell the
    base from the stray: both go."""
    points, _, part = _lamp_with_stray()
    keep = geo.outlier_free(points, OUTLIER_EPS_M)
    assert keep[part == "shade"].all()
    assert not keep[part == "base"].any() and not keep[part == "stray"].any()


def test_clean_up_keeps_the_base_and_its_support(encoder):
    points, support, part = _lamp_with_stray()
    obj = MapObject(id=1, first_seen=1, first_seen_t=0.0, last_seen_t=1.0, confirmed=True)
    obj.set_points(points, 0.025, support)
    obj.observe_label("lamp", encoder.encode(["lamp"])[0])
    assert _denoise(obj)
    kept = np.isin(points.view("V12"), obj.points.view("V12")).ravel()
    assert kept[part == "base"].all() and not kept[part == "stray"].any()
    assert obj.support is not None and len(obj.support) == len(obj.points)
    np.testing.assert_array_equal(np.sort(obj.support), np.sort(support[kept]))


def test_support_of_another_length_is_refused():
    points, support, _ = _lamp_with_stray()
    with pytest.raises(ValueError, match="support"):
        geo.outlier_free(points, OUTLIER_EPS_M, support=support[:-1])
