"""A command whose port is taken says so in one line and exits 2, with no traceback: the
server (`serve`), the demo (its server and its viewer) and the viewer."""

from __future__ import annotations

import socket
import subprocess
import sys

import pytest

pytestmark = pytest.mark.timeout(120)


@pytest.fixture
def busy_port():
    """A port some other program listens on, for the duration of the test."""
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        yield holder.getsockname()[1]


def semanticxr(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "app.cli", *argv], capture_output=True, text=True, timeout=90
    )


def assert_one_clear_line(result: subprocess.CompletedProcess, command: str, port: int, flag):
    assert result.returncode == 2, (result.stdout, result.stderr)
    assert "Traceback" not in result.stdout + result.stderr
    assert result.stderr.strip().splitlines() == [
        f"semanticxr {command}: port {port} is in use; pass {flag} with a free port"
    ]


def test_serve_on_a_busy_port_says_so_in_one_line(busy_port, tmp_path):
    result = semanticxr(
        "serve", "--host", "127.0.0.1", "--port", str(busy_port), "--data-dir", str(tmp_path)
    )
    assert_one_clear_line(result, "serve", busy_port, "--port")


def test_demo_on_a_busy_port_says_so_in_one_line(busy_port, tmp_path):
    result = semanticxr("demo", "--port", str(busy_port), "--no-viewer", "--exit")
    assert_one_clear_line(result, "demo", busy_port, "--port")


def test_demo_with_a_busy_viewer_port_says_so_in_one_line(busy_port):
    result = semanticxr("demo", "--port", "0", "--viewer-port", str(busy_port), "--exit")
    assert_one_clear_line(result, "demo", busy_port, "--viewer-port (or --no-viewer)")


def test_viewer_on_a_busy_port_says_so_in_one_line(busy_port):
    result = semanticxr(
        "viewer", "--server", "http://127.0.0.1:9", "--session", "s", "--port", str(busy_port)
    )
    assert_one_clear_line(result, "viewer", busy_port, "--port")


def test_a_free_port_is_not_reported_busy():
    from app.cli.ports import port_in_use

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    assert not port_in_use("127.0.0.1", port)
    assert not port_in_use("127.0.0.1", 0)
