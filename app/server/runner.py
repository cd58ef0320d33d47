"""Run the server inside another program: uvicorn in a background thread (demo, tests)."""

from __future__ import annotations

import socket
import threading
import time

import uvicorn

from app.semantics import TextEncoder
from app.server.app import create_app
from app.server.edges import logging_config
from app.server.settings import ServerSettings


def free_port(host: str = "127.0.0.1") -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def uvicorn_config(app, settings: ServerSettings, log_level: str | None = None) -> uvicorn.Config:
    """The one uvicorn configuration of the service (`semanticxr serve` and in-process)."""
    return uvicorn.Config(
        app,
        host=settings.host,
        port=settings.port,
        log_level=log_level or settings.log_level,
        log_config=logging_config(),  # tokens in URLs never reach the access log
        ws_max_size=settings.max_message_bytes,
        ws_per_message_deflate=False,  # payloads are JPEG/zstd already
        limit_concurrency=settings.max_connections,  # beyond: 503 (HTTP) or refused (socket)
    )


class ServerThread:
    """A real uvicorn serving the app; `url` once `start()` returns."""

    def __init__(self, settings: ServerSettings, encoder: TextEncoder | None = None):
        if settings.port == 0:
            settings.port = free_port(settings.host)
        self.settings = settings
        self.app = create_app(settings, encoder=encoder)
        self.server = uvicorn.Server(uvicorn_config(self.app, settings, log_level="warning"))
        self.thread = threading.Thread(
            target=self.server.run, name="semanticxr-server", daemon=True
        )
        self.url = f"http://{settings.host}:{settings.port}"
        self.ws_url = f"ws://{settings.host}:{settings.port}"

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
