"""Shared fixtures: the real text encoder, loaded once per test session."""

import os

import pytest

os.environ.setdefault("HF_HUB_OFFLINE", "1")


@pytest.fixture(scope="session")
def encoder():
    from app.semantics import get_text_encoder

    return get_text_encoder()


class LiveServer:
    """A real uvicorn serving the app on a free loopback port, in a background thread."""

    def __init__(self, data_dir, encoder, **settings):
        import socket
        import threading

        import uvicorn

        from app.server.app import create_app
        from app.server.settings import ServerSettings

        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        self.settings = ServerSettings(
            host="127.0.0.1", port=port, data_dir=str(data_dir), **settings
        )
        self.app = create_app(self.settings, encoder=encoder)
        config = uvicorn.Config(
            self.app,
            host="127.0.0.1",
            port=port,
            log_level="warning",
            ws_max_size=self.settings.max_message_bytes,
            ws_per_message_deflate=False,
        )
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(target=self.server.run, daemon=True)
        self.thread.start()
        import time

        deadline = time.monotonic() + 30
        while not self.server.started:
            if time.monotonic() > deadline or not self.thread.is_alive():
                raise RuntimeError("server did not start")
            time.sleep(0.01)
        self.url = f"http://127.0.0.1:{port}"
        self.ws_url = f"ws://127.0.0.1:{port}"

    def stop(self):
        self.server.should_exit = True
        self.thread.join(timeout=30)


@pytest.fixture
def live_server(tmp_path, encoder):
    """Start with live_server() (kwargs are ServerSettings fields); stopped at teardown."""
    servers = []

    def start(**settings):
        server = LiveServer(tmp_path / "data", encoder, **settings)
        servers.append(server)
        return server

    yield start
    for server in servers:
        server.stop()
