"""Run the server: the one uvicorn configuration (`semanticxr serve`), its certificate with
--https (`tls_ready`), uvicorn in a background thread of another program (`ServerThread`: the
demo, scripts, tests), and `semanticxr serve` in a child process as an operator runs it
(`ServerProcess`: benches, crash tests)."""

from __future__ import annotations

import dataclasses
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import httpx
import uvicorn

from app.semantics import TextEncoder
from app.server.app import create_app
from app.server.edges import WILDCARD_BINDS, logging_config
from app.server.settings import ServerSettings
from app.server.tls import (
    TLS_DIR,
    Certificate,
    TlsError,
    given_certificate,
    self_signed_certificate,
    this_machine_names,
    url_host,
)


def free_port(host: str = "127.0.0.1") -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def tls_ready(settings: ServerSettings) -> tuple[ServerSettings, Certificate | None]:
    """The settings to serve with, and the certificate (None without --https).

    With --https: tls_cert and tls_key name the certificate and key (--tls-cert/--tls-key,
    checked; else this machine's self-signed one in DATA_DIR/tls, made or reused), and
    allowed_hosts are the certificate's names unless --allowed-hosts is given. TlsError names
    the flag whose file cannot serve. Call it before making the app (it reads the hosts)."""
    if not settings.https:
        return settings, None
    if settings.tls_cert is not None and settings.tls_key is not None:
        certificate = given_certificate(Path(settings.tls_cert), Path(settings.tls_key))
    else:
        directory = Path(settings.data_dir) / TLS_DIR
        try:
            certificate = self_signed_certificate(directory, this_machine_names())
        except OSError as exc:
            raise TlsError(
                f"--data-dir: cannot keep the certificate in {directory}: {exc.strerror}"
            ) from None
    allowed = settings.allowed_hosts
    served = dataclasses.replace(
        settings,
        tls_cert=str(certificate.cert_path),
        tls_key=str(certificate.key_path),
        allowed_hosts=",".join(certificate.names) if allowed is None else allowed,
    )
    return served, certificate


def uvicorn_config(app, settings: ServerSettings, log_level: str | None = None) -> uvicorn.Config:
    """The one uvicorn configuration of the service (`semanticxr serve` and in-process);
    HTTPS when settings come from `tls_ready` with --https."""
    if settings.https and settings.tls_cert is None:
        raise ValueError("https settings without a certificate: pass them through tls_ready")
    return uvicorn.Config(
        app,
        host=settings.host,
        port=settings.port,
        log_level=log_level or settings.log_level,
        log_config=logging_config(),  # tokens in URLs never reach the access log
        ws_max_size=settings.max_message_bytes,
        ws_per_message_deflate=False,  # payloads are JPEG/zstd already
        limit_concurrency=settings.max_connections,  # beyond: 503 (HTTP) or refused (socket)
        ssl_certfile=settings.tls_cert,
        ssl_keyfile=settings.tls_key,
    )


class ServerThread:
    """A real uvicorn serving the app in a daemon thread; `url` once `start()` returns.

    Port 0 picks a free port. With --https settings it serves TLS (`certificate`: the one it
    serves, for clients' CA). A stopped ServerThread does not start again: make a new one
    (on the same port and data dir to "restart" the server)."""

    def __init__(
        self,
        settings: ServerSettings,
        encoder: TextEncoder | None = None,
        app_factory: Callable[[ServerSettings], Any] | None = None,
    ):
        """app_factory: makes another ASGI app to serve with the service's configuration (a
        cluster's gateway) instead of the server."""
        if settings.port == 0:
            settings.port = free_port(settings.host)
        settings, self.certificate = tls_ready(settings)
        self.settings = settings
        self.app = app_factory(settings) if app_factory else create_app(settings, encoder=encoder)
        self.server = uvicorn.Server(uvicorn_config(self.app, settings, log_level="warning"))
        self.thread = threading.Thread(
            target=self.server.run, name="semanticxr-server", daemon=True
        )
        # a wildcard bind is reached on loopback from this machine
        host = url_host("127.0.0.1" if settings.host in WILDCARD_BINDS else settings.host)
        secure = "s" if settings.https else ""
        self.url = f"http{secure}://{host}:{settings.port}"
        self.ws_url = f"ws{secure}://{host}:{settings.port}"

    def start(self, timeout_s: float = 60.0) -> ServerThread:
        self.thread.start()
        deadline = time.monotonic() + timeout_s
        while not self.server.started:
            if not self.thread.is_alive():
                raise RuntimeError(f"the server on port {self.settings.port} exited at start")
            if time.monotonic() > deadline:
                raise RuntimeError(f"the server did not start within {timeout_s:.0f} s")
            time.sleep(0.01)
        return self

    def stop(self, timeout_s: float = 30.0) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=timeout_s)


class ServerProcess:
    """`semanticxr serve` in a child process (`python -m app.cli serve`), as an operator runs
    it, on loopback: `url` and `ws_url` once `start()` returns (/healthz answered).

    port 0 picks a free port. extra_args: more `serve` flags. quiet: the child's stderr goes
    to a temporary file (`output()`; its tail is in the error if it dies at start) instead of
    ours. prefix: a command the server runs under, e.g. `["prlimit", "--fsize=N:unlimited",
    "--"]` (it must exec the server, so `pid` is the server's).
    """

    def __init__(
        self,
        data_dir: str | Path,
        port: int = 0,
        *,
        extra_args: Sequence[str] = (),
        log_level: str = "warning",
        quiet: bool = True,
        prefix: Sequence[str] = (),
    ):
        self.port = port or free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.ws_url = f"ws://127.0.0.1:{self.port}"
        self.argv = [
            *prefix,
            sys.executable,
            "-m",
            "app.cli",
            "serve",
            "--host",
            "127.0.0.1",
            "--port",
            str(self.port),
            "--data-dir",
            str(data_dir),
            "--log-level",
            log_level,
            *extra_args,
        ]
        self.quiet = quiet
        self.proc: subprocess.Popen | None = None
        self._stderr = None

    def start(self, timeout_s: float = 120.0) -> ServerProcess:
        """Start the child and wait until /healthz answers 200 (RuntimeError if it exits or
        does not answer within `timeout_s`)."""
        # Closed by stop(): it lives as long as the child.
        self._stderr = tempfile.TemporaryFile() if self.quiet else None  # noqa: SIM115
        self.proc = subprocess.Popen(
            self.argv,
            env=dict(os.environ, HF_HUB_OFFLINE="1"),
            stdout=subprocess.DEVNULL if self.quiet else None,
            stderr=self._stderr,
        )
        deadline = time.monotonic() + timeout_s
        while True:
            if self.proc.poll() is not None:
                raise RuntimeError(f"the server exited at start: {self._stderr_tail()}")
            try:
                if httpx.get(f"{self.url}/healthz", timeout=1).status_code == 200:
                    return self
            except httpx.TransportError:
                pass
            if time.monotonic() > deadline:
                self.proc.kill()
                self.proc.wait(timeout=30)
                raise RuntimeError(f"the server did not answer within {timeout_s:.0f} s")
            time.sleep(0.1)  # a polling period: the child offers nothing to wait on

    @property
    def pid(self) -> int:
        assert self.proc is not None, "not started"
        return self.proc.pid

    def output(self) -> str:
        """What the server wrote to stderr so far (its log), with quiet=True; "" otherwise."""
        if self._stderr is None:
            return ""
        # pread: the child shares the file offset, which a seek here would move under it.
        fd = self._stderr.fileno()
        return os.pread(fd, os.fstat(fd).st_size, 0).decode(errors="replace")

    def kill9(self) -> None:
        """SIGKILL: a crash, no shutdown code runs."""
        assert self.proc is not None, "not started"
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(timeout=30)
        self.stop()  # releases what is left (the stderr file)

    def stop(self, timeout_s: float = 30.0) -> None:
        """Ctrl-C (a clean shutdown); SIGKILL if it takes longer than `timeout_s`."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=30)
        if self._stderr is not None:
            self._stderr.close()
            self._stderr = None

    def _stderr_tail(self, n_chars: int = 2000) -> str:
        if self._stderr is None:
            return "(see its stderr above)"
        return self.output()[-n_chars:]

    def __enter__(self) -> ServerProcess:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.stop()
