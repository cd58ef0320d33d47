"""Server settings: environment variables, flags, and clear errors for values that cannot work."""

from __future__ import annotations

import pytest

from app.cli import main
from app.server.settings import ServerSettings


def test_environment_then_overrides(monkeypatch):
    monkeypatch.setenv("SEMANTICXR_PORT", "9001")
    monkeypatch.setenv("SEMANTICXR_API_KEY", "k")
    monkeypatch.setenv("SEMANTICXR_DATA_DIR", "")  # empty: unset, as compose leaves it
    settings = ServerSettings.from_env(max_sessions=3, port=None)
    assert (settings.port, settings.api_key, settings.max_sessions) == (9001, "k", 3)
    assert settings.data_dir == ServerSettings().data_dir
    assert ServerSettings.from_env(port=9002).port == 9002


def test_the_store_defaults_to_the_sqlite_file_in_the_data_dir(monkeypatch, tmp_path):
    assert ServerSettings(data_dir="data").store_url == "sqlite:///data/semanticxr.sqlite3"
    assert ServerSettings(data_dir="/srv/x/").store_url == "sqlite:////srv/x/semanticxr.sqlite3"
    monkeypatch.setenv("SEMANTICXR_STORE", f"sqlite:///{tmp_path}/elsewhere.db")
    assert ServerSettings.from_env().store_url == f"sqlite:///{tmp_path}/elsewhere.db"


@pytest.mark.parametrize(
    ("env", "flags", "named"),
    [
        ({"SEMANTICXR_PORT": "abc"}, [], "SEMANTICXR_PORT must be an integer, got 'abc'"),
        ({"SEMANTICXR_MAX_SESSIONS": "0"}, [], "max_sessions must be at least 1"),
        ({}, ["--port", "70000"], "port must be within [0, 65535], got 70000"),
        ({}, ["--mapping-workers", "0"], "mapping_workers must be at least 1, got 0"),
        ({}, ["--max-message-bytes", "-1"], "max_message_bytes must be at least 1"),
        ({}, ["--api-key", " "], "api_key must not be empty"),
        ({}, ["--max-instances-per-frame", "2000"], "max_instances_per_frame must be at most 1024"),
        ({"SEMANTICXR_MAX_OBJECTS": "0"}, [], "max_objects must be at least 1"),
        ({}, ["--max-frame-pixels", "0"], "max_frame_pixels must be at least 1"),
        ({"SEMANTICXR_STORE": "mysql://db/x"}, [], "unknown scheme 'mysql'"),
        ({}, ["--store", "postgresql://me:pw@db:x/db"], "port of 'postgresql://me:***@db:x/db'"),
        ({"SEMANTICXR_STORE": "semanticxr.db"}, [], "store (--store, SEMANTICXR_STORE) must be"),
        ({"SEMANTICXR_MAX_TOMBSTONES": "0"}, [], "max_tombstones must be at least 1"),
        ({"SEMANTICXR_PERCEPTION": "detections,owl"}, [], "perception: unknown backend 'owl'"),
        ({"SEMANTICXR_PERCEPTION": " , "}, [], "perception: unknown backend ''"),
        ({}, ["--max-resident-sessions", "0"], "max_resident_sessions must be at least 1"),
        ({}, ["--idle-unload-s", "0"], "idle_unload_s must be over 0 seconds, got 0.0"),
        ({"SEMANTICXR_IDLE_UNLOAD_S": "soon"}, [], "SEMANTICXR_IDLE_UNLOAD_S must be a number"),
        ({}, ["--session-retention-days", "-1"], "session_retention_days must be over 0 days"),
        ({}, ["--tls-cert", "cert.pem"], "tls_cert and tls_key go together"),
        ({"SEMANTICXR_HTTPS": "maybe"}, [], "SEMANTICXR_HTTPS must be true or false, got 'maybe'"),
        ({}, ["--https", "--cluster", "auto", "--store", "postgresql://db/x"], "https: a cluster"),
    ],
)
def test_serve_refuses_settings_that_cannot_work_and_names_them(
    monkeypatch, capsys, tmp_path, env, flags, named
):
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    with pytest.raises(SystemExit) as exit_info:  # before any server starts
        main(["serve", "--data-dir", str(tmp_path), *flags])
    assert exit_info.value.code == 2
    assert named in capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["eval", "--scene", "nowhere"], "unknown scene 'nowhere'; valid names: living_room"),
        (["eval", "--frames", "-3"], "argument --frames: must be at least 1, got -3"),
        (["eval", "--width", "wide"], "argument --width: must be an integer, got 'wide'"),
        (["demo", "--frames", "0"], "argument --frames: must be at least 1, got 0"),
        (["viewer", "--server", "notaurl", "--session", "x"], "must look like http://host:port"),
        (["device", "--server", "ftp://h:1", "--create"], "must look like http://host:port"),
    ],
)
def test_commands_refuse_bad_arguments_and_name_them(capsys, argv, named):
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    assert named in capsys.readouterr().err


def test_serve_has_a_flag_per_setting_and_a_flag_beats_the_environment(monkeypatch, capsys):
    import dataclasses

    from app.cli import build_parser
    from app.cli.serve import settings_from_args

    with pytest.raises(SystemExit):
        build_parser().parse_args(["serve", "--help"])
    help_text = capsys.readouterr().out
    for field in dataclasses.fields(ServerSettings):
        assert f"--{field.name.replace('_', '-')}" in help_text
        assert f"SEMANTICXR_{field.name.upper()}" in help_text.replace("\n", "").replace(" ", "")

    monkeypatch.setenv("SEMANTICXR_PORT", "9001")
    monkeypatch.setenv("SEMANTICXR_MAX_SESSIONS", "5")
    args = build_parser().parse_args(["serve", "--port", "9002", "--max-query-k", "7"])
    settings = settings_from_args(args)
    assert (settings.port, settings.max_sessions, settings.max_query_k) == (9002, 5, 7)
    assert settings.host == ServerSettings().host


def test_fractional_settings_come_from_flags_and_the_environment(monkeypatch):
    from app.cli import build_parser
    from app.cli.serve import settings_from_args

    monkeypatch.setenv("SEMANTICXR_SESSION_RETENTION_DAYS", "0.5")
    args = build_parser().parse_args(["serve", "--idle-unload-s", "2.5"])
    settings = settings_from_args(args)
    assert (settings.idle_unload_s, settings.session_retention_days) == (2.5, 0.5)
    assert ServerSettings().session_retention_days is None  # retention is off by default
    assert (ServerSettings().max_sessions, ServerSettings().max_resident_sessions) == (10_000, 64)


def test_https_listens_on_every_interface_unless_a_host_is_given(monkeypatch):
    assert ServerSettings().host == "127.0.0.1"  # plain serve: this machine only, as before
    assert ServerSettings(https=True).host == ""  # '' binds IPv4 and IPv6 (0.0.0.0 only v4)
    assert ServerSettings(https=True, host="127.0.0.1").host == "127.0.0.1"
    given = ServerSettings(tls_cert="cert.pem", tls_key="key.pem")
    assert given.https and given.host == ""  # a certificate given means HTTPS
    monkeypatch.setenv("SEMANTICXR_HTTPS", "true")
    assert ServerSettings.from_env().https
    monkeypatch.setenv("SEMANTICXR_HTTPS", "0")
    assert not ServerSettings.from_env().https


def test_serve_with_a_certificate_it_cannot_read_exits_2_naming_the_flag(capsys, tmp_path):
    missing = str(tmp_path / "nope.pem")
    code = main(["serve", "--data-dir", str(tmp_path), "--tls-cert", missing, "--tls-key", missing])
    assert code == 2  # before any port is bound
    assert f"semanticxr serve: --tls-cert: cannot read {missing}" in capsys.readouterr().err
