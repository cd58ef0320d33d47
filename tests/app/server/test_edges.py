"""Who may reach the server: Host and Origin checks, /metrics auth, credentials kept out of
URLs and logs (docs/faults.md, "Credentials and origins"). Through a real server on loopback."""

import asyncio
import os
import subprocess
import sys
import time

import httpx
import pytest
import websockets

from app.server.edges import default_allowed_hosts, redact, split_host
from app.server.runner import free_port


def test_a_loopback_bind_answers_to_loopback_names_and_a_wildcard_bind_to_any():
    assert default_allowed_hosts("127.0.0.1") == ["localhost", "127.0.0.1", "::1"]
    assert default_allowed_hosts("0.0.0.0") is None
    assert default_allowed_hosts("::") is None
    assert "10.0.0.5" in default_allowed_hosts("10.0.0.5")


def test_host_headers_lose_their_port():
    assert split_host("LocalHost:8000") == "localhost"
    assert split_host("[::1]:8000") == "::1"
    assert split_host("::1") == "::1"


def test_a_foreign_host_is_refused_naming_the_flag(live_server):
    server = live_server()
    refused = httpx.get(f"{server.url}/healthz", headers={"Host": "evil.example"})
    assert refused.status_code == 400
    assert "--allowed-hosts" in refused.json()["detail"]
    port = server.settings.port
    for host in (f"localhost:{port}", f"127.0.0.1:{port}"):
        assert httpx.get(f"{server.url}/healthz", headers={"Host": host}).status_code == 200


def test_allowed_hosts_adds_a_name(live_server):
    server = live_server(allowed_hosts="server,localhost")
    assert httpx.get(f"{server.url}/healthz", headers={"Host": "server:8000"}).status_code == 200
    assert httpx.get(f"{server.url}/healthz", headers={"Host": "127.0.0.1"}).status_code == 400


def _open_updates(url: str, **kwargs) -> str:
    async def go() -> str:
        try:
            async with websockets.connect(url, open_timeout=5, **kwargs):
                return "open"
        except websockets.InvalidStatus as exc:
            return f"refused {exc.response.status_code}"

    return asyncio.run(go())


def test_a_foreign_origin_cannot_open_a_socket_but_the_servers_own_pages_can(live_server):
    server = live_server(allow_origin="https://viewer.example:8443")
    sid = httpx.post(f"{server.url}/v1/sessions", json={}).json()["session_id"]
    url = f"{server.ws_url}/v1/sessions/{sid}/updates"
    own = f"http://127.0.0.1:{server.settings.port}"
    assert _open_updates(url, origin="http://evil.example") == "refused 403"
    assert _open_updates(url, origin=own) == "open"
    assert _open_updates(url, origin="https://viewer.example:8443") == "open"
    assert _open_updates(url) == "open"  # non-browser clients send no Origin


def test_metrics_need_the_api_key_when_the_server_has_one(live_server):
    server = live_server(api_key="k3y")
    assert httpx.get(f"{server.url}/metrics").status_code == 401
    assert (
        httpx.get(f"{server.url}/metrics", headers={"Authorization": "Bearer nope"}).status_code
        == 403
    )
    ok = httpx.get(f"{server.url}/metrics", headers={"Authorization": "Bearer k3y"})
    assert ok.status_code == 200 and "semanticxr_" in ok.text


def test_rest_takes_credentials_from_the_header_only(live_server):
    server = live_server(api_key="k3y")
    created = httpx.post(
        f"{server.url}/v1/sessions", json={}, headers={"Authorization": "Bearer k3y"}
    ).json()
    sid, token = created["session_id"], created["token"]
    assert httpx.get(f"{server.url}/v1/sessions/{sid}?token={token}").status_code == 401
    assert httpx.get(f"{server.url}/v1/sessions?token=k3y").status_code == 401
    headers = {"Authorization": f"Bearer {token}"}
    assert httpx.get(f"{server.url}/v1/sessions/{sid}", headers=headers).status_code == 200


def test_redact_blanks_tokens_and_authorization_values():
    line = "GET /v1/sessions/ab/updates?since=3&token=s3cret HTTP/1.1 Authorization: Bearer k3y"
    clean = redact(line)
    assert "s3cret" not in clean and "k3y" not in clean
    assert "since=3" in clean and "token=[redacted]" in clean


@pytest.mark.slow
def test_the_access_log_of_a_real_server_never_shows_a_token(tmp_path):
    port = free_port()
    env = dict(os.environ, HF_HUB_OFFLINE="1")
    server = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "app.cli",
            "serve",
            "--port",
            str(port),
            "--data-dir",
            str(tmp_path),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
    )
    try:
        url = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 60
        while True:
            try:
                if httpx.get(f"{url}/healthz", timeout=1).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            assert time.monotonic() < deadline and server.poll() is None, "server did not start"
            time.sleep(0.1)
        sid = httpx.post(f"{url}/v1/sessions", json={}).json()["session_id"]
        httpx.get(f"{url}/v1/sessions/{sid}?token=s3cret-token")
        assert _open_updates(f"ws://127.0.0.1:{port}/v1/sessions/{sid}/updates?token=s3cret-ws")
    finally:
        server.terminate()
        output, _ = server.communicate(timeout=30)
    assert f"/v1/sessions/{sid}?token=[redacted]" in output  # the request was logged...
    assert "s3cret" not in output  # ...without its credential
