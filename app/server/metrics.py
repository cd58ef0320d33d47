"""The server's Prometheus series, made with `prometheus_client`, one registry per app.

Every series exists from the start (counters at 0, each label value the server uses
pre-created), so a dashboard can tell "none yet" from "not exported". Units follow
Prometheus' naming: seconds and bytes, counters ending in `_total`. Besides the service's
own series: the process (CPU seconds, resident memory, open fds), Python's GC and version,
and every HTTP request by method, route template and status with its duration.
"""

from __future__ import annotations

import time
from typing import Any

from prometheus_client import (
    CONTENT_TYPE_LATEST,
    CollectorRegistry,
    Counter,
    Gauge,
    Histogram,
    gc_collector,
    generate_latest,
    platform_collector,
    process_collector,
)

LATENCY_BUCKETS_S = (0.001, 0.0025, 0.005, 0.01, 0.02, 0.04, 0.08, 0.16, 0.32, 0.64, 1.28, 2.56)
"""Histogram bounds of the latencies, seconds (1 ms to 2.56 s, doubling)."""
FRAME_OUTCOMES = ("ok", "bad")
UPSTREAM_KINDS = ("rgb", "depth", "detections")
DOWNSTREAM_KINDS = ("updates",)
UNLOAD_REASONS = ("idle", "budget")


class Metrics:
    """The series of one server; `render()` is the /metrics body (CONTENT_TYPE)."""

    CONTENT_TYPE = CONTENT_TYPE_LATEST

    def __init__(self) -> None:
        # A registry of its own: several apps in one process (the tests) never share series.
        self.registry = registry = CollectorRegistry()
        process_collector.ProcessCollector(registry=registry)
        platform_collector.PlatformCollector(registry=registry)
        gc_collector.GCCollector(registry=registry)

        self.frames = Counter(
            "semanticxr_frames", "Frames received, by outcome", ["outcome"], registry=registry
        )
        self.upstream_bytes = Counter(
            "semanticxr_upstream_bytes", "Upstream payload bytes, by kind", ["kind"],
            registry=registry,
        )  # fmt: skip
        self.downstream_bytes = Counter(
            "semanticxr_downstream_bytes", "Downstream update bytes, by kind", ["kind"],
            registry=registry,
        )  # fmt: skip
        self.dropped_frames = Counter(
            "semanticxr_dropped_frames", "Keyframes superseded by newer ones", registry=registry
        )
        self.persist_failures = Counter(
            "semanticxr_persist_failures",
            "Failed writes to the store (keyframe commits, counter saves); a keyframe whose "
            "commit failed was undone and refused",
            registry=registry,
        )
        self.mapping_failures = Counter(
            "semanticxr_mapping_failures",
            "Keyframes whose mapping raised an unexpected error (undone and refused as internal)",
            registry=registry,
        )
        self.slow_subscribers_closed = Counter(
            "semanticxr_slow_subscribers_closed",
            "Update subscribers closed (1013) because they could not keep up",
            registry=registry,
        )
        self.mapping_latency = Histogram(
            "semanticxr_mapping_latency_seconds",
            "Server time per mapped keyframe: decode + perception + mapping + delta "
            "(committed to the delta log and the store), without queueing",
            buckets=LATENCY_BUCKETS_S,
            registry=registry,
        )
        self.query_latency = Histogram(
            "semanticxr_query_latency_seconds",
            "Server query latency: embedding the text, the search and rating the hits",
            buckets=LATENCY_BUCKETS_S,
            registry=registry,
        )
        self.http_requests = Counter(
            "semanticxr_http_requests",
            "HTTP requests answered, by method, route template and status",
            ["method", "route", "status"],
            registry=registry,
        )
        self.http_request_duration = Histogram(
            "semanticxr_http_request_duration_seconds",
            "Time to answer an HTTP request, by method and route template",
            ["method", "route"],
            buckets=LATENCY_BUCKETS_S,
            registry=registry,
        )
        self.sessions = Gauge(
            "semanticxr_sessions", "Sessions resident (their maps in memory)", registry=registry
        )
        self.sessions_stored = Gauge(
            "semanticxr_sessions_stored", "Sessions in the store, resident or not",
            registry=registry,
        )  # fmt: skip
        self.session_loads = Counter(
            "semanticxr_session_loads", "Sessions loaded from the store on first use",
            registry=registry,
        )  # fmt: skip
        self.session_load_latency = Histogram(
            "semanticxr_session_load_seconds",
            "Time to load a session's map from the store",
            buckets=LATENCY_BUCKETS_S,
            registry=registry,
        )
        self.session_unloads = Counter(
            "semanticxr_session_unloads",
            "Sessions unloaded from memory (saved first), by reason: idle (unused for "
            "--idle-unload-s) or budget (room for another under --max-resident-sessions)",
            ["reason"],
            registry=registry,
        )
        self.sessions_expired = Counter(
            "semanticxr_sessions_expired",
            "Sessions deleted by retention (unused for over --session-retention-days)",
            registry=registry,
        )
        self.sessions_taken_over = Counter(
            "semanticxr_sessions_taken_over",
            "Sessions this map shard dropped because another shard claimed them (its lease ran "
            "out while it hung or lost the store); their late writes were refused",
            registry=registry,
        )
        self.subscribers = Gauge(
            "semanticxr_subscribers", "Update subscribers connected", registry=registry
        )
        for outcome in FRAME_OUTCOMES:  # labelled series present at 0 too
            self.frames.labels(outcome=outcome)
        for kind in UPSTREAM_KINDS:
            self.upstream_bytes.labels(kind=kind)
        for kind in DOWNSTREAM_KINDS:
            self.downstream_bytes.labels(kind=kind)
        for reason in UNLOAD_REASONS:
            self.session_unloads.labels(reason=reason)

    def render(self) -> bytes:
        """The Prometheus text exposition of every series."""
        return generate_latest(self.registry)


def make_metrics() -> Metrics:
    return Metrics()


class HttpMetricsMiddleware:
    """ASGI middleware counting and timing HTTP requests by route template (never the raw
    path: ids in paths would make a series per session). Series go to the app's manager's
    Metrics once the lifespan has made it."""

    def __init__(self, app: Any) -> None:
        self.app = app

    async def __call__(self, scope: dict, receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        status = 500  # what a request that raised before answering counts as
        start_s = time.perf_counter()

        async def send_noting_status(message: dict) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            await send(message)

        try:
            await self.app(scope, receive, send_noting_status)
        finally:
            manager = getattr(getattr(scope.get("app"), "state", None), "manager", None)
            if manager is not None:
                route = getattr(scope.get("route"), "path", None) or "unmatched"
                method = scope["method"]
                metrics: Metrics = manager.metrics
                metrics.http_requests.labels(method=method, route=route, status=str(status)).inc()
                metrics.http_request_duration.labels(method=method, route=route).observe(
                    time.perf_counter() - start_s
                )
