"""docker/compose.yaml passes the API key and a token to the services that need them."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from app.cli import device, viewer

yaml = pytest.importorskip("yaml")

COMPOSE = Path(__file__).resolve().parents[2] / "docker" / "compose.yaml"
KEY = "k3y"


def interpolate(text: str, env: dict[str, str]) -> str:
    """Compose's `${NAME}` and `${NAME:-default}` (defaults may nest), innermost first."""
    pattern = re.compile(r"\$\{(\w+)(?::-([^${}]*))?\}")
    while pattern.search(text):
        text = pattern.sub(lambda m: env.get(m[1]) or (m[2] or ""), text)
    return text


def service_env(service: str, env: dict[str, str]) -> dict[str, str]:
    """The environment compose gives `service` when the shell has `env`."""
    entries = yaml.safe_load(COMPOSE.read_text())["services"][service].get("environment", [])
    out = {}
    for entry in entries:
        name, sep, value = entry.partition("=")
        if sep:
            out[name] = interpolate(value, env)
        elif name in env:  # a bare name is passed on only when set
            out[name] = env[name]
    return out


def parse(module, argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    module.add_parser(parser.add_subparsers(dest="command"))
    return parser.parse_args(argv)


def test_with_an_api_key_every_service_gets_what_it_needs(monkeypatch):
    shell = {"SEMANTICXR_API_KEY": KEY}
    assert service_env("server", shell)["SEMANTICXR_API_KEY"] == KEY
    device_env = service_env("device", shell)
    assert device_env["SEMANTICXR_API_KEY"] == KEY
    viewer_env = service_env("viewer", shell)
    assert viewer_env["SEMANTICXR_TOKEN"] == KEY  # the key opens every session

    # ... and the commands read those variables.
    for name, value in {**device_env, **viewer_env}.items():
        monkeypatch.setenv(name, value)
    args = parse(device, ["device", "--server", "http://server:8000", "--create"])
    assert args.api_key == KEY
    args = parse(viewer, ["viewer", "--server", "http://server:8000", "--session", "s1"])
    assert args.token == KEY


def test_a_session_token_goes_to_the_viewer_in_place_of_the_key():
    shell = {"SEMANTICXR_API_KEY": KEY, "SEMANTICXR_TOKEN": "t0ken"}
    assert service_env("viewer", shell)["SEMANTICXR_TOKEN"] == "t0ken"


def test_without_a_key_nothing_is_passed_and_the_server_runs_open():
    assert "SEMANTICXR_API_KEY" not in service_env("server", {})
    assert "SEMANTICXR_API_KEY" not in service_env("device", {})
    assert service_env("viewer", {})["SEMANTICXR_TOKEN"] == ""  # empty: no token


def test_the_cluster_profile_runs_our_commands_behind_one_port():
    """The cluster's services run `serve --cluster` and `gateway` with flags our CLI takes,
    on a PostgreSQL store, and nginx sends port 8000 to both gateways."""
    from app.cli import build_parser
    from app.cli.serve import settings_from_args

    services = yaml.safe_load(COMPOSE.read_text())["services"]
    cluster = {name for name, s in services.items() if "cluster" in s.get("profiles", [])}
    assert cluster == {"postgres", "ray-head", "gateway2", "gateways"}
    env = {"SEMANTICXR_STORE": "postgresql://semanticxr:pw@postgres:5432/semanticxr"}
    for name in ("ray-head", "gateway2"):
        script = services[name]["command"][-1]
        line = script.split("exec ", 1)[1].replace("$$SEMANTICXR_STORE", env["SEMANTICXR_STORE"])
        argv = [part.strip("'\"") for part in line.split()][1:]  # after "semanticxr"
        settings = settings_from_args(build_parser().parse_args(argv))
        assert settings.store_url == env["SEMANTICXR_STORE"] and settings.port == 8000
        assert argv[0] == ("serve" if name == "ray-head" else "gateway")
    assert services["gateways"]["ports"] == ["127.0.0.1:8000:8000"]
    nginx = (COMPOSE.parent / "nginx-cluster.conf").read_text()
    assert "server ray-head:8000;" in nginx and "server gateway2:8000;" in nginx
    assert "proxy_set_header Upgrade" in nginx  # WebSockets pass
