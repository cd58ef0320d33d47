"""bench.scale's arguments and its estimate (the runs themselves need Ray and PostgreSQL and
are measured, not tested: see README's figures)."""

import pytest

from bench.scale import estimate, main


def test_it_needs_a_postgresql_store(monkeypatch, capsys):
    monkeypatch.delenv("SEMANTICXR_STORE", raising=False)
    with pytest.raises(SystemExit) as exit_:
        main(["--store", "sqlite:///x.sqlite3"])
    assert exit_.value.code == 2 and "--store" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--store", "postgresql://u:p@h/db", "--shards", "0"])


def test_the_estimate_divides_cores_by_what_a_device_costs():
    runs = [
        {"route": "gateway", "shards": 1, "server_cpu_ms_per_acked_frame": 20.0},
        {"route": "direct", "shards": 1, "server_cpu_ms_per_acked_frame": 1.0},
        {"route": "gateway", "shards": 4, "server_cpu_ms_per_acked_frame": 10.0},
    ]
    figures = estimate(runs, fps=5.0)
    assert figures["cpu_ms_per_frame"] == 10.0  # the widest run through the gateway
    assert figures["cores_per_device"] == pytest.approx(0.05)
    assert figures["devices_per_core"] == pytest.approx(20.0)
    assert figures["example_4_machines_of_8_cores"] == 640
