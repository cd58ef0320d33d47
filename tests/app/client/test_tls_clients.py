"""The API client against a `serve --https` server on loopback: REST, the updates subscriber
and the stream socket trust its certificate through one SSL context built from the CA file
(`--tls-ca`), and nothing else does."""

from __future__ import annotations

import asyncio
import json

import msgpack
import pytest
from analytic_world import KITCHEN
from devices import frame_message, send_and_collect
from helpers_device import FAST_KNOBS, wait_until

from app.cli import main
from app.client import (
    ApiError,
    Disconnect,
    SessionApi,
    UpdatesSubscriber,
    create_session,
    open_websocket,
    trusting,
)
from app.protocol import unpack_update

pytestmark = pytest.mark.timeout(120)


@pytest.fixture
def https_server(live_server):
    """A server with --https on 127.0.0.1, and the SSL context that trusts its certificate."""
    server = live_server(https=True)
    return server, trusting(server.certificate.cert_path)


def test_a_ca_file_that_is_missing_or_not_certificates_is_refused_saying_why(tmp_path):
    with pytest.raises(ValueError, match="no such file: .*nope.pem"):
        trusting(tmp_path / "nope.pem")
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(ValueError, match="cannot read certificates from .*notes.txt"):
        trusting(tmp_path / "notes.txt")


@pytest.mark.parametrize("command", [["device", "--create"], ["viewer", "--session", "x"]])
def test_the_commands_refuse_a_missing_ca_file_naming_tls_ca(capsys, tmp_path, command):
    missing = str(tmp_path / "nope.pem")
    with pytest.raises(SystemExit) as exit_info:
        main([command[0], "--server", "https://127.0.0.1:1", "--tls-ca", missing, *command[1:]])
    assert exit_info.value.code == 2
    assert f"argument --tls-ca: no such file: {missing}" in capsys.readouterr().err


def test_the_rest_client_works_over_https_with_the_ca_and_refuses_without(https_server):
    server, trust = https_server

    async def calls() -> tuple[str, int]:
        sid, token, _ = await create_session(server.url, name="tls", ssl_context=trust)
        async with SessionApi(server.url, sid, token, ssl_context=trust) as api:
            stats = await api.fetch()
        hits = await asyncio.to_thread(
            SessionApi(server.url, sid, token, ssl_context=trust).query_blocking, "chair"
        )
        return stats.name, len(hits)

    assert asyncio.run(calls()) == ("tls", 0)
    with pytest.raises(ApiError, match="CERTIFICATE_VERIFY_FAILED"):
        asyncio.run(create_session(server.url))  # the system's CAs do not know it


def test_the_updates_subscriber_follows_a_session_over_wss(https_server):
    server, trust = https_server

    async def follow() -> tuple[list[dict], list[Disconnect]]:
        sid, token, _ = await create_session(server.url, knobs=FAST_KNOBS, ssl_context=trust)
        deltas: list[dict] = []
        refusals: list[Disconnect] = []

        def apply(raw: bytes | str) -> str | None:
            message = unpack_update(raw)
            if isinstance(message, str):
                return message
            deltas.append(message)
            return None

        def subscriber(ssl_context=None, on_disconnected=None) -> UpdatesSubscriber:
            return UpdatesSubscriber(
                server.url,
                sid,
                token,
                apply=apply,
                applied_seq=lambda: deltas[-1]["seq"] if deltas else 0,
                on_disconnected=on_disconnected,
                ssl_context=ssl_context,
            )

        trusting_one, stranger = subscriber(trust), subscriber(on_disconnected=refusals.append)
        tasks = [asyncio.create_task(s.run()) for s in (trusting_one, stranger)]
        frames = [frame_message(KITCHEN, i, cam_xy=(0.03 * i, 0.0)) for i in range(3)]
        stream_url = f"{server.ws_url}/v1/sessions/{sid}/stream"
        async with await open_websocket(stream_url, token, ssl_context=trust) as ws:
            replies = await send_and_collect(ws, [msgpack.packb(f) for f in frames])
        assert [reply["type"] for reply in replies] == ["ack"] * 3
        await wait_until(lambda: any(d["upserts"] for d in deltas), what="a delta with objects")
        await wait_until(lambda: bool(refusals), what="the untrusting subscriber's refusal")
        for s in (trusting_one, stranger):
            await s.stop()
        await asyncio.wait_for(asyncio.gather(*tasks), 15)
        return deltas, refusals

    deltas, refusals = asyncio.run(follow())
    assert server.ws_url.startswith("wss://")
    assert {upsert["label"] for d in deltas for upsert in d["upserts"]} >= {"chair"}
    assert "CERTIFICATE_VERIFY_FAILED" in refusals[0].reason


def test_the_sessions_command_lists_an_https_server_with_tls_ca(https_server, capsys):
    server, trust = https_server
    asyncio.run(create_session(server.url, name="over tls", ssl_context=trust))
    cert = str(server.certificate.cert_path)
    assert main(["sessions", "list", "--server", server.url, "--tls-ca", cert, "--json"]) == 0
    assert [row["name"] for row in json.loads(capsys.readouterr().out)] == ["over tls"]
    with pytest.raises(SystemExit) as exit_info:
        main(["sessions", "list", "--server", server.url])
    assert exit_info.value.code == 1
    assert "CERTIFICATE_VERIFY_FAILED" in capsys.readouterr().err
