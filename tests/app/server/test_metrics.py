"""/metrics: prometheus_client's exposition, Prometheus naming, every series from the start."""

from __future__ import annotations

import asyncio

import httpx
from analytic_world import KITCHEN
from devices import frame_message, stream_in_step
from prometheus_client.parser import text_string_to_metric_families

from app.server.metrics import Metrics

FAULT_COUNTERS = (
    "semanticxr_dropped_frames_total",
    "semanticxr_persist_failures_total",
    "semanticxr_mapping_failures_total",
    "semanticxr_slow_subscribers_closed_total",
)


def scrape(url: str) -> dict[str, dict[tuple, float]]:
    """sample name -> {sorted label items: value}, parsed by prometheus_client's parser."""
    response = httpx.get(f"{url}/metrics")
    assert response.status_code == 200
    assert response.headers["content-type"].startswith("text/plain; version=")
    samples: dict[str, dict[tuple, float]] = {}
    for family in text_string_to_metric_families(response.text):
        for sample in family.samples:
            key = tuple(sorted(sample.labels.items()))
            samples.setdefault(sample.name, {})[key] = sample.value
    return samples


def test_a_fresh_server_exports_every_series_with_counters_at_zero(live_server):
    samples = scrape(live_server().url)
    for name in FAULT_COUNTERS:
        assert samples[name] == {(): 0.0}, name
    assert samples["semanticxr_frames_total"] == {
        (("outcome", "bad"),): 0.0,
        (("outcome", "ok"),): 0.0,
    }
    assert samples["semanticxr_upstream_bytes_total"][(("kind", "rgb"),)] == 0.0
    assert samples["semanticxr_mapping_latency_seconds_count"] == {(): 0.0}
    assert samples["semanticxr_sessions"] == {(): 0.0}
    # the process and the runtime, from prometheus_client's collectors
    assert samples["process_resident_memory_bytes"][()] > 0
    assert "process_cpu_seconds_total" in samples and "python_info" in samples
    # units in the names: no milliseconds left
    assert not [name for name in samples if name.endswith("_ms") or "_ms_" in name]


def test_requests_frames_and_queries_are_counted_by_route_template(live_server):
    server = live_server()
    sid = httpx.post(f"{server.url}/v1/sessions", json={}).json()["session_id"]
    frames = [frame_message(KITCHEN, i, cam_xy=(0.03 * i, 0.0)) for i in range(3)]
    asyncio.run(stream_in_step(f"{server.ws_url}/v1/sessions/{sid}/stream", frames))
    for _ in range(2):
        httpx.get(f"{server.url}/v1/sessions/{sid}/query", params={"text": "fridge"})
    httpx.get(f"{server.url}/v1/sessions/nope/query", params={"text": "fridge"})

    samples = scrape(server.url)
    requests = samples["semanticxr_http_requests_total"]
    route = "/v1/sessions/{sid}/query"
    assert requests[(("method", "GET"), ("route", route), ("status", "200"))] == 2
    assert requests[(("method", "GET"), ("route", route), ("status", "404"))] == 1
    assert requests[(("method", "POST"), ("route", "/v1/sessions"), ("status", "201"))] == 1
    assert not [labels for labels in requests if ("route", f"/v1/sessions/{sid}") in labels]
    duration = samples["semanticxr_http_request_duration_seconds_count"]
    assert duration[(("method", "GET"), ("route", route))] == 3
    assert samples["semanticxr_frames_total"][(("outcome", "ok"),)] == 3
    assert samples["semanticxr_query_latency_seconds_count"][()] == 2
    assert samples["semanticxr_mapping_latency_seconds_count"][()] >= 1
    assert samples["semanticxr_upstream_bytes_total"][(("kind", "depth"),)] > 0
    assert samples["semanticxr_sessions"][()] == 1


def test_each_app_has_its_own_registry():
    first, second = Metrics(), Metrics()  # would raise "Duplicated timeseries" if shared
    first.dropped_frames.inc()
    assert first.registry.get_sample_value("semanticxr_dropped_frames_total") == 1
    assert second.registry.get_sample_value("semanticxr_dropped_frames_total") == 0
