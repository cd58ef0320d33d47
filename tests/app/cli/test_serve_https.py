"""`semanticxr serve --https` at start: the real-device page's URL and a QR code of it (read
back with a QR decoder), the hint about the phone's certificate warning, no secret printed;
then the real command in a child process on loopback."""

from __future__ import annotations

import os
import signal
import ssl
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
import zxingcpp
from PIL import Image

from app.cli.serve import https_banner, qr_text
from app.server.runner import free_port
from app.server.settings import ServerSettings
from app.server.tls import Certificate

NAMES = ("localhost", "127.0.0.1", "::1", "studio", "192.168.1.23", "fd00::23")
HALF_BLOCKS = {" ": (1, 1), "\u2580": (0, 1), "\u2584": (1, 0), "\u2588": (0, 0)}
"""segno's compact terminal code: (top, bottom) module of each character, 1 dark; the light
modules are the ones drawn."""


def read_qr(text: str) -> list[str]:
    """What the half-block QR codes in `text` (a terminal's output, other lines around them)
    say, read by zxing-cpp from a picture of them."""
    rows: list[list[int]] = []
    for line in text.splitlines():
        if line and set(line) <= set(HALF_BLOCKS):
            pairs = [HALF_BLOCKS[c] for c in line]
            rows += [[top for top, _ in pairs], [bottom for _, bottom in pairs]]
    assert rows, f"no QR code in:\n{text}"
    dark = np.array(rows, dtype=bool)
    picture = np.where(dark, 0, 255).astype(np.uint8).repeat(8, axis=0).repeat(8, axis=1)
    return [barcode.text for barcode in zxingcpp.read_barcodes(Image.fromarray(picture))]


def certificate(tmp_path: Path, made: bool = True) -> Certificate:
    return Certificate(
        tmp_path / "cert.pem", tmp_path / "key.pem", NAMES, made=made, self_signed=True
    )


def test_the_banner_shows_the_phone_page_url_and_a_qr_code_of_it(tmp_path):
    settings = ServerSettings(https=True, port=8443, data_dir=str(tmp_path))
    banner = https_banner(settings, certificate(tmp_path))
    assert "Open this on a phone on the same network: https://192.168.1.23:8443/xr" in banner
    assert read_qr(banner) == ["https://192.168.1.23:8443/xr"]
    assert "also: https://studio:8443/xr, https://[fd00::23]:8443/xr" in banner
    assert "listening on every interface, IPv4 and IPv6" in banner
    hint = [line for line in banner.splitlines() if "not private" in line]
    assert len(hint) == 1 and "made now" in hint[0] and "proceed once" in hint[0]
    assert f"--tls-ca {tmp_path / 'cert.pem'}" in banner
    assert "key.pem" not in banner


def test_bound_to_loopback_the_banner_says_a_phone_cannot_reach_it(tmp_path):
    settings = ServerSettings(https=True, host="127.0.0.1", port=8443, data_dir=str(tmp_path))
    banner = https_banner(settings, certificate(tmp_path, made=False))
    assert read_qr(banner) == ["https://127.0.0.1:8443/xr"]
    assert "leave out --host" in banner and "also:" not in banner
    assert "reused" in banner


def test_in_a_terminal_the_code_is_white_on_black_whatever_its_theme():
    plain, coloured = qr_text("https://192.168.1.23:8443/xr"), qr_text("x", color=True)
    assert "\x1b" not in plain
    assert all(line.startswith("\x1b[97;40m") for line in coloured.splitlines())


# --- the real command -----------------------------------------------------------------------


class Output:
    """A child's stdout, line by line, read in a thread; `wait_for` a line with a deadline."""

    def __init__(self, stream):
        self.lines: list[str] = []
        self._changed = threading.Condition()
        threading.Thread(target=self._read, args=(stream,), daemon=True).start()

    def _read(self, stream) -> None:
        for line in stream:
            with self._changed:
                self.lines.append(line.rstrip("\n"))
                self._changed.notify_all()

    def wait_for(self, piece: str, timeout_s: float) -> None:
        with self._changed:
            found = self._changed.wait_for(
                lambda: any(piece in line for line in self.lines), timeout_s
            )
        assert found, f"no {piece!r} within {timeout_s} s in:\n{self.text}"

    @property
    def text(self) -> str:
        return "\n".join(self.lines)


def healthz_over_tls(url: str, cafile: Path, timeout_s: float) -> httpx.Response:
    """/healthz as soon as it answers (the child loads its text encoder first)."""
    trust = ssl.create_default_context(cafile=str(cafile))
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return httpx.get(f"{url}/healthz", verify=trust, timeout=2)
        except httpx.TransportError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)  # a polling period: the child offers nothing to wait on


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_serve_https_prints_the_url_and_its_qr_code_and_serves_tls(tmp_path):
    port = free_port()
    argv = [sys.executable, "-m", "app.cli", "serve", "--https", "--host", "127.0.0.1"]
    argv += ["--port", str(port), "--data-dir", str(tmp_path), "--api-key", "sesame"]
    child = subprocess.Popen(
        [*argv, "--log-level", "warning"],
        env=dict(os.environ, HF_HUB_OFFLINE="1"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        out = Output(child.stdout)
        out.wait_for("Python clients: --tls-ca", timeout_s=120)
        url = f"https://127.0.0.1:{port}"
        assert f"Open this on a phone on the same network: {url}/xr" in out.text
        assert read_qr(out.text) == [f"{url}/xr"]
        cert = tmp_path / "tls" / "cert.pem"
        assert f"--tls-ca {cert}" in out.text
        assert healthz_over_tls(url, cert, timeout_s=120).json()["status"] == "ok"
    finally:
        child.send_signal(signal.SIGINT)
        _, err = child.communicate(timeout=60)
    assert child.returncode == 130, err  # stopped by Ctrl-C, as plain `serve` is
    for secret in ("sesame", "PRIVATE KEY", (tmp_path / "tls" / "key.pem").read_text()):
        assert secret not in out.text and secret not in err
    assert "no API key" not in err  # a key was given
