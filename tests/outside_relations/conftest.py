"""A real server for the outside client: `semanticxr serve` as a subprocess on 127.0.0.1,
on a free port, with a throwaway data dir (README "Using it piece by piece")."""

import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

START_TIMEOUT_S = 45.0


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _semanticxr() -> list[str]:
    exe = Path(sys.executable).with_name("semanticxr")
    return [str(exe)] if exe.exists() else [shutil.which("semanticxr") or "semanticxr"]


@pytest.fixture(scope="module")
def outside_server(tmp_path_factory):
    """Base URL of a running server; stopped (its own process only) at teardown."""
    data = tmp_path_factory.mktemp("outside-data")
    port = _free_port()
    env = dict(os.environ, HF_HUB_OFFLINE="1")
    cmd = [*_semanticxr(), "serve", "--host", "127.0.0.1", "--port", str(port)]
    cmd += ["--data-dir", str(data)]
    url = f"http://127.0.0.1:{port}"
    with open(data / "server.log", "wb") as log:
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env)
        try:
            _wait_healthy(proc, url, data / "server.log")
            yield url
        finally:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=5)


def _wait_healthy(proc, url, log_path):
    deadline = time.monotonic() + START_TIMEOUT_S
    while True:
        if proc.poll() is not None:
            tail = log_path.read_text()[-2000:]
            raise RuntimeError(f"server exited with {proc.returncode}: {tail}")
        try:
            if httpx.get(f"{url}/healthz", timeout=1.0).status_code == 200:
                return
        except httpx.HTTPError:
            pass
        if time.monotonic() > deadline:
            raise RuntimeError(f"server not healthy within {START_TIMEOUT_S} s")
        time.sleep(0.2)
