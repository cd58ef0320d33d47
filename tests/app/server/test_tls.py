"""HTTPS (`serve --https`): the certificate for this machine's names (made once, reused,
made anew when the names change, owner-only files), a real server over TLS on loopback, and
the Host names it answers to."""

from __future__ import annotations

import datetime
import logging
import ssl
import stat

import httpx
import pytest
from cryptography import x509

from app.server.runner import tls_ready
from app.server.settings import ServerSettings
from app.server.tls import (
    RENEW_BEFORE_DAYS,
    TlsError,
    certificate_names,
    given_certificate,
    machine_names,
    make_self_signed,
    page_address,
    page_host,
    self_signed_certificate,
)

NAMES = ["localhost", "127.0.0.1", "::1", "studio", "192.168.1.23", "fd00::23"]


def mode(path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_a_certificate_made_for_given_names_holds_them_in_owner_only_files(tmp_path):
    folder = tmp_path / "data" / "tls"
    certificate = self_signed_certificate(folder, NAMES)
    assert certificate.made and certificate.self_signed
    assert set(certificate.names) == set(NAMES)
    assert set(certificate_names(certificate.cert_path.read_bytes())) == set(NAMES)
    assert mode(folder) == 0o700
    assert mode(certificate.cert_path) == 0o600 and mode(certificate.key_path) == 0o600
    assert sorted(p.name for p in folder.iterdir()) == ["cert.pem", "key.pem"]  # no leftovers


def test_a_certificate_is_reused_while_the_names_stay_and_made_anew_when_they_change(tmp_path):
    folder = tmp_path / "tls"
    first = self_signed_certificate(folder, NAMES)
    pem = first.cert_path.read_bytes()
    first.key_path.chmod(0o644)  # widened by hand: reuse narrows it again

    again = self_signed_certificate(folder, list(reversed(NAMES)))  # same names, any order
    assert not again.made
    assert again.cert_path.read_bytes() == pem
    assert mode(again.key_path) == 0o600

    moved = [*NAMES[:4], "10.0.0.7"]  # the machine joined another network
    remade = self_signed_certificate(folder, moved)
    assert remade.made
    assert set(certificate_names(remade.cert_path.read_bytes())) == set(moved)
    assert mode(remade.cert_path) == 0o600 and mode(remade.key_path) == 0o600


def test_a_certificate_near_its_end_or_beside_another_key_is_made_anew(tmp_path):
    folder = tmp_path / "tls"
    made = self_signed_certificate(folder, NAMES)
    expires = x509.load_pem_x509_certificate(made.cert_path.read_bytes()).not_valid_after_utc
    near_the_end = expires - datetime.timedelta(days=RENEW_BEFORE_DAYS - 1)
    assert self_signed_certificate(folder, NAMES, now=near_the_end).made

    _, other_key = make_self_signed(NAMES, datetime.datetime.now(datetime.UTC))
    (folder / "key.pem").write_bytes(other_key)  # a crash between the two writes
    assert self_signed_certificate(folder, NAMES).made
    (folder / "cert.pem").write_text("not a certificate")
    assert self_signed_certificate(folder, NAMES).made


def test_this_machines_names_leave_out_loopback_and_link_local_ipv6():
    names = machine_names(
        "Studio", ["127.0.0.1", "::1", "192.168.1.23", "fe80::1%eth0", "fd00::23", "192.168.1.23"]
    )
    assert names == NAMES


def test_the_page_address_is_a_private_ipv4_before_any_other():
    assert page_address(NAMES) == "192.168.1.23"
    assert page_address(["localhost", "::1", "2a01:4f8::5", "fd00::23"]) == "fd00::23"
    assert page_address(["localhost", "127.0.0.1", "studio"]) is None
    assert page_host("", NAMES) == "192.168.1.23"
    assert page_host("127.0.0.1", NAMES) == "127.0.0.1"  # a bind to one address is that one
    assert page_host("", ["localhost", "xr.example.com"]) == "xr.example.com"


def test_an_operators_certificate_is_checked_against_its_key_before_start(tmp_path):
    now = datetime.datetime.now(datetime.UTC)
    cert_pem, key_pem = make_self_signed(["xr.example.com"], now)
    _, stranger_key = make_self_signed(["xr.example.com"], now)
    (tmp_path / "cert.pem").write_bytes(cert_pem)
    (tmp_path / "key.pem").write_bytes(key_pem)
    (tmp_path / "stranger.pem").write_bytes(stranger_key)

    given = given_certificate(tmp_path / "cert.pem", tmp_path / "key.pem")
    assert given.names == ("xr.example.com",) and not given.self_signed
    with pytest.raises(TlsError, match="--tls-key: .*stranger.pem"):
        given_certificate(tmp_path / "cert.pem", tmp_path / "stranger.pem")
    with pytest.raises(TlsError, match="--tls-cert: cannot read .*missing.pem"):
        given_certificate(tmp_path / "missing.pem", tmp_path / "key.pem")
    with pytest.raises(TlsError, match="--tls-cert: .*key.pem is not a PEM certificate"):
        given_certificate(tmp_path / "key.pem", tmp_path / "key.pem")


def test_with_https_the_allowed_hosts_are_exactly_the_certificates_names(tmp_path):
    served, certificate = tls_ready(ServerSettings(https=True, data_dir=str(tmp_path)))
    assert served.host == ""  # every interface, IPv4 and IPv6
    assert served.allowed_host_list() == list(certificate.names)
    assert served.tls_cert == str(tmp_path / "tls" / "cert.pem")

    chosen = ServerSettings(https=True, data_dir=str(tmp_path), allowed_hosts="xr.local")
    assert tls_ready(chosen)[0].allowed_host_list() == ["xr.local"]
    plain, none = tls_ready(ServerSettings(data_dir=str(tmp_path)))
    assert none is None and plain.allowed_host_list() == ["localhost", "127.0.0.1", "::1"]


# --- a real server over TLS ---------------------------------------------------------------


def test_an_https_server_answers_a_client_that_trusts_its_certificate_and_no_other(live_server):
    server = live_server(https=True)
    assert server.url.startswith("https://127.0.0.1:")
    trust = ssl.create_default_context(cafile=str(server.certificate.cert_path))
    answer = httpx.get(f"{server.url}/healthz", verify=trust)
    assert answer.status_code == 200 and answer.json()["status"] == "ok"
    with pytest.raises(httpx.ConnectError, match="CERTIFICATE_VERIFY_FAILED"):
        httpx.get(f"{server.url}/healthz")  # the system's CAs know nothing of it
    with pytest.raises(httpx.RemoteProtocolError):
        httpx.get(server.url.replace("https:", "http:") + "/healthz")  # TLS only


def test_an_https_server_refuses_a_host_its_certificate_does_not_name(live_server):
    server = live_server(https=True)
    trust = ssl.create_default_context(cafile=str(server.certificate.cert_path))
    with httpx.Client(base_url=server.url, verify=trust) as http:
        for name in server.certificate.names:  # as a browser sends them, IPv6 in brackets
            host = f"[{name}]" if ":" in name else name
            assert http.get("/healthz", headers={"Host": host}).status_code == 200, name
        refused = http.get("/healthz", headers={"Host": "rebinding.example"})
    assert refused.status_code == 400
    assert "--allowed-hosts" in refused.json()["detail"]


def test_https_without_an_api_key_warns_once_that_the_network_can_reach_it(live_server, caplog):
    caplog.set_level(logging.WARNING, logger="semanticxr")
    live_server(https=True)
    said = [r.getMessage() for r in caplog.records if "no API key" in r.getMessage()]
    assert len(said) == 1
    assert "anyone on your network" in said[0] and "--api-key" in said[0]
    caplog.clear()
    live_server(https=True, api_key="sesame")
    assert not [r for r in caplog.records if "no API key" in r.getMessage()]
