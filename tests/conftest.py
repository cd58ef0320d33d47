"""Shared fixtures: the real text encoder, loaded once per test session."""

import os

import pytest
from pg import fresh_pg_url, pg_cluster, pg_url  # noqa: F401 (the PostgreSQL fixtures)

os.environ.setdefault("HF_HUB_OFFLINE", "1")


@pytest.fixture(scope="session")
def encoder():
    from app.semantics import get_text_encoder

    return get_text_encoder()


class LiveServer:
    """A real uvicorn serving the app on a free loopback port, in a background thread."""

    def __init__(self, data_dir, encoder, **settings):
        from app.server.runner import ServerThread
        from app.server.settings import ServerSettings

        self.settings = ServerSettings(host="127.0.0.1", port=0, data_dir=str(data_dir), **settings)
        self._thread = ServerThread(self.settings, encoder).start()
        self.app, self.server = self._thread.app, self._thread.server
        self.url, self.ws_url = self._thread.url, self._thread.ws_url
        self.certificate = self._thread.certificate  # with https=True: what clients trust

    def stop(self):
        self._thread.stop()


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
