"""A server with `--perception models` on tiny random models (nothing to download), in process
on a free loopback port, for the bench and the screenshot that drive the real-device page."""

from __future__ import annotations

import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from app.perception.models.tiny import write_tiny_models
from app.server.runner import ServerThread
from app.server.settings import ServerSettings


@contextmanager
def tiny_models_server() -> Iterator[ServerThread]:
    """A running ServerThread (its `url`) whose data and models live in a temporary folder."""
    with tempfile.TemporaryDirectory() as tmp:
        settings = ServerSettings(
            host="127.0.0.1",
            port=0,
            data_dir=str(Path(tmp) / "data"),
            perception="models",
            models_dir=str(write_tiny_models(Path(tmp) / "models")),
        )
        server = ServerThread(settings).start()
        try:
            yield server
        finally:
            server.stop()
