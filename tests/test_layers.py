"""The layers hold: the import-linter contracts in pyproject.toml pass on this tree (the
CLI and the benches on top, the device and the viewer apart, app below both, no cycles)."""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def contracts() -> list[dict]:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    return config["tool"]["importlinter"]["contracts"]


def test_the_import_contracts_pass():
    if importlib.util.find_spec("importlinter") is None:
        pytest.skip("import-linter is not installed (pip install -e '.[dev]')")
    script = Path(sys.executable).with_name("lint-imports")
    command = str(script) if script.exists() else shutil.which("lint-imports")
    if command is None:
        pytest.skip("import-linter is installed but its lint-imports script is not found")
    done = subprocess.run(
        [command, "--no-cache"], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-2000:]
    assert "0 broken" in done.stdout


def test_every_app_module_below_the_cli_sits_below_the_device_and_the_viewer():
    """The top-level contract names app's modules one by one (import-linter cannot say "app
    but not app.cli"); the exhaustive app contract makes sure none is forgotten there, and
    this makes sure the two lists agree."""
    by_container = {tuple(c.get("containers", ())): c for c in contracts() if c["type"] == "layers"}
    app_layers = by_container[("app",)]["layers"]
    top_layers = by_container[()]["layers"]
    app_modules = {
        name.strip().strip("()")
        for layer in app_layers
        for name in layer.replace("|", ":").split(":")
    } - {"cli"}
    below_both = {
        name.strip().strip("()").removeprefix("app.") for name in top_layers[-1].split(":")
    }
    assert below_both == app_modules
