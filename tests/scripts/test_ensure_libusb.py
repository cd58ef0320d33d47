"""scripts/ensure_libusb.sh: the set-up's libusb detection, run against stand-in programs.

The stand-in interpreter fails `import open3d` with open3d's real libusb message until the
stand-in apt-get has run, so a passing run proves the install branch was taken.
"""

import os
import stat
import subprocess
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "ensure_libusb.sh"
LIBUSB_ERROR = (
    "ImportError: libusb-1.0.so.0: cannot open shared object file: No such file or directory"
)


def _executable(path: Path, body: str) -> Path:
    path.write_text("#!/usr/bin/env bash\n" + body)
    path.chmod(path.stat().st_mode | stat.S_IEXEC)
    return path


def _stand_ins(tmp_path: Path, error: str) -> tuple[Path, Path, Path]:
    installed = tmp_path / "installed"
    calls = tmp_path / "apt-calls"
    python = _executable(
        tmp_path / "python",
        f'[ -f "{installed}" ] && exit 0\necho "{error}" >&2\nexit 1\n',
    )
    apt_get = _executable(tmp_path / "apt-get", f'echo "$@" >> "{calls}"\ntouch "{installed}"\n')
    return python, apt_get, calls


def _run(python: Path, apt_get: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, APT_GET=str(apt_get))
    return subprocess.run(
        ["bash", str(SCRIPT), str(python)], env=env, capture_output=True, text=True, timeout=30
    )


@pytest.mark.skipif(os.geteuid() != 0, reason="the install branch runs as root only")
def test_a_missing_libusb_is_installed_with_apt_get(tmp_path):
    python, apt_get, calls = _stand_ins(tmp_path, LIBUSB_ERROR)
    result = _run(python, apt_get)
    assert result.returncode == 0, result.stderr
    assert "libusb-1.0-0" in calls.read_text()
    assert "installing Debian's libusb-1.0-0" in result.stdout


def test_an_importable_open3d_installs_nothing(tmp_path):
    python, apt_get, calls = _stand_ins(tmp_path, LIBUSB_ERROR)
    (tmp_path / "installed").touch()
    result = _run(python, apt_get)
    assert result.returncode == 0, result.stderr
    assert not calls.exists()


def test_another_import_error_is_shown_and_installs_nothing(tmp_path):
    python, apt_get, calls = _stand_ins(tmp_path, "ImportError: libGL.so.1: cannot open")
    result = _run(python, apt_get)
    assert result.returncode == 1
    assert "libGL.so.1" in result.stderr
    assert not calls.exists()
