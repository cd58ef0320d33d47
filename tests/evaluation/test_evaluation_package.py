"""The evaluation package's shape: one module per scenario, each a config and a `run` that
gives a `Report`; importing the package loads none of them."""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import subprocess
import sys

import pytest

from evaluation.report import Report

SCENARIOS = {
    "walk": "EvalConfig",
    "relations": "RelationsConfig",
    "revisit": "RevisitConfig",
}


def test_importing_the_package_loads_no_scenario_and_nothing_of_app():
    done = subprocess.run(
        [
            sys.executable,
            "-c",
            "import sys, evaluation\n"
            "loaded = sorted(m for m in sys.modules if m.startswith(('evaluation.', 'app', "
            "'world', 'client_sim')))\n"
            "assert not loaded, loaded\n",
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr


@pytest.mark.parametrize("scenario", sorted(SCENARIOS))
def test_each_scenario_is_a_config_and_a_run_giving_a_report(scenario):
    module = importlib.import_module(f"evaluation.{scenario}")
    config = getattr(module, SCENARIOS[scenario])
    assert dataclasses.is_dataclass(config)
    signature = inspect.signature(module.run)
    assert list(signature.parameters)[:2] == ["cfg", "encoder"]
    assert signature.return_annotation in (Report, "Report")


def test_a_report_formats_its_table_from_its_document_when_asked():
    asked = []

    def table(document: dict) -> str:
        asked.append(document)
        return f"{document['n']} things"

    report = Report("walk", {"n": 3}, table)
    assert asked == []
    assert report.table() == "3 things"
    assert asked == [{"n": 3}]
