"""The relations package as the device imports it: numpy and scipy only, its thresholds one
frozen record."""

from __future__ import annotations

import dataclasses
import json
import pkgutil
import subprocess
import sys

import pytest

import app.relations
from app.relations.thresholds import THRESHOLDS, Thresholds

MODULES = sorted(f"app.relations.{m.name}" for m in pkgutil.iter_modules(app.relations.__path__))


def test_the_relations_package_needs_nothing_of_app_and_no_model_library():
    imports = "; ".join(f"import {m}" for m in MODULES)
    report = "import json, sys; print(json.dumps(sorted(sys.modules)))"
    done = subprocess.run(
        [sys.executable, "-c", f"{imports}; {report}"],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    loaded = json.loads(done.stdout)
    outside = [m for m in loaded if m.startswith("app.") and not m.startswith("app.relations")]
    assert outside == []
    assert not {"torch", "transformers", "sentence_transformers", "open3d"} & set(loaded)


def test_the_thresholds_are_one_frozen_record():
    assert isinstance(THRESHOLDS, Thresholds) and Thresholds() == THRESHOLDS
    assert len(dataclasses.fields(Thresholds)) == 45
    with pytest.raises(dataclasses.FrozenInstanceError):
        THRESHOLDS.near_max_m = 1.0  # type: ignore[misc]
