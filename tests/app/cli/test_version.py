"""`semanticxr --version` names the package's version."""

import subprocess
import sys

from app import __version__


def test_version_prints_the_package_version():
    result = subprocess.run(
        [sys.executable, "-m", "app.cli", "--version"], capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0
    assert result.stdout.strip() == f"semanticxr {__version__}"
